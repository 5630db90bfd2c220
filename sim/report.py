"""Truth about the flight: collisions, clearance and the JSON report.

The vehicle is a sphere of radius ``r`` whose lowest point is the vehicle position (so it can sit on
a roof without touching it); its centre is ``r`` above the position. *Clearance* is the distance
from the sphere's surface to the nearest box, i.e. centre distance minus ``r``. Collision means
clearance < 0.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .world import SEARCH_CAP_M, CityMap


@dataclass
class Collision:
    """A sphere/box intersection found by :class:`TruthMonitor` (map frame)."""

    sim_time_s: float
    north_m: float
    east_m: float
    up_m: float
    speed_m_s: float
    box_index: int


class TruthMonitor:
    """Checks the sphere against the true boxes every step, cheaply.

    Exact distances are recomputed only when the triangle-inequality bound from the last exact
    query (``last - moved``) could hide a collision or a new minimum clearance, so the result is the
    same as checking every step exactly.

    Parameters
    ----------
    city : CityMap
        Obstacles.
    radius_m : float
        Vehicle sphere radius (m).
    """

    def __init__(self, city: CityMap, radius_m: float) -> None:
        self.city = city
        self.radius_m = float(radius_m)
        self._last_centre: np.ndarray | None = None
        self._last_distance_m = 0.0
        self.min_clearance_m: float | None = None
        self.min_clearance_at: dict | None = None
        self.exact_queries = 0

    def check(self, position_neu: np.ndarray, airborne: bool, sim_time_s: float, speed_m_s: float):
        """Return a :class:`Collision` if the sphere intersects a box this step, else None."""
        if not airborne:
            return None
        r = self.radius_m
        centre = position_neu + np.array([0.0, 0.0, r])
        if self._last_centre is not None:
            bound = self._last_distance_m - float(np.linalg.norm(centre - self._last_centre))
            can_improve = self.min_clearance_m is None or bound - r < self.min_clearance_m
            if bound >= r and not can_improve:
                return None
        distance, index = self.city.nearest_box(centre, SEARCH_CAP_M)
        self.exact_queries += 1
        self._last_centre = centre
        self._last_distance_m = distance
        clearance = distance - r
        if self.min_clearance_m is None or clearance < self.min_clearance_m:
            self.min_clearance_m = clearance
            self.min_clearance_at = {
                "sim_time_s": round(sim_time_s, 3),
                "north_m": float(position_neu[0]),
                "east_m": float(position_neu[1]),
                "up_m": float(position_neu[2]),
                "box_index": index,
            }
        if distance < r - 1e-9:
            return Collision(sim_time_s, *(float(v) for v in position_neu), speed_m_s, index)
        return None


class FlightRecorder:
    """Accumulates what the report needs; owned by the simulation thread."""

    def __init__(self, city: CityMap, radius_m: float) -> None:
        self.city = city
        self.truth = TruthMonitor(city, radius_m)
        self.start: dict = {}
        self.home: dict = {}
        self.armed_time_s = 0.0
        self.airborne_time_s = 0.0
        self.distance_flown_m = 0.0
        self.max_up_m: float | None = None
        self.max_height_above_home_m: float | None = None
        self.collisions: list[dict] = []
        self.landings: list[dict] = []
        self.commands: list[dict] = []
        self.events: list[dict] = []
        self.setpoints_received = 0
        self.last_setpoint_sim_time_s: float | None = None
        self.last_gcs_heartbeat_sim_time_s: float | None = None
        self._last_pos: np.ndarray | None = None

    def place(self, north_m: float, east_m: float, up_m: float) -> dict:
        """Position in both map and geodetic terms."""
        lat, lon, alt = self.city.map_to_geodetic(north_m, east_m, up_m)
        return {
            "lat_deg": lat,
            "lon_deg": lon,
            "alt_m": alt,
            "north_m": float(north_m),
            "east_m": float(east_m),
            "up_m": float(up_m),
        }

    def update(
        self, dt_s: float, position_neu: np.ndarray, armed: bool, airborne: bool, home_up_m: float
    ) -> None:
        """Integrate statistics for one physics step (call after the step)."""
        if armed:
            self.armed_time_s += dt_s
        if airborne:
            self.airborne_time_s += dt_s
            up = float(position_neu[2])
            self.max_up_m = up if self.max_up_m is None else max(self.max_up_m, up)
            h = up - home_up_m
            self.max_height_above_home_m = h if self.max_height_above_home_m is None else max(
                self.max_height_above_home_m, h
            )
        if self._last_pos is not None:
            self.distance_flown_m += float(np.linalg.norm(position_neu - self._last_pos))
        self._last_pos = position_neu.copy()

    def add_collision(self, c: Collision) -> dict:
        entry = {"sim_time_s": round(c.sim_time_s, 3), "speed_m_s": c.speed_m_s}
        entry.update(self.place(c.north_m, c.east_m, c.up_m))
        entry["box"] = self.city.box(c.box_index).as_dict() if c.box_index >= 0 else None
        self.collisions.append(entry)
        return entry

    def add_landing(self, sim_time_s: float, position_neu: np.ndarray) -> dict:
        entry = {"sim_time_s": round(sim_time_s, 3)}
        entry.update(self.place(*position_neu))
        self.landings.append(entry)
        return entry

    def add_event(self, sim_time_s: float, kind: str, text: str) -> None:
        self.events.append({"sim_time_s": round(sim_time_s, 3), "kind": kind, "text": text})

    def to_dict(self, final: dict, config: dict, sim_time_s: float, wall_time_s: float) -> dict:
        """The report as a JSON-ready dict (keys documented in ``sim/__init__.py``)."""
        landed = None
        if final.get("on_ground"):
            landed = dict(final["position"])
        elif self.landings:
            landed = {k: v for k, v in self.landings[-1].items() if k != "sim_time_s"}
        min_c = self.truth.min_clearance_m
        return {
            "config": config,
            "sim_time_s": round(sim_time_s, 3),
            "wall_time_s": round(wall_time_s, 3),
            "start": self.start,
            "home": self.home,
            "final": final,
            "landed": landed,
            "landings": self.landings,
            "armed_time_s": round(self.armed_time_s, 3),
            "airborne_time_s": round(self.airborne_time_s, 3),
            "distance_flown_m": self.distance_flown_m,
            "max_altitude_m": self.max_up_m,
            "max_height_above_home_m": self.max_height_above_home_m,
            "min_clearance_m": None if min_c is None else min(min_c, SEARCH_CAP_M),
            "min_clearance_at": self.truth.min_clearance_at,
            "clearance_search_cap_m": SEARCH_CAP_M,
            "crashed": bool(self.collisions) or bool(final.get("crashed")),
            "collisions": self.collisions,
            "commands": self.commands,
            "setpoints_received": self.setpoints_received,
            "last_setpoint_sim_time_s": self.last_setpoint_sim_time_s,
            "last_gcs_heartbeat_sim_time_s": self.last_gcs_heartbeat_sim_time_s,
            "events": self.events,
        }


def write_report(path: str | Path, report: dict) -> Path:
    """Write the report as indented JSON (NaN written as null)."""

    def clean(obj):
        if isinstance(obj, float) and not math.isfinite(obj):
            return None
        if isinstance(obj, dict):
            return {k: clean(v) for k, v in obj.items()}
        if isinstance(obj, (list, tuple)):
            return [clean(v) for v in obj]
        return obj

    path = Path(path)
    path.write_text(json.dumps(clean(report), indent=2) + "\n")
    return path
