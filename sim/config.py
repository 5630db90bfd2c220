"""Simulator settings shared by the CLI and the in-process API."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .boot import BootTimeline, resolve_boot
from .faults import FaultConfig
from .params import ParamTable
from .sensors import SensorConfig
from .signing import secret_key

#: A ``start`` may lie this far (m) outside the map's extent (its boxes' footprints and home).
START_MARGIN_M = 50.0
#: The project root is the parent of the ``sim`` package.
PROJECT_ROOT = Path(__file__).resolve().parent.parent


def default_map_path() -> Path:
    """``colliders.csv`` in the project root, else in the current directory."""
    candidate = PROJECT_ROOT / "colliders.csv"
    if candidate.exists():
        return candidate
    return Path.cwd() / "colliders.csv"


@dataclass(frozen=True)
class SimConfig:
    """Settings of one simulator instance.

    Attributes
    ----------
    map_path : Path or None
        ``colliders.csv`` to load; None means :func:`default_map_path`.
    host, port : str, int
        TCP listen address; port 0 picks a free ephemeral port (see ``Simulator.port``).
    speedup : float
        Simulated seconds per wall-clock second, in (0, 1000].
    start : (lat_deg, lon_deg) or (lat_deg, lon_deg, alt_m) or None
        Where the vehicle boots: on the surface at or below ``alt_m`` (m above the map datum, default 0: the
        ground; give a roof's height to boot on the roof); None = the map's home on the ground. It must lie
        on the map (within its extent plus :data:`START_MARGIN_M`) and not inside a building.
    report_path, tlog_path : Path or None
        JSON report written on stop; MAVLink telemetry log written while running.
    autopilot : {"px4", "ardupilot"}
        Personality (mode table, HEARTBEAT autopilot type).
    strict : bool
        PX4 as the real one: NED z only, arming in OFFBOARD needs a fresh setpoint stream, and without
        setpoints for ``COM_OF_LOSS_T`` (1.0 simulated s) the offboard failsafe ``COM_OBL_RC_ACT`` acts.
    origin : {"home", "boot"}
        Local NED origin: the current home position (moves with DO_SET_HOME and with every arming, as home
        does), or the EKF origin where the vehicle booted (as the real autopilots' LOCAL_POSITION_NED).
    radius_m : float
        Vehicle sphere radius for collisions (m).
    wind_m_s : (north, east)
        Mean wind velocity (m/s, direction the air moves towards).
    gust_m_s : float
        Standard deviation of wind gusts (m/s), per horizontal axis.
    gps_noise_m : float
        Standard deviation of the position estimate's error (m), a Gauss-Markov drift with ``gps_correlation_s``
        correlation, smoothed over 2 s as an estimator fusing an IMU smooths it (``sim.autopilot._drift_gps``): the
        reported position carries it, and the autopilot flies its estimate, so the vehicle itself is off every
        commanded position by its horizontal part (collisions use the truth).
    gps_correlation_s : float
        The drift's correlation time (s): 60 by default, PX4 SITL's GPS model (Gazebo's gps plugin); shorter is
        harsher (10 s moves a landing vehicle's estimate by the whole spread over its 7 s descent).
    seed : int
        Seed for wind, GPS noise and packet loss.
    physics_dt_s : float
        Fixed physics step (simulated seconds).
    faults : FaultConfig
        Fault injection (all off by default).
    boot : str or BootTimeline
        Boot timeline: a preset of :mod:`sim.boot` (``fast``, ``instant``, ``arducopter``, ``px4``,
        ``px4-fast-align``), ``key=seconds`` pairs, or a :class:`BootTimeline`.
    params : dict
        ``{name: value}`` parameter overrides at boot (names of :mod:`sim.params` for the personality).
    signing_key : str or None
        MAVLink 2 signing key (:func:`sim.signing.secret_key`); None = no signing.
    scale_timeouts : bool
        Multiply the link-loss timeouts (COM_OF_LOSS_T, COM_DL_LOSS_T, FS_GCS_TIMEOUT) by the speedup, as PX4's
        SITL startup does with PX4_SIM_SPEED_FACTOR, for clients that pace their streams in wall-clock time.
    sensor : SensorConfig
        The obstacle sensors (:mod:`sim.sensors`; on by default).
    targets : tuple of (north_m, east_m)
        Ground targets the downward camera reports (:mod:`sim.targets`); none by default.
    """

    map_path: Path | None = None
    host: str = "127.0.0.1"
    port: int = 5760
    speedup: float = 1.0
    start: tuple[float, float] | None = None
    report_path: Path | None = None
    tlog_path: Path | None = None
    autopilot: str = "px4"
    strict: bool = False
    origin: str = "home"
    radius_m: float = 0.3
    wind_m_s: tuple[float, float] = (0.0, 0.0)
    gust_m_s: float = 0.0
    gps_noise_m: float = 0.0
    gps_correlation_s: float = 60.0
    seed: int = 0
    physics_dt_s: float = 0.02
    faults: FaultConfig = field(default_factory=FaultConfig)
    boot: str | BootTimeline = "fast"
    params: dict = field(default_factory=dict)
    signing_key: str | None = None
    scale_timeouts: bool = False
    sensor: SensorConfig = field(default_factory=SensorConfig)
    targets: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.autopilot not in ("px4", "ardupilot"):
            raise ValueError(f"autopilot must be 'px4' or 'ardupilot', not {self.autopilot!r}")
        if self.origin not in ("home", "boot"):
            raise ValueError(f"origin must be 'home' or 'boot', not {self.origin!r}")
        if not 0 < self.speedup <= 1000:  # also refuses NaN
            raise ValueError(f"speedup must be in (0, 1000], not {self.speedup}")
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port must be in [0, 65535], not {self.port}")
        if self.start is not None:
            if len(self.start) not in (2, 3) or not all(math.isfinite(v) for v in self.start):
                raise ValueError(f"start must be LAT,LON or LAT,LON,ALT in finite numbers, not {self.start}")
            if not (-90 <= self.start[0] <= 90 and -180 <= self.start[1] <= 180):
                raise ValueError(f"start must be LAT,LON within [-90, 90] x [-180, 180], not {self.start}")
            if len(self.start) == 3 and not -1000.0 <= self.start[2] <= 10_000.0:
                raise ValueError(f"start altitude must be in [-1000, 10000] m, not {self.start[2]}")
        for name in ("report_path", "tlog_path"):
            path = getattr(self, name)
            if path is not None and not Path(path).resolve().parent.is_dir():
                folder = Path(path).resolve().parent
                raise ValueError(f"{name.replace('_path', '')} {path}: {folder} is not a directory")
        if not 0 < self.physics_dt_s <= 0.1:
            raise ValueError(f"physics_dt_s must be in (0, 0.1], not {self.physics_dt_s}")
        if not 0 <= self.radius_m <= 100:
            raise ValueError(f"radius must be in [0, 100] m, not {self.radius_m}")
        if len(self.wind_m_s) != 2 or not all(math.isfinite(v) and abs(v) <= 100 for v in self.wind_m_s):
            raise ValueError(f"wind must be two finite speeds within +-100 m/s, not {self.wind_m_s}")
        if not 0 <= self.gust_m_s <= 100:
            raise ValueError(f"gust must be in [0, 100] m/s, not {self.gust_m_s}")
        if not 0 <= self.gps_noise_m <= 1000:
            raise ValueError(f"gps noise must be in [0, 1000] m, not {self.gps_noise_m}")
        if not 1 <= self.gps_correlation_s <= 3600:
            raise ValueError(f"gps correlation must be in [1, 3600] s, not {self.gps_correlation_s}")
        resolve_boot(self.boot)
        ParamTable(self.autopilot, self.params)  # unknown names and non-finite values
        if self.signing_key is not None:
            secret_key(self.signing_key)

    def resolved_map_path(self) -> Path:
        return Path(self.map_path) if self.map_path is not None else default_map_path()

    def as_dict(self) -> dict:
        """JSON-ready copy (paths as strings)."""
        out = asdict(self)
        for key in ("map_path", "report_path", "tlog_path"):
            out[key] = None if out[key] is None else str(out[key])
        out["map_path"] = str(self.resolved_map_path())
        out["faults"]["deny_commands"] = list(self.faults.deny_commands)
        out["boot"] = resolve_boot(self.boot).as_dict()
        out["boot_name"] = self.boot if isinstance(self.boot, str) else "custom"
        out["signing_key"] = None if self.signing_key is None else "(set)"
        return out
