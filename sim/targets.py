"""Ground targets (``--targets FILE``): what a downward camera sees, reported as LANDING_TARGET, and the truth.

A targets file is CSV, one target a line, ``north_m,east_m`` in the map frame (metres from the map's lat0/lon0,
as ``colliders.csv``'s boxes); an optional first line ``north_m,east_m`` (or any line starting with ``#``) is
skipped. Targets lie on the map's ground (up 0 m).

The camera looks straight down with a 30 degree half angle: a target is *in view* when the vehicle is at most
``max_altitude_m`` (30 m) above the ground and its horizontal distance to the target is at most
``altitude x tan(30 deg) + 2 m`` (the issue's footprint). While it is, the sim streams one LANDING_TARGET a
target at ``rate_hz`` (simulated), as a precision-landing beacon does: ``frame`` MAV_FRAME_LOCAL_NED, ``x, y,
z`` the target's position in the autopilot's local frame (m), ``position_valid`` 1, ``target_num`` the target's
index (0-based, file order), ``distance`` the slant range (m), ``angle_x``/``angle_y`` its angles off the
camera's axis (rad, north and east). A target is *visited* when the vehicle is within ``visit_radius_m`` (3 m)
horizontally at no more than ``visit_altitude_m`` (3 m) above it (the issue's "collect").

The report's ``targets`` entry lists each target with ``first_seen_s`` and ``visited_s`` (simulated seconds,
None if never).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as M

HALF_ANGLE_RAD = math.radians(30.0)
FOOTPRINT_MARGIN_M = 2.0
MAX_TARGETS = 1000


class TargetFileError(ValueError):
    """A targets file that cannot be read: ``"<file>:<line>: <why>"``."""


def read_targets(path: str | Path) -> tuple[tuple[float, float], ...]:
    """The ``(north_m, east_m)`` targets of a targets file (see the module notes).

    Raises
    ------
    TargetFileError
        Naming the file and the line (not two finite numbers, too many targets); OSError when unreadable.
    """
    p = Path(path)
    if not p.is_file():
        raise TargetFileError(f"{p}: not a regular file")
    out: list[tuple[float, float]] = []
    for number, line in enumerate(p.read_text(encoding="utf-8", errors="replace").split("\n"), start=1):
        text = line.strip()
        if not text or text.startswith("#") or (number == 1 and text.replace(" ", "").lower() == "north_m,east_m"):
            continue
        parts = [s.strip() for s in text.split(",")]
        try:
            if len(parts) != 2:
                raise ValueError
            north, east = float(parts[0]), float(parts[1])
        except ValueError:
            raise TargetFileError(f"{p}:{number}: expected 'north_m,east_m', got {text[:60]!r}") from None
        if not (math.isfinite(north) and math.isfinite(east)) or max(abs(north), abs(east)) > 1e6:
            raise TargetFileError(f"{p}:{number}: coordinates must be finite and within 1e6 m, got {text[:60]!r}")
        out.append((north, east))
        if len(out) > MAX_TARGETS:
            raise TargetFileError(f"{p}:{number}: more than {MAX_TARGETS} targets")
    return tuple(out)


def footprint_radius_m(altitude_m: float) -> float:
    """Horizontal radius (m) in which the camera sees a ground target from ``altitude_m`` above it.

    >>> round(footprint_radius_m(5.0), 3), footprint_radius_m(-1.0)
    (4.887, 2.0)
    """
    return max(altitude_m, 0.0) * math.tan(HALF_ANGLE_RAD) + FOOTPRINT_MARGIN_M


@dataclass(frozen=True)
class TargetConfig:
    """``rate_hz`` LANDING_TARGET rate while in view (simulated); the camera's ``max_altitude_m``; the visit box."""

    rate_hz: float = 5.0
    max_altitude_m: float = 30.0
    visit_radius_m: float = 3.0
    visit_altitude_m: float = 3.0


class GroundTargets:
    """The targets, what the camera sees of them, and when each was first seen and visited (simulated time)."""

    def __init__(self, targets_ne, config: TargetConfig | None = None) -> None:
        self.config = config or TargetConfig()
        self.ne = np.asarray(targets_ne, float).reshape(-1, 2)
        self.first_seen_s: list[float | None] = [None] * len(self.ne)
        self.visited_s: list[float | None] = [None] * len(self.ne)
        self.closest_m: list[float | None] = [None] * len(self.ne)  # horizontal, while at <= visit altitude
        self.in_view = np.zeros(len(self.ne), bool)
        self._sent_s = -math.inf
        self.reports_sent = 0

    def step(self, sim_time_s: float, position_neu) -> None:
        """Update what is in view from the vehicle at map ``position_neu`` (north, east, up m)."""
        if len(self.ne) == 0:
            return
        n, e, up = (float(v) for v in position_neu)
        horizontal = np.hypot(self.ne[:, 0] - n, self.ne[:, 1] - e)
        cfg = self.config
        self.in_view = (up <= cfg.max_altitude_m) & (horizontal <= footprint_radius_m(up))
        low = up <= cfg.visit_altitude_m
        for k in np.flatnonzero(self.in_view):
            if self.first_seen_s[k] is None:
                self.first_seen_s[k] = round(sim_time_s, 3)
        if low:
            for k in range(len(self.ne)):
                d = float(horizontal[k])
                if self.closest_m[k] is None or d < self.closest_m[k]:
                    self.closest_m[k] = round(d, 3)
                if d <= cfg.visit_radius_m and self.visited_s[k] is None:
                    self.visited_s[k] = round(sim_time_s, 3)

    def messages(self, sim_time_s: float, position_neu, origin_neu, local_scale=(1.0, 1.0, 1.0)) -> list:
        """LANDING_TARGET messages due now (one per target in view, at ``rate_hz``); ``origin_neu`` is the
        autopilot's local origin in the map frame, ``local_scale`` its local metres per map metre."""
        if not self.in_view.any() or sim_time_s - self._sent_s < 1.0 / self.config.rate_hz - 1e-9:
            return []
        self._sent_s = sim_time_s
        n, e, up = (float(v) for v in position_neu)
        out = []
        for k in np.flatnonzero(self.in_view):
            tn, te = (float(v) for v in self.ne[k])
            dn, de, height = tn - n, te - e, max(up, 1e-3)
            local = ((tn - float(origin_neu[0])) * local_scale[0], (te - float(origin_neu[1])) * local_scale[1],
                     float(origin_neu[2]) - 0.0)
            out.append(M.MAVLink_landing_target_message(
                int(sim_time_s * 1e6), int(k), M.MAV_FRAME_LOCAL_NED, math.atan2(dn, height),
                math.atan2(de, height), math.sqrt(dn * dn + de * de + up * up), 0.5, 0.5,
                x=local[0], y=local[1], z=local[2], q=[1.0, 0.0, 0.0, 0.0],
                type=M.LANDING_TARGET_TYPE_VISION_OTHER, position_valid=1))
        self.reports_sent += len(out)
        return out

    def report(self) -> list[dict]:
        """The report's ``targets`` entry."""
        return [{"index": k, "north_m": float(self.ne[k, 0]), "east_m": float(self.ne[k, 1]),
                 "first_seen_s": self.first_seen_s[k], "visited_s": self.visited_s[k],
                 "closest_low_m": self.closest_m[k]} for k in range(len(self.ne))]
