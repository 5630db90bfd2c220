"""Flying through a city that differs from its map: the mission's sensing step and its replan records.

The mission never imports the vehicle package nor planning (rule 3): the vehicle offers its sensor readings
(``vehicle.sensor_readings()``: a list of readings drained since the last call, and ``vehicle.sensing`` True while
the autopilot streams obstacle data), and the command line injects an :class:`ObstacleMap` (the planning side's
``Replanner``: a live occupancy layer over the planning grid and the replanning on it). :class:`Sensing` joins the
two each poll: it feeds every horizontal reading to the map at the vehicle's map position and checks the rest of
the path; the mission turns a blockage into PATH_BLOCKED -> REPLANNING -> WAYPOINT (see ``states``), braking to a
hold first when the vehicle could not stop short of the obstacle (:func:`can_turn_in_time`).

Latency: a :class:`ReplanRecord`'s ``latency_ms`` runs from the arrival of the oldest reading of the poll that
found the blockage (our monotonic clock, stamped by the link's reader) to the first setpoint of the new path.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

log = logging.getLogger(__name__)


class Blockage(Protocol):
    """Where the remaining path meets an observed obstacle: ``reason`` "blocked" or "margin", ``along_m`` along
    the remaining path, ``point_ne`` the map point."""

    reason: str
    along_m: float
    point_ne: tuple[float, float]


class Route(Protocol):
    """A new route: ``waypoints`` (K, 4) map frame from the vehicle's position, ``plan_ms`` its planning time."""

    waypoints: np.ndarray
    plan_ms: float


class ObstacleMap(Protocol):
    """What the mission needs of the live layer and its replanner (``skyroute.planning.replan.Replanner``)."""

    def add_scan(self, north_m: float, east_m: float, bearings_rad, half_width_rad: float, distances_m,
                 max_range_m: float) -> object: ...

    def check(self, position_ne: Sequence[float], waypoints_ne: np.ndarray) -> Blockage | None: ...

    def replan(self, position_ne: Sequence[float]) -> Route: ...

    def route_to(self, position_ne: Sequence[float], target_ne: Sequence[float]) -> Route: ...

    def discovered_ne(self) -> np.ndarray: ...


@dataclass(frozen=True)
class ReplanRecord:
    """One replan: ``time_s`` (our clock), where (map ``north_m``, ``east_m``), ``reason`` and ``along_m`` of the
    blockage, ``plan_ms`` the planning, ``latency_ms`` reading in -> new setpoint out, ``braked`` whether the
    vehicle stopped first, ``waypoints`` the new route (None when the replan failed), ``outcome`` "replanned",
    "goal blocked" / "goal unreachable" (with the error text)."""

    time_s: float
    north_m: float
    east_m: float
    reason: str
    along_m: float
    plan_ms: float
    latency_ms: float
    braked: bool
    waypoints: np.ndarray | None
    outcome: str = "replanned"

    def describe(self) -> str:
        """One log line."""
        what = (f"{self.outcome}: {len(self.waypoints)} waypoints" if self.waypoints is not None else self.outcome)
        return (f"path {self.reason} {self.along_m:.1f} m ahead at ({self.north_m:.1f} N, {self.east_m:.1f} E); "
                f"{'braked, then ' if self.braked else ''}{what}, planned in {self.plan_ms:.1f} ms, new setpoint "
                f"{self.latency_ms:.1f} ms after the reading")


def braking_distance_m(speed_mps: float, decel_mps2: float, reaction_s: float = 0.3) -> float:
    """Metres to stop from ``speed_mps``: ``v * reaction_s + v^2 / (2 decel)``.

    >>> round(braking_distance_m(10.0, 3.0), 2)
    19.67
    """
    v = max(float(speed_mps), 0.0)
    return v * reaction_s + v * v / (2.0 * max(float(decel_mps2), 1e-6))


def can_turn_in_time(blockage: Blockage | None, speed_mps: float, decel_mps2: float, safety_m: float,
                     reaction_s: float = 0.3) -> bool:
    """Whether the vehicle can switch to a new route without braking to a stop first: along the path it could
    still stop at least half the margin short of the obstacle (which stands about a margin beyond a "margin"
    blockage's point, and at a "blocked" one's).

    >>> class B: reason, along_m, point_ne = "margin", 25.0, (0.0, 0.0)
    >>> can_turn_in_time(B(), 10.0, 3.0, 5.0), can_turn_in_time(B(), 14.0, 3.0, 5.0)
    (True, False)
    """
    if blockage is None:
        return True
    room = blockage.along_m + (safety_m if blockage.reason == "margin" else 0.0) - 0.5 * safety_m
    return braking_distance_m(speed_mps, decel_mps2, reaction_s) <= room


@dataclass
class Sensing:
    """The mission's sensing step (see the module notes).

    Parameters
    ----------
    vehicle : object
        Offers ``sensor_readings()`` and ``sensing`` (a vehicle without them has no sensor).
    obstacles : ObstacleMap or None
        None: replanning off (``--no-replan``); readings are still drained (and dropped).
    clock : callable
        Monotonic seconds (the readings' ``received_s`` clock).
    """

    vehicle: object
    obstacles: ObstacleMap | None
    clock: Callable[[], float]
    scans: int = 0
    heights: int = 0
    records: list[ReplanRecord] = field(default_factory=list)
    _oldest_s: float = math.nan

    @property
    def active(self) -> bool:
        """Replanning is on and the autopilot streams obstacle data."""
        return self.obstacles is not None and bool(getattr(self.vehicle, "sensing", False))

    def drain(self, position_ne: Sequence[float]) -> bool:
        """Feed every reading queued since the last call to the map at ``position_ne``; True if there were any."""
        readings = getattr(self.vehicle, "sensor_readings", None)
        if readings is None:
            return False
        got = readings()
        if not got or self.obstacles is None:
            return bool(got)
        n, e = float(position_ne[0]), float(position_ne[1])
        for r in got:
            if hasattr(r, "bearings_rad"):
                self.obstacles.add_scan(n, e, r.bearings_rad, r.half_width_rad, r.distances_m, r.max_range_m)
                self.scans += 1
                received = float(getattr(r, "received_s", math.nan))
                if math.isfinite(received) and not received >= self._oldest_s:
                    self._oldest_s = received
            else:
                self.heights += 1
        return True

    def step(self, position_ne: Sequence[float], waypoints_ne: np.ndarray) -> Blockage | None:
        """Drain the readings and check the path ``position -> waypoints_ne``; the blockage, or None."""
        if not self.active:
            self.drain(position_ne)
            self._oldest_s = math.nan
            return None
        fresh = self.drain(position_ne)
        if not fresh:
            return None
        blockage = self.obstacles.check(position_ne, waypoints_ne)
        if blockage is None:
            self._oldest_s = math.nan
        return blockage

    def latency_ms(self) -> float:
        """Milliseconds since the oldest reading behind the current blockage arrived (NaN if unknown)."""
        return (self.clock() - self._oldest_s) * 1e3 if math.isfinite(self._oldest_s) else math.nan

    def record(self, entry: ReplanRecord) -> None:
        self.records.append(entry)
        self._oldest_s = math.nan
        log.info("replan: %s", entry.describe())

    def discovered_ne(self) -> np.ndarray:
        """Map ``(north_m, east_m)`` of the observed obstacle cells, ``(K, 2)``."""
        if self.obstacles is None:
            return np.empty((0, 2))
        return np.asarray(self.obstacles.discovered_ne(), float).reshape(-1, 2)
