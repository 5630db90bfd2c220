"""Simulator settings shared by the CLI and the in-process API."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

from .faults import FaultConfig

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
        Simulated seconds per wall-clock second.
    start : (lat_deg, lon_deg) or None
        Where the vehicle boots (on the ground or roof there); None = at home.
    report_path, tlog_path : Path or None
        JSON report written on stop; MAVLink telemetry log written while running.
    autopilot : {"px4", "ardupilot"}
        Personality (mode table, HEARTBEAT autopilot type).
    strict : bool
        PX4-like: NED z only, offboard needs a fresh setpoint stream and falls back to hold after
        ``COM_OF_LOSS_T`` (0.5 s wall clock) without setpoints.
    origin : {"home", "boot"}
        Local NED origin: the home position (follows DO_SET_HOME) or where the vehicle booted.
    radius_m : float
        Vehicle sphere radius for collisions (m).
    wind_m_s : (north, east)
        Mean wind velocity (m/s, direction the air moves towards).
    gust_m_s : float
        Standard deviation of wind gusts (m/s), per horizontal axis.
    gps_noise_m : float
        Standard deviation of reported-position noise (m), 1-order Gauss-Markov with 10 s correlation.
    seed : int
        Seed for wind, GPS noise and packet loss.
    physics_dt_s : float
        Fixed physics step (simulated seconds).
    faults : FaultConfig
        Fault injection (all off by default).
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
    seed: int = 0
    physics_dt_s: float = 0.02
    faults: FaultConfig = field(default_factory=FaultConfig)

    def __post_init__(self) -> None:
        if self.autopilot not in ("px4", "ardupilot"):
            raise ValueError(f"autopilot must be 'px4' or 'ardupilot', not {self.autopilot!r}")
        if self.origin not in ("home", "boot"):
            raise ValueError(f"origin must be 'home' or 'boot', not {self.origin!r}")
        if not 0 < self.speedup <= 1000:  # also refuses NaN
            raise ValueError(f"speedup must be in (0, 1000], not {self.speedup}")
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port must be in [0, 65535], not {self.port}")
        if self.start is not None and not (-90 <= self.start[0] <= 90 and -180 <= self.start[1] <= 180):
            raise ValueError(f"start must be LAT,LON within [-90, 90] x [-180, 180], not {self.start}")
        for name in ("report_path", "tlog_path"):
            path = getattr(self, name)
            if path is not None and not Path(path).resolve().parent.is_dir():
                folder = Path(path).resolve().parent
                raise ValueError(f"{name.replace('_path', '')} {path}: {folder} is not a directory")
        if not 0 < self.physics_dt_s <= 0.1:
            raise ValueError(f"physics_dt_s must be in (0, 0.1], not {self.physics_dt_s}")
        if not self.radius_m >= 0:
            raise ValueError(f"radius_m must be >= 0, not {self.radius_m}")

    def resolved_map_path(self) -> Path:
        return Path(self.map_path) if self.map_path is not None else default_map_path()

    def as_dict(self) -> dict:
        """JSON-ready copy (paths as strings)."""
        out = asdict(self)
        for key in ("map_path", "report_path", "tlog_path"):
            out[key] = None if out[key] is None else str(out[key])
        out["map_path"] = str(self.resolved_map_path())
        out["faults"]["deny_commands"] = list(self.faults.deny_commands)
        return out
