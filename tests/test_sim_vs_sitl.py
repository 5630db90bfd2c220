"""Side by side: the same requests to the sim's personalities and to the real autopilots' SITL, compared.

ArduCopter SITL (V4.7.0-dev) and PX4 SITL (v1.15.4, SIH quadcopter, fast estimator alignment) are found under
``$SKYROUTE_SHARED/sitl`` if that is set, else ``../shared/sitl`` next to the project root; without the binaries
every test here is skipped. One SITL boot per autopilot for the whole module, on an instance number picked at
run time from the free ones; each is stopped by its process group when the module ends.

What is compared: the messages a fresh link gets without asking, command result codes (and for refusals the
STATUSTEXT), HEARTBEAT mode numbers and flags per mode, parameter names/types/defaults and their PARAM_VALUE
encoding, the landed-state sequence of a takeoff and landing, auto-disarm timing, ArduCopter GUIDED's
GUID_TIMEOUT continuation and PX4's offboard-loss failsafe. Differences that remain are listed in
:data:`KNOWN_DIFFERENCES` (and in ``sim/__init__.py``); the comparisons leave exactly those out.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import random
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sim import boot as sim_boot
from sim import params as sim_params
from sim import streams as sim_streams
from tests import shared

M = mavlink
NAN = math.nan
ROOT = Path(__file__).resolve().parent.parent
SHARED = shared.shared_dir()  # the one rule (tests/shared.py): $SKYROUTE_SHARED, else ../shared
ARDUCOPTER_BIN = SHARED / "sitl" / "arducopter"
ARDUCOPTER_PARM = SHARED / "sitl" / "copter.parm"
PX4_DIR = SHARED / "sitl" / "px4"
HOME = (37.792480, -122.397450)
ACM = {v: k for k, v in mavutil.mode_mapping_acm.items()}
SPEEDUP = 5

pytestmark = pytest.mark.sitl

#: What still differs, per autopilot: (what, why). The comparisons below skip exactly these.
KNOWN_DIFFERENCES = {
    "ardupilot": [
        ("TIMESYNC, PARAM_VALUE on a fresh link", "SITL sends TIMESYNC requests (~0.1 Hz) and announces a few "
                                                  "parameter changes; the sim does neither"),
        ("REQUEST_DATA_STREAM groups", "the sim streams only the group members it builds (no RAW_IMU, AHRS, "
                                       "MEMINFO, ...)"),
        ("param_count", "the sim's table has the parameters it models, not ArduCopter's ~1350"),
        ("stream requests and reconnects", "SITL keeps SET_MESSAGE_INTERVAL rates per serial port, across TCP "
                                           "connections; the sim's rates belong to one TCP connection"),
        ("takeoff spool-up", "SITL reports ON_GROUND for ~3 s after NAV_TAKEOFF while the motors spool up; the "
                             "sim climbs at once (the state sequence is the same)"),
        ("manual modes without RC", "SITL in STABILIZE/ALT_HOLD with the throttle at minimum sinks or falls; the "
                                    "sim holds position in them"),
    ],
    "px4": [
        ("streams the sim does not build", "HIGHRES_IMU, ODOMETRY, ALTITUDE, DISTANCE_SENSOR, ATTITUDE_TARGET, "
                                           "POSITION_TARGET_LOCAL_NED, SERVO_OUTPUT_RAW, ESTIMATOR_STATUS, "
                                           "MISSION_CURRENT, OPEN_DRONE_ID_*, SCALED_PRESSURE, VIBRATION, "
                                           "CURRENT_MODE, LINK_NODE_STATUS, PING and TIMESYNC requests"),
        ("EVENT / CURRENT_EVENT_SEQUENCE", "pymavlink 2.4.50 has no EVENT message (id 410) in any dialect, so the sim "
                                           "sends PX4's refusals as STATUSTEXT only"),
        ("ATTITUDE rate", "PX4 streams 100 Hz; the sim at most once per 20 ms physics step"),
        ("param_count", "the sim's table has the parameters it models, not PX4's ~900"),
        ("system id", "PX4 SITL instance N is system N+1; the sim is always system 1"),
        ("GCS link", "every sim link streams the onboard/API link's set; PX4's GCS link (UDP 14550) streams "
                     "LOCAL_POSITION_NED, GLOBAL_POSITION_INT, ATTITUDE at 50 Hz and RC_CHANNELS etc."),
        ("commands to another system", "PX4 answers a COMMAND_LONG for another system id with FAILED; the sim "
                                       "ignores it (ArduPilot's routing)"),
    ],
}

#: Commands both get while disarmed and ready, in this order (the last leaves the vehicle as it began).
ARDU_COMMANDS = [
    (M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 10),
    (M.MAV_CMD_DO_SET_MODE, 0, ACM["GUIDED"]),
    (M.MAV_CMD_DO_SET_MODE, 1, 99),
    (M.MAV_CMD_REQUEST_MESSAGE, 9999),
    (M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000),
    (M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 1e6),
    (M.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 37.7926, -122.3973, 5),
    (M.MAV_CMD_DO_CHANGE_SPEED, 1, 3, -1),
    (M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1),
    (M.MAV_CMD_GET_HOME_POSITION,),
    (31999, 1),
    (M.MAV_CMD_DO_SET_MODE, 1, ACM["STABILIZE"]),
]
PX4_COMMANDS = [
    (M.MAV_CMD_DO_SET_MODE, 0, 4, 3),
    (M.MAV_CMD_REQUEST_MESSAGE, 9999),
    (M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000),
    (M.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 37.7926, -122.3973, 5),
    (M.MAV_CMD_DO_CHANGE_SPEED, 1, 3, -1),
    (31999, 1),
    (M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN),
    (M.MAV_CMD_DO_SET_MODE, 1, 4, 3),
]


# ---------------------------------------------------------------------------------------------- a MAVLink probe
class Probe:
    """A ground station (255/190) on any pymavlink connection string, with a reader thread."""

    def __init__(self, connection: str, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.conn = mavutil.mavlink_connection(connection, source_system=255, source_component=190,
                                                       autoreconnect=False, retries=0)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        self.messages: list = []
        self.cond = threading.Condition()
        self._stop = threading.Event()
        self._hb: threading.Event | None = None
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        hb = self.wait_for("HEARTBEAT", lambda m: m.get_srcComponent() == 1, timeout_s=timeout_s)
        self.target = (hb.get_srcSystem(), 1)

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
            except (OSError, ValueError):
                break
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            with self.cond:
                self.messages.append(msg)
                self.cond.notify_all()

    def close(self) -> None:
        self.heartbeats(None)
        self._stop.set()
        self.thread.join(2)
        self.conn.close()

    def mark(self) -> int:
        with self.cond:
            return len(self.messages)

    def wait_for(self, kind: str, predicate=None, timeout_s: float = 5.0, since: int = 0):
        deadline = time.monotonic() + timeout_s
        with self.cond:
            i = since
            while True:
                while i < len(self.messages):
                    m = self.messages[i]
                    i += 1
                    if m.get_type() == kind and (predicate is None or predicate(m)):
                        return m
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"no {kind} within {timeout_s} s")
                self.cond.wait(remaining)

    def of_type(self, kind: str, since: int = 0) -> list:
        with self.cond:
            return [m for m in self.messages[since:] if m.get_type() == kind]

    def from_vehicle(self, since: int = 0) -> list:
        with self.cond:
            return [m for m in self.messages[since:] if m.get_srcSystem() == self.target[0]]

    def command(self, command: int, *params: float, timeout_s: float = 5.0):
        p = list(params) + [0.0] * (7 - len(params))
        since = self.mark()
        self.conn.mav.command_long_send(self.target[0], self.target[1], command, 0, *p)
        return self.wait_for("COMMAND_ACK", lambda m: m.command == command, timeout_s, since)

    def texts(self, since: int) -> list[str]:
        return [m.text for m in self.of_type("STATUSTEXT", since)]

    def heartbeats(self, hz: float | None) -> None:
        """Send GCS heartbeats at ``hz`` (wall clock); None stops them."""
        if self._hb is not None:
            self._hb.set()
            self._hb = None
        if hz is None:
            return
        stop = self._hb = threading.Event()

        def run() -> None:
            while not stop.is_set():
                with contextlib.suppress(OSError):
                    self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                stop.wait(1.0 / hz)

        threading.Thread(target=run, daemon=True).start()

    def stop_streams(self, msg_ids) -> None:
        """Cancel SET_MESSAGE_INTERVAL requests: ArduPilot keeps them per serial port, across TCP connections."""
        for msg_id in msg_ids:
            self.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, -1)

    def param(self, name: str):
        since = self.mark()
        self.conn.mav.param_request_read_send(self.target[0], self.target[1], name.encode(), -1)
        return self.wait_for("PARAM_VALUE", lambda m: m.param_id == name, timeout_s=3, since=since)

    def heartbeat(self, since: int = 0):
        return self.wait_for("HEARTBEAT", lambda m: m.get_srcSystem() == self.target[0], timeout_s=5, since=since)

    def setpoint(self, north: float, east: float, down: float) -> None:
        self.conn.mav.set_position_target_local_ned_send(0, *self.target, M.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000,
                                                         north, east, down, 0, 0, 0, 0, 0, 0, 0, 0)


@contextlib.contextmanager
def streaming(probe: Probe, target: list, hz: float):
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            probe.setpoint(*target)
            stop.wait(1.0 / hz)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(2)


# ---------------------------------------------------------------------------------------------- SITL processes
def _port_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _free_instance(ports_of, lock_of=None, first: int = 2, last: int = 60) -> int:
    candidates = list(range(first, last))
    random.shuffle(candidates)
    for n in candidates:
        if lock_of is not None and Path(lock_of(n)).exists():
            continue
        if all(_port_free(port, kind) for port, kind in ports_of(n)):
            return n
    pytest.skip("no free SITL instance number")


def _stop(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)


@pytest.fixture(scope="module")
def arducopter_sitl():
    """A fresh ArduCopter SITL at ``--speedup 5``, ready to arm; yields its SERIAL1 connection string."""
    if shared.arducopter() is None:
        pytest.skip(f"ArduCopter SITL not found at {ARDUCOPTER_BIN}")
    n = _free_instance(lambda i: [(5760 + 10 * i + k, socket.SOCK_STREAM) for k in (0, 2, 3)] +
                       [(5501 + 10 * i, socket.SOCK_DGRAM)])
    run = tempfile.mkdtemp(prefix="arducopter-")
    args = [str(ARDUCOPTER_BIN), "--model", "+", "--speedup", str(SPEEDUP), "--defaults", str(ARDUCOPTER_PARM),
            f"-I{n}", "--home", f"{HOME[0]},{HOME[1]},0,0", "--wipe", "--serial0", "tcp:0"]
    with open(Path(run) / "out.txt", "wb") as out:
        proc = subprocess.Popen(args, cwd=run, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        connection = f"tcp:127.0.0.1:{5762 + 10 * n}"
        probe = Probe(connection)
        try:
            streams = [M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT]
            for msg_id in streams:
                assert probe.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 2e5).result == 0
            probe.wait_for("LOCAL_POSITION_NED", timeout_s=60)  # the EKF uses GPS: ~41 s simulated
            probe.stop_streams(streams)  # intervals outlive the TCP connection
            _wait_armable(probe, lambda p: p.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]))
            boot = _boot_times(probe)
        finally:
            probe.close()
        yield Sitl(connection, boot)
    finally:
        _stop(proc)
        shutil.rmtree(run, ignore_errors=True)


@pytest.fixture(scope="module")
def px4_sitl():
    """PX4 SITL (SIH, fast alignment, real time), ready to arm; yields its API-link connection string."""
    px4 = PX4_DIR / "bin" / "px4"
    if shared.px4_dir() is None:
        pytest.skip(f"PX4 SITL not found at {px4}")
    n = _free_instance(lambda i: [(14540 + i, socket.SOCK_DGRAM), (14580 + i, socket.SOCK_DGRAM),
                                  (18570 + i, socket.SOCK_DGRAM), (19450 + i, socket.SOCK_DGRAM)],
                       lock_of=lambda i: f"/tmp/px4_lock-{i}", first=3, last=9)
    run = Path(tempfile.mkdtemp(prefix="px4-"))
    (run / "bin").mkdir()
    os.symlink(px4, run / "bin" / "px4")
    for entry in (PX4_DIR / "bin").iterdir():  # the command links: px4-<module> -> px4
        if entry.name.startswith("px4-"):
            os.symlink(entry if entry.suffix == ".sh" else "px4", run / "bin" / entry.name)
    env = dict(os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIM_MODEL="sihsim_quadx", PX4_HOME_LAT=str(HOME[0]),
               PX4_HOME_LON=str(HOME[1]), PX4_HOME_ALT="0", PX4_EKF2_FAST_ALIGN="1")
    connection = f"udpin:127.0.0.1:{14540 + n}"  # PX4's API link sends to 127.0.0.1:14540+N
    with open(run / "out.txt", "wb") as out:
        proc = subprocess.Popen(["bin/px4", "-d", "-i", str(n), str(PX4_DIR / "etc")], cwd=run, env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        probe = Probe(connection)
        try:
            _wait_armable(probe, lambda p: p.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 3))
            boot = _boot_times(probe)
        finally:
            probe.close()
        yield Sitl(connection, boot)
    finally:
        _stop(proc)
        shutil.rmtree(run, ignore_errors=True)


@dataclasses.dataclass
class Sitl:
    """A running SITL: where to connect, and when (its own clock, s) its boot produced what."""

    connection: str
    boot: dict


def _boot_times(probe: Probe) -> dict:
    """First GPS position, home and local position in the autopilot's own clock (s since boot)."""
    gpi = [m.time_boot_ms / 1000 for m in probe.of_type("GLOBAL_POSITION_INT") if m.lat != 0]
    lpn = [m.time_boot_ms / 1000 for m in probe.of_type("LOCAL_POSITION_NED")]
    home = [m.time_usec / 1e6 for m in probe.of_type("HOME_POSITION")]
    return {"global_position_s": min(gpi, default=None), "home_s": min(home, default=None),
            "local_position_s": min(lpn, default=None)}


def _wait_armable(probe: Probe, select_mode, timeout_s: float = 60.0) -> None:
    """Arm until accepted (then disarm): the autopilot has booted."""
    deadline = time.monotonic() + timeout_s
    while True:
        select_mode(probe)
        ack = probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if ack.result == M.MAV_RESULT_ACCEPTED:
            probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
            return
        if time.monotonic() > deadline:
            raise TimeoutError(f"SITL not armable within {timeout_s} s")
        time.sleep(1.0)


@contextlib.contextmanager
def probing(connection: str):
    probe = Probe(connection)
    try:
        yield probe
    finally:
        probe.close()


@pytest.fixture
def sim_probe(sim_start):
    """``sim_probe(**config)`` -> a Probe on a started, ready sim."""
    probes = []

    def start(**kwargs) -> Probe:
        kwargs.setdefault("speedup", SPEEDUP)
        sim = sim_start(**kwargs)
        probe = Probe(f"tcp:127.0.0.1:{sim.port}")
        probes.append(probe)
        sim.wait_until(lambda s: s["ready"], 10)
        probe.sim = sim
        return probe

    yield start
    for probe in probes:
        probe.close()


# ---------------------------------------------------------------------------------------------- fingerprints
def streamed_unasked(probe: Probe, wall_s: float) -> set[str]:
    """Kinds of message a fresh link gets from the vehicle in ``wall_s`` without asking for anything."""
    since = probe.mark()
    time.sleep(wall_s)
    return {m.get_type() for m in probe.from_vehicle(since)}


def command_results(probe: Probe, commands: list) -> list[tuple]:
    out = []
    for command, *params in commands:
        ack = probe.command(command, *params)
        out.append((command, ack.result, ack.target_system, ack.target_component))
    return out


def mode_flags(probe: Probe, requests: dict) -> dict:
    """HEARTBEAT (custom_mode, base_mode) after each DO_SET_MODE request."""
    out = {}
    for name, params in requests.items():
        assert probe.command(M.MAV_CMD_DO_SET_MODE, *params).result == M.MAV_RESULT_ACCEPTED, name
        since = probe.mark()
        probe.heartbeat(since)
        hb = probe.heartbeat(probe.mark())  # the next one surely reflects the change
        out[name] = (hb.custom_mode, hb.base_mode, hb.system_status)
    return out


def param_fingerprint(probe: Probe, names) -> dict:
    """Per name: the PARAM_VALUE's value bytes as sent (float32), its type, and whether the index is 65535."""
    out = {}
    for name in names:
        pv = probe.param(name)
        out[name] = (struct.pack("<f", pv.param_value).hex(), pv.param_type, pv.param_index == 65535)
    return out


def landed_states(probe: Probe, since: int) -> list[int]:
    states = [m.landed_state for m in probe.of_type("EXTENDED_SYS_STATE", since)]
    return [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]


def clock_s(probe: Probe, since: int = 0) -> float:
    """The autopilot's own clock now (s since boot), from the last timestamped message it sent."""
    for m in reversed(probe.from_vehicle(since)):
        if hasattr(m, "time_boot_ms"):
            return m.time_boot_ms / 1000
    raise AssertionError("no timestamped message")


# ---------------------------------------------------------------------------------------------- ArduCopter
def test_arducopter_boot_follows_the_sims_arducopter_preset(arducopter_sitl):
    """The boot this module's SITL just went through, against the sim's ``arducopter`` preset (+-20 %)."""
    preset = sim_boot.PRESETS["arducopter"]
    real = arducopter_sitl.boot
    assert real["home_s"] == pytest.approx(preset.home_s, rel=0.2)
    assert real["local_position_s"] == pytest.approx(preset.local_position_s, rel=0.2)
    assert real["global_position_s"] == pytest.approx(preset.gps_fix_s, rel=0.2)


def test_arducopter_streams_the_same_on_a_fresh_link(arducopter_sitl, sim_probe):
    with probing(arducopter_sitl.connection) as real:
        real_kinds = streamed_unasked(real, 3.0)
    sim_kinds = streamed_unasked(sim_probe(autopilot="ardupilot"), 3.0)
    ignore = {"TIMESYNC", "PARAM_VALUE", "STATUSTEXT"}  # KNOWN_DIFFERENCES
    assert real_kinds - ignore == sim_kinds - ignore == {"HEARTBEAT"}


def test_arducopter_result_codes_mode_numbers_and_params(arducopter_sitl, sim_probe):
    sim = sim_probe(autopilot="ardupilot")
    modes = {name: (1, ACM[name]) for name in ("GUIDED", "LOITER", "LAND", "RTL", "ALT_HOLD", "POSHOLD", "BRAKE",
                                               "STABILIZE")}
    names = list(sim_params.ARDUPILOT_PARAMS)
    with probing(arducopter_sitl.connection) as real:
        real_results = command_results(real, ARDU_COMMANDS)
        real_modes = mode_flags(real, modes)
        real_params = param_fingerprint(real, names)
        real_refusals = _ardu_refusals(real)
    assert command_results(sim, ARDU_COMMANDS) == real_results
    assert mode_flags(sim, modes) == real_modes
    assert param_fingerprint(sim, names) == real_params
    assert _ardu_refusals(sim) == real_refusals


def _ardu_refusals(probe: Probe) -> list:
    out = []
    for mode in ("LAND", "RTL", "BRAKE", "SMART_RTL", "AUTO"):
        assert probe.command(M.MAV_CMD_DO_SET_MODE, 1, ACM[mode]).result == M.MAV_RESULT_ACCEPTED
        since = probe.mark()
        ack = probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        time.sleep(0.2)
        out.append((mode, ack.result, [t for t in probe.texts(since) if t.startswith("Arm:")]))
    probe.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["STABILIZE"])
    return out


def test_arducopter_auto_disarm_and_guided_arming_without_setpoints(arducopter_sitl, sim_probe):
    def run(probe: Probe) -> tuple:
        probe.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_SYSTEM_TIME, 2e5)
        assert probe.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0
        since = probe.mark()
        ack = probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        probe.wait_for("SYSTEM_TIME", since=since)
        armed_at = clock_s(probe, since)
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Disarming motors", timeout_s=5, since=since)
        held = clock_s(probe, since) - armed_at
        probe.stop_streams([M.MAVLINK_MSG_ID_SYSTEM_TIME])
        return ack.result, [t for t in probe.texts(since) if "motors" in t], round(held)

    with probing(arducopter_sitl.connection) as real:
        expected = run(real)
    assert run(sim_probe(autopilot="ardupilot")) == expected
    assert expected == (M.MAV_RESULT_ACCEPTED, ["Arming motors", "Disarming motors"], 10)


def test_arducopter_takeoff_guid_timeout_gcs_loss_and_landing(arducopter_sitl, sim_probe):
    """Takeoff to 10 m; one position+velocity target 10 m ahead at 2 m/s, then silence (SITL: 16 m); no GCS
    heartbeat for 8 s with FS_GCS_ENABLE 0 (SITL: stays GUIDED, armed); LAND; landed-state sequence."""

    def run(probe: Probe) -> tuple:
        probe.heartbeats(SPEEDUP)  # 1 Hz simulated
        since = probe.mark()
        for msg_id, hz in ((M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 10), (M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 10)):
            probe.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)
        probe.wait_for("EXTENDED_SYS_STATE", since=since)  # on the ground, before the takeoff
        assert probe.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0
        assert probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert probe.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 10).result == 0
        probe.wait_for("LOCAL_POSITION_NED", lambda m: m.z < -9.9, timeout_s=15, since=since)
        time.sleep(0.5)
        lpn = probe.of_type("LOCAL_POSITION_NED")[-1]
        probe.conn.mav.set_position_target_local_ned_send(0, *probe.target, M.MAV_FRAME_LOCAL_NED,
                                                          0b0000_1101_1100_0000, lpn.x + 10, lpn.y, -10, 2, 0, 0,
                                                          0, 0, 0, 0, 0)
        probe.heartbeats(None)
        time.sleep(8 / SPEEDUP + 3.0)
        end = probe.of_type("LOCAL_POSITION_NED")[-1]
        hb = probe.heartbeat(probe.mark())
        probe.heartbeats(SPEEDUP)
        after_silence = (hb.custom_mode, bool(hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED))
        assert probe.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, 0, 0, 0).result == 0
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Disarming motors", timeout_s=30, since=since)
        time.sleep(0.5)
        probe.heartbeats(None)
        probe.stop_streams([M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE])
        return round(end.x - lpn.x), after_silence, landed_states(probe, since)

    with probing(arducopter_sitl.connection) as real:
        expected = run(real)
    # What SITL did (16 m out on the last tangent; GUIDED and armed after the silence; the landed states).
    assert expected == (16, (ACM["GUIDED"], True), [M.MAV_LANDED_STATE_ON_GROUND, M.MAV_LANDED_STATE_TAKEOFF,
                                                    M.MAV_LANDED_STATE_IN_AIR, M.MAV_LANDED_STATE_LANDING,
                                                    M.MAV_LANDED_STATE_ON_GROUND])
    assert run(sim_probe(autopilot="ardupilot")) == expected


# ---------------------------------------------------------------------------------------------- PX4
def test_px4_boot_follows_the_sims_fast_align_preset(px4_sitl):
    """PX4 with PX4_EKF2_FAST_ALIGN: home and global position against the sim's ``px4-fast-align`` preset."""
    preset = sim_boot.PRESETS["px4-fast-align"]
    real = px4_sitl.boot
    # PX4 SITL runs in real time, so its boot wanders with the machine's load: HOME_POSITION measured 1.3-2.4 s
    assert real["home_s"] == pytest.approx(preset.home_s, abs=1.5)
    assert real["global_position_s"] == pytest.approx(preset.global_position_s, abs=1.5)
    assert real["local_position_s"] < real["global_position_s"]


PX4_BUILT = {M.mavlink_map[msg_id].msgname for msg_id in sim_streams.PX4_ONBOARD_RATES_HZ}


def test_px4_streams_the_same_on_the_api_link(px4_sitl, sim_probe):
    with probing(px4_sitl.connection) as real:
        real_kinds = streamed_unasked(real, 3.0)
    sim_kinds = streamed_unasked(sim_probe(), 3.0)
    # The sim builds a subset of PX4's stream list (KNOWN_DIFFERENCES): compare on what it builds; the 0.5 Hz
    # ones may miss a 3 s window on either side.
    slow = {"HOME_POSITION", "BATTERY_STATUS"}
    assert real_kinds & PX4_BUILT - slow == sim_kinds & PX4_BUILT - slow == PX4_BUILT - slow


def test_px4_result_codes_mode_numbers_and_params(px4_sitl, sim_probe):
    sim = sim_probe(strict=True)
    modes = {"LOITER": (1, 4, 3), "POSCTL": (1, 3, 0), "OFFBOARD": (1, 6, 0), "LAND": (1, 4, 6), "RTL": (1, 4, 5),
             "TAKEOFF": (1, 4, 2)}
    names = list(sim_params.PX4_PARAMS)
    with probing(px4_sitl.connection) as real:
        real_results = command_results(real, PX4_COMMANDS)
        real_modes = mode_flags(real, modes)
        real_params = param_fingerprint(real, names)
        real_refusals = _px4_refusals(real)
    assert command_results(sim, PX4_COMMANDS) == real_results
    assert {k: v[:2] for k, v in mode_flags(sim, modes).items()} == {k: v[:2] for k, v in real_modes.items()}
    assert param_fingerprint(sim, names) == real_params
    assert _px4_refusals(sim) == real_refusals


def _px4_refusals(probe: Probe) -> list:
    out = []
    for name, params in (("OFFBOARD", (1, 6, 0)), ("POSCTL", (1, 3, 0)), ("LAND", (1, 4, 6))):
        assert probe.command(M.MAV_CMD_DO_SET_MODE, *params).result == M.MAV_RESULT_ACCEPTED  # disarmed: any mode
        since = probe.mark()
        ack = probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        time.sleep(0.3)
        out.append((name, ack.result, "".join(t for t in probe.texts(since) if "denied" in t or t == "t\t")))
    probe.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 3)
    return out


def climb_in_offboard(probe: Probe, target: list, speedup: float, since: int) -> None:
    """With setpoints streaming: OFFBOARD, arm, and wait until the vehicle is within 0.3 m of ``target``'s down.

    PX4 answers TEMPORARILY_REJECTED while its health checks settle after the previous test's landing (seen in CI
    under load); a client retries that, so does this probe, for up to 20 s of the autopilot's time."""
    time.sleep(1.0 / speedup)
    assert probe.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 0
    deadline = time.monotonic() + 20.0 / speedup
    while (ack := probe.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)).result == \
            M.MAV_RESULT_TEMPORARILY_REJECTED and time.monotonic() < deadline:
        time.sleep(0.5 / speedup)
    assert ack.result == 0
    probe.wait_for("LOCAL_POSITION_NED", lambda m: m.z < target[2] + 0.3, timeout_s=20, since=since)


def test_px4_offboard_flight_loss_failsafe_landing_and_mode_after_disarm(px4_sitl, sim_probe):
    """Offboard climb to 3 m at 20 Hz (of the autopilot's time), setpoints stop: failsafe; they resume: OFFBOARD
    again; NAV_LAND: landed-state sequence, "Disarmed by landing", and the mode PX4 is in after the disarm."""

    def run(probe: Probe, speedup: float) -> tuple:
        probe.heartbeats(speedup)
        lpn = probe.wait_for("LOCAL_POSITION_NED", since=probe.mark())
        target = [lpn.x, lpn.y, lpn.z - 3.0]
        since = probe.mark()
        with streaming(probe, target, 20.0 * speedup):
            climb_in_offboard(probe, target, speedup, since)
            lost_at = probe.mark()
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Failsafe activated\t", timeout_s=5, since=lost_at)
        hb = probe.heartbeat(probe.mark())
        failsafe_mode = mavutil.interpret_px4_mode(hb.base_mode, hb.custom_mode)
        with streaming(probe, target, 20.0 * speedup):
            back = probe.wait_for("HEARTBEAT", lambda m: m.get_srcSystem() == probe.target[0] and m.custom_mode
                                  == (6 << 16), timeout_s=5, since=probe.mark())
            assert back is not None
            assert probe.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Disarmed by landing\t", timeout_s=40, since=since)
        hb = probe.heartbeat(probe.mark())
        probe.heartbeats(None)
        texts = [t for t in probe.texts(since) if t in ("Failsafe activated\t", "Landing detected\t",
                                                         "Disarmed by landing\t", "Armed by external command\t")]
        return (failsafe_mode, landed_states(probe, since), mavutil.interpret_px4_mode(hb.base_mode, hb.custom_mode),
                list(dict.fromkeys(texts)))

    with probing(px4_sitl.connection) as real:
        expected = run(real, 1.0)  # PX4 SITL runs in real time
    assert expected[0] == "POSCTL" and expected[2] == "OFFBOARD"  # what PX4 did: COM_OBL_RC_ACT 0; back to OFFBOARD
    assert run(sim_probe(strict=True, speedup=4.0), 4.0) == expected


def test_px4_offboard_loss_without_rc_descends_in_position_mode_and_lands(px4_sitl, sim_probe):
    """Offboard climb to 5 m, setpoints stop for good: with COM_OBL_RC_ACT 0 and no RC, PX4 goes to position mode
    and comes down where it is (measured: 0.6-1.15 m/s, "Disarmed by landing"); the sim does the same. The client's
    link-loss warning rests on this (skyroute/vehicle/limits.py)."""

    def run(probe: Probe, speedup: float) -> tuple:
        probe.heartbeats(speedup)
        lpn = probe.wait_for("LOCAL_POSITION_NED", since=probe.mark())
        ground = lpn.z
        target = [lpn.x, lpn.y, ground - 5.0]
        since = probe.mark()
        with streaming(probe, target, 20.0 * speedup):
            climb_in_offboard(probe, target, speedup, since)
        lost = probe.mark()
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Failsafe activated\t", timeout_s=5, since=lost)
        failsafe = probe.mark()
        probe.wait_for("STATUSTEXT", lambda m: m.text == "Disarmed by landing\t", timeout_s=40, since=lost)
        modes = {mavutil.interpret_px4_mode(m.base_mode, m.custom_mode) for m in probe.of_type("HEARTBEAT", failsafe)
                 if m.get_srcSystem() == probe.target[0] and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED}
        # the descent's speed: band samples moving down (in one CI run most of PX4's samples in the band were level,
        # median -0.08 m/s, and it still landed, disarmed by landing; why it was level there is not known; moving
        # down it went 0.61-0.72 m/s in the next run)
        down = sorted(m.vz for m in probe.of_type("LOCAL_POSITION_NED", lost)
                      if ground - 4.0 < m.z < ground - 1.0 and m.vz > 0.1)
        probe.heartbeats(None)
        texts = [t for t in probe.texts(lost) if t in ("Failsafe activated\t", "Disarmed by landing\t")]
        return modes, (down[len(down) // 2] if len(down) >= 5 else 0.0), list(dict.fromkeys(texts))

    with probing(px4_sitl.connection) as real:
        modes, rate_mps, texts = run(real, 1.0)
    # down, not hovering, and no faster than position mode lets it sink (MPC_Z_VEL_MAX_DN 1.5 m/s): PX4's median
    # moving down has been 0.60, 0.61-0.72, 0.92 and 1.15 m/s in different runs
    assert modes == {"POSCTL"} and 0.3 < rate_mps < 1.5, (modes, rate_mps)
    assert texts == ["Failsafe activated\t", "Disarmed by landing\t"]
    sim_modes, sim_rate_mps, sim_texts = run(sim_probe(strict=True, speedup=4.0), 4.0)
    assert (sim_modes, sim_texts) == (modes, texts)
    # the sim lands at MPC_LAND_SPEED 0.7 m/s, inside PX4's run-to-run spread (0.60-1.15 m/s above)
    assert sim_rate_mps == pytest.approx(rate_mps, abs=0.5)
