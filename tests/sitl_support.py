"""Real autopilots for the tests: ArduCopter SITL and PX4 SITL (SIH) from ../shared/sitl, and an independent monitor.

Where the binaries are: ``$SKYROUTE_SHARED/sitl`` if the environment variable is set, else ``../shared/sitl``
beside the project root (the one rule; a user's fresh clone has neither, and the tests skip). Each autopilot runs
in its own temporary directory and process group, on an instance number picked at run time among those whose
ports are free (a hand-run instance or a parallel run cannot clash), and is stopped by its process group.

:class:`Monitor` is a second MAVLink connection on the autopilot's ground-station port that records what the
vehicle reports and checks it against the map's boxes with its own point-to-box distance and its own local
WGS84 approximation (:mod:`tests.geodesy`): it shares no code with the client or the planner.
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests import shared
from tests.geodesy import latlon_to_ned as to_north_east  # noqa: F401 (the tests import them from here)
from tests.geodesy import ned_to_latlon as to_latlon  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]


shared_dir = shared.shared_dir  # the one rule (tests/shared.py): $SKYROUTE_SHARED, else ../shared


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_client(args: list[str]) -> subprocess.Popen:
    """``motion_planning.py args`` as a child in the project root, pipes for its output, SIGINT at its default: a test
    run started in the background of a shell (``cmd &``) passes SIGINT on ignored, and Python then never turns
    Ctrl-C into KeyboardInterrupt, so a test that sends it would see the mission fly on to the goal."""
    import sys

    return subprocess.Popen([sys.executable, str(ROOT / "motion_planning.py"), *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)  # before exec: only a signal disposition


def fly_and_set_param_in_flight(monitor, args: list[str], name: str, value: float, param_type: int,
                                 fly_timeout_s: float = 90.0) -> tuple[int, str, str]:
    """Run the CLI with ``args`` (:func:`run_client`); once the monitor sees the vehicle flying (armed, 3 m up,
    2 m/s), set the autopilot's parameter ``name`` from the monitor's ground station (e.g. to switch its GPS off);
    wait for the CLI to exit. Returns ``(exit code, stdout, stderr)``."""
    proc = run_client(args)
    try:
        monitor.wait(lambda s: s.armed and s.up_m > 3.0 and s.speed_mps > 2.0, fly_timeout_s, "a vehicle flying")
        monitor.send(lambda mav, sysid: mav.param_set_send(sysid, 1, name.encode(), value, param_type))
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    return proc.returncode, out, err


def arducopter_binary() -> Path | None:
    """The ArduCopter SITL binary in the shared directory (:func:`tests.shared.arducopter`), or None."""
    return shared.arducopter()


def px4_binary() -> Path | None:
    """PX4 SITL's ``bin/px4`` in the shared directory (:func:`tests.shared.px4_dir`), or None."""
    px4 = shared.px4_dir()
    return None if px4 is None else px4 / "bin" / "px4"


# ------------------------------------------------------------------------------------------------ geometry
def read_boxes(path: Path) -> tuple[float, float, np.ndarray]:
    """``(lat0, lon0, boxes)`` from a colliders.csv: boxes (N, 6) centre north/east/up and half sizes."""
    first = path.read_text(encoding="utf-8").splitlines()[0]
    lat0, lon0 = (float(part.split()[1]) for part in first.split(","))
    return lat0, lon0, np.loadtxt(path, delimiter=",", skiprows=2, ndmin=2)


def distance_to_boxes_m(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(P,) 3D distance from each point (north, east, up) to the nearest box (0 inside one)."""
    lo, hi = boxes[:, :3] - boxes[:, 3:], boxes[:, :3] + boxes[:, 3:]
    out = np.empty(len(points))
    for k in range(0, len(points), 256):
        p = points[k:k + 256, None, :]
        gap = np.maximum(np.maximum(lo[None] - p, p - hi[None]), 0.0)
        out[k:k + 256] = np.sqrt((gap**2).sum(axis=2)).min(axis=1)
    return out


# ------------------------------------------------------------------------------------------------ processes
def _tcp_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    with socket.socket() as s:  # nobody listening either
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) != 0


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _reserve(kind: str, instances, ports_free) -> tuple[int, object] | tuple[None, None]:
    """The first instance whose ports are free (``ports_free(n)``) and whose lock no other process holds:
    ``(instance, lock file)``, the lock held until the file is closed (or the process dies), else ``(None, None)``.

    Two test workers starting an autopilot at once both saw instance 1's ports free before either bound them, and
    the second ArduCopter exited with 'bind failed on port 5770' (a CI run's error at setup); the lock makes the
    choice one process's at a time."""
    import fcntl

    for n in instances:
        if not ports_free(n):
            continue
        lock = open(Path(tempfile.gettempdir()) / f"skyroute-{kind}-instance-{n}.lock", "w")  # noqa: SIM115
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        return n, lock
    return None, None


def _tail(log: Path, lines: int = 5) -> str:
    """The last lines of an autopilot's log, for an error raised before stop() removes the log's directory."""
    try:
        return " | ".join(log.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return f"(no log at {log})"


def _stop_group(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=grace_s)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=grace_s)


class ArduCopterSitl:
    """ArduCopter SITL in a temporary directory: ``client`` (SERIAL1) and ``gcs`` (SERIAL2) TCP connections.

    Boots without waiting for a client (``--serial0 tcp:0``), from a wiped eeprom unless ``wipe`` is False.
    ``home`` is (lat, lon, alt AMSL m); ``params`` defaults beyond copter.parm (e.g. ``PRX1_TYPE``: read at boot);
    ``extra`` more command-line arguments. ``serial0``: the free port (SERIAL0) for a third connection.
    """

    def __init__(self, home: tuple[float, float, float], *, speedup: float = 5.0, wipe: bool = True,
                 instances=range(1, 40), extra: tuple[str, ...] = (), params: dict[str, float] | None = None):
        self.home, self.speedup, self.wipe, self.extra = home, speedup, wipe, extra
        self.params = dict(params or {})
        self.instance, self._reservation = _reserve(
            "arducopter", instances, lambda n: all(_tcp_free(5760 + 10 * n + k) for k in (0, 2, 3)))
        if self.instance is None:
            raise RuntimeError("no free ArduCopter SITL instance (ports 5760+10N..5763+10N all busy)")
        self.dir = Path(tempfile.mkdtemp(prefix="skyroute-arducopter-"))
        self.proc: subprocess.Popen | None = None

    @property
    def client(self) -> str:
        return f"tcp:127.0.0.1:{5762 + 10 * self.instance}"

    @property
    def gcs(self) -> str:
        return f"tcp:127.0.0.1:{5763 + 10 * self.instance}"

    @property
    def serial0(self) -> str:
        return f"tcp:127.0.0.1:{5760 + 10 * self.instance}"

    def start(self) -> ArduCopterSitl:
        sitl = shared_dir() / "sitl"
        lat, lon, alt = self.home
        defaults = [str(sitl / "copter.parm")]
        if self.params:
            extra = self.dir / "extra.parm"
            extra.write_text("".join(f"{name} {value:g}\n" for name, value in self.params.items()))
            defaults.append(str(extra))
        cmd = [str(sitl / "arducopter"), "--model", "+", "--speedup", f"{self.speedup:g}", "--defaults",
               ",".join(defaults), "-I", str(self.instance), "--home", f"{lat:.7f},{lon:.7f},{alt:g},0",
               "--serial0", "tcp:0", *(["--wipe"] if self.wipe else []), *self.extra]
        self.log = open(self.dir / "arducopter.log", "w")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(cmd, cwd=self.dir, stdout=self.log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + 20.0
        port = 5762 + 10 * self.instance
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"arducopter exited ({self.proc.returncode}): {_tail(self.dir / 'arducopter.log')}")
            with socket.socket() as s:
                s.settimeout(0.2)
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    return self
            time.sleep(0.1)
        raise RuntimeError("arducopter did not open its ports within 20 s")

    def stop(self) -> None:
        if self.proc is not None:
            _stop_group(self.proc)
            self.log.close()
        shutil.rmtree(self.dir, ignore_errors=True)
        self._reservation.close()

    def __enter__(self) -> ArduCopterSitl:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()


class Px4Sitl:
    """PX4 SITL with SIH in a temporary directory; ``client`` is its offboard link, ``gcs`` its GCS link.

    The shared ``px4/bin`` holds PX4's command links as plain files (the copy lost the symlinks), which the
    startup script cannot run; the run directory gets its own ``bin/`` with ``px4-*`` symlinks to the binary.
    ``fast_align`` sets PX4_EKF2_FAST_ALIGN=1 (global position in ~2.5 s instead of ~35 s).
    """

    def __init__(self, home: tuple[float, float, float], *, fast_align: bool = False, instances=range(1, 10)):
        self.home, self.fast_align = home, fast_align
        self.instance, self._reservation = _reserve(
            "px4", instances, lambda n: all(_udp_free(p + n) for p in (14540, 14580, 18570, 14280, 13030, 19450))
            and not Path(f"/tmp/px4_lock-{n}").exists())
        if self.instance is None:
            raise RuntimeError("no free PX4 SITL instance (1..9)")
        self.dir = Path(tempfile.mkdtemp(prefix="skyroute-px4-"))
        self.proc: subprocess.Popen | None = None

    @property
    def client(self) -> str:
        return f"udpin:127.0.0.1:{14540 + self.instance}"

    @property
    def gcs(self) -> str:
        return f"udpout:127.0.0.1:{18570 + self.instance}"

    def start(self) -> Px4Sitl:
        shared = shared_dir() / "sitl" / "px4"
        bin_dir = self.dir / "bin"
        bin_dir.mkdir()
        (bin_dir / "px4").symlink_to(shared / "bin" / "px4")
        for item in (shared / "bin").iterdir():
            if item.name.startswith("px4-") and item.name != "px4-alias.sh":
                (bin_dir / item.name).symlink_to("px4")
        shutil.copy(shared / "bin" / "px4-alias.sh", bin_dir / "px4-alias.sh")
        lat, lon, alt = self.home
        env = {**os.environ, "PX4_SYS_AUTOSTART": "10040", "PX4_SIM_MODEL": "sihsim_quadx",
               "PX4_HOME_LAT": f"{lat:.7f}", "PX4_HOME_LON": f"{lon:.7f}", "PX4_HOME_ALT": f"{alt:g}"}
        if self.fast_align:
            env["PX4_EKF2_FAST_ALIGN"] = "1"
        self.log = open(self.dir / "px4.log", "w")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen([str(bin_dir / "px4"), "-d", "-i", str(self.instance), str(shared / "etc")],
                                     cwd=self.dir, env=env, stdout=self.log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        time.sleep(1.0)
        if self.proc.poll() is not None:
            raise RuntimeError(f"px4 exited ({self.proc.returncode}): {_tail(self.dir / 'px4.log')}")
        return self

    def stop(self) -> None:
        if self.proc is not None:
            _stop_group(self.proc)
            self.log.close()
        shutil.rmtree(self.dir, ignore_errors=True)
        self._reservation.close()

    def __enter__(self) -> Px4Sitl:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()


# ------------------------------------------------------------------------------------------------- monitor
@dataclass
class Sample:
    time_s: float
    north_m: float
    east_m: float
    up_m: float  # above the map's ground
    speed_mps: float
    armed: bool
    mode: str


@dataclass
class Monitor:
    """A ground station of its own (system 250) on the autopilot's GCS port, recording the reported track.

    ``ground_amsl_m`` is the map ground's altitude above sea level in this test (the truth, known to the test).
    """

    connection: str
    map_path: Path
    ground_amsl_m: float
    samples: list[Sample] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)

    def __post_init__(self):
        from pymavlink import mavutil

        self.lat0, self.lon0, self.boxes = read_boxes(self.map_path)
        self._mav = mavutil.mavlink_connection(self.connection, source_system=250, source_component=190,
                                               autoreconnect=False, retries=10)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._armed, self._mode = False, ""
        self.sysid = None  # PX4 SITL instance N is system N + 1; learnt from the first autopilot heartbeat
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from pymavlink import mavutil

        mav = self._mav
        next_ask, next_beat = 0.0, 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            try:  # a UDP peer not listening yet answers with ICMP: OSError on the next send or receive
                if now >= next_beat:
                    next_beat = now + 1.0
                    mav.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0,
                                           0, 0)
                if now >= next_ask and self.sysid is not None:  # ArduPilot streams on this port only once asked
                    next_ask = now + 5.0
                    mav.mav.command_long_send(self.sysid, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                              mavutil.mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1e5, 0, 0, 0, 0, 0)
                msg = mav.recv_match(blocking=True, timeout=0.1)
            except OSError:
                time.sleep(0.1)
                continue
            if msg is None:
                continue
            kind = msg.get_type()
            if self.sysid is None and kind == "HEARTBEAT" and msg.get_srcComponent() == 1 \
                    and msg.autopilot != mavutil.mavlink.MAV_AUTOPILOT_INVALID:
                self.sysid = msg.get_srcSystem()
            if msg.get_srcSystem() != self.sysid or msg.get_srcComponent() != 1:
                continue
            if kind == "HEARTBEAT":
                self._armed = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                self._mode = mavutil.mode_string_v10(msg)
            elif kind == "STATUSTEXT":
                with self._lock:
                    self.texts.append(str(msg.text))
            elif kind == "GLOBAL_POSITION_INT" and (msg.lat or msg.lon):
                north, east = to_north_east(msg.lat * 1e-7, msg.lon * 1e-7, self.lat0, self.lon0)
                with self._lock:
                    self.samples.append(Sample(now, north, east, msg.alt * 1e-3 - self.ground_amsl_m,
                                               math.hypot(msg.vx, msg.vy) / 100.0, self._armed, self._mode))

    def send(self, build) -> None:
        """Send one message built by ``build(mav, sysid)`` on the monitor's own link (e.g. to land a vehicle)."""
        build(self._mav.mav, self.sysid)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._mav.close()

    def track(self, since_s: float = -math.inf) -> list[Sample]:
        with self._lock:
            return [s for s in self.samples if s.time_s >= since_s]

    def latest(self) -> Sample | None:
        with self._lock:
            return self.samples[-1] if self.samples else None

    def wait(self, predicate, timeout_s: float, what: str) -> Sample:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            s = self.latest()
            if s is not None and predicate(s):
                return s
            time.sleep(0.05)
        raise AssertionError(f"monitor: no {what} within {timeout_s:g} s (last {self.latest()})")

    def landed_at(self, settle_s: float = 2.0, timeout_s: float = 60.0) -> tuple[float, float, float]:
        """``(north_m, east_m, up_m)`` where the vehicle stands once disarmed: the median of ``settle_s`` of reports
        (PX4 SIH's reported position jitters by ~0.5 m on the ground)."""
        self.wait(lambda s: not s.armed, timeout_s, "disarmed vehicle")
        since = time.monotonic()
        time.sleep(settle_s)
        points = np.array([(s.north_m, s.east_m, s.up_m) for s in self.track(since) if not s.armed])
        return tuple(float(v) for v in np.median(points, axis=0))

    def min_clearance_m(self, since_s: float = -math.inf, above_m: float = 0.5, ignore=()) -> float:
        """Smallest distance from the reported track (while ``above_m`` above the ground) to any box but the
        ``ignore`` ones (row numbers, e.g. the roof it took off from)."""
        points = np.array([(s.north_m, s.east_m, s.up_m) for s in self.track(since_s) if s.up_m > above_m])
        boxes = np.delete(self.boxes, list(ignore), axis=0)
        if not len(points):
            return math.inf
        distances = distance_to_boxes_m(points, boxes)
        k = int(distances.argmin())
        print(f"closest approach {distances[k]:.2f} m at N {points[k, 0]:.1f} E {points[k, 1]:.1f} "
              f"up {points[k, 2]:.1f} m (sample {k + 1} of {len(points)})")
        return float(distances[k])


def upload_fence(connection: str, lat0: float, lon0: float, inclusion_ne: np.ndarray,
                 exclusions_ne: list[np.ndarray], timeout_s: float = 20.0) -> None:
    """Upload polygon fences (map north, east m round ``lat0, lon0``) over the MAVLink mission protocol
    (MAV_MISSION_TYPE_FENCE): one inclusion polygon and any exclusion ones. ArduCopter SITL's own proximity sensor
    (PRX1_TYPE 10) reads them: each sector's distance is found by bisecting its middle ray for a fence breach up to
    200 m, so an exclusion zone shows only where it runs on past the bisection's test points (a thick block)."""
    from pymavlink import mavutil

    mav = mavutil.mavlink_connection(connection, source_system=251, autoreconnect=False, retries=10)
    try:
        beat = mav.wait_heartbeat(timeout=timeout_s)
        if beat is None:
            raise RuntimeError(f"no heartbeat on {connection}")
        target = beat.get_srcSystem()
        m = mavutil.mavlink
        items = []
        for command, polygon in [(m.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, inclusion_ne),
                                 *((m.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, p) for p in exclusions_ne)]:
            for north, east in polygon:
                lat, lon = to_latlon(float(north), float(east), lat0, lon0)
                items.append((command, len(polygon), int(round(lat * 1e7)), int(round(lon * 1e7))))
        mav.mav.mission_count_send(target, 1, len(items), m.MAV_MISSION_TYPE_FENCE)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = mav.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True,
                                 timeout=1.0)
            if msg is None:
                continue
            if msg.get_type() == "MISSION_ACK":
                if msg.type != m.MAV_MISSION_ACCEPTED:
                    raise RuntimeError(f"fence upload refused: MAV_MISSION_RESULT {msg.type}")
                return
            command, count, lat, lon = items[msg.seq]
            mav.mav.mission_item_int_send(target, 1, msg.seq, m.MAV_FRAME_GLOBAL, command, 0, 1, count, 0, 0, 0,
                                          lat, lon, 0, m.MAV_MISSION_TYPE_FENCE)
        raise RuntimeError("fence upload: no MISSION_ACK")
    finally:
        mav.close()


def box_ne(north_m: float, east_m: float, half_north_m: float, half_east_m: float) -> np.ndarray:
    """The corners (4, 2) of a map box's footprint, north and east m."""
    return np.array([[north_m - half_north_m, east_m - half_east_m], [north_m - half_north_m, east_m + half_east_m],
                     [north_m + half_north_m, east_m + half_east_m], [north_m + half_north_m, east_m - half_east_m]])


# ------------------------------------------------------------------------------------------- held-out goals
def held_out_goal(map_path: Path, seed: int, *, min_m: float = 80.0, max_m: float = 180.0, safety_m: float = 5.0,
                  altitude_m: float = 5.0) -> tuple[float, float]:
    """A goal (north_m, east_m) no other test uses: a seeded random cell centre ``min_m``..``max_m`` from home,
    where the vehicle may descend (at least ``safety_m`` from every box at ground level, by this module's own
    distance) and that the client's planner can reach from home. Deterministic for a seed."""
    from skyroute.cli.exits import UserError
    from skyroute.cli.setting import check_endpoint, load_setting, make_plan

    setting = load_setting(map_path, altitude_m, safety_m)
    _, _, boxes = read_boxes(map_path)
    grid = setting.grid_map
    rng = np.random.default_rng(seed)
    for _ in range(10_000):
        cell = tuple(int(v) for v in rng.integers(0, grid.grid.shape))
        north, east = grid.centre_of(cell)
        if grid.grid[cell] or not min_m <= math.hypot(north, east) <= max_m:
            continue
        if distance_to_boxes_m(np.array([[north, east, 0.0]]), boxes)[0] < safety_m + 0.5:
            continue
        try:
            check_endpoint(setting, "goal", north, east)
            make_plan(setting, (0.0, 0.0), (north, east))
        except UserError:
            continue
        return float(north), float(east)
    raise RuntimeError(f"no reachable goal {min_m:g}-{max_m:g} m from home on {map_path}")
