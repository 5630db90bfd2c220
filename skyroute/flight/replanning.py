"""Flying through a city that differs from its map: the mission's sensing step and its replan records.

The mission never imports the vehicle package nor planning (rule 3): the vehicle offers its sensor readings
(``vehicle.sensor_readings()``: a list of readings drained since the last call, and ``vehicle.sensing`` True while
the autopilot streams obstacle data), and the command line injects an :class:`ObstacleMap` (the planning side's
``Replanner``: a live occupancy layer over the planning grid and the replanning on it). :class:`Sensing` joins the
two each poll: it feeds every horizontal reading to the map at the vehicle's map position and checks the rest of
the path; the mission turns a blockage into PATH_BLOCKED -> REPLANNING -> WAYPOINT (see ``states``), braking to a
hold first when the vehicle could not stop short of the obstacle (:func:`can_turn_in_time`) unless the new route
runs on the way it flies with room to slow down for its corners, or when it cannot turn onto the new route (at
once, or after a free straight lead-in to slow down) and slow down in time for its corners. Once
the new route's first setpoint is out, the map's refinement under its stale-map prior (``refine_job``) runs on a
worker thread and, if it finds a better route that is still clear when it is done, the vehicle switches to it
(no new event: the state stays WAYPOINT; the replan's record keeps the refined route). When the layer drops
observed obstacles as noise, the same worker looks for a way they closed that is open again (``reroute_job``); a
clearly better one is taken as the refined routes are, braking first only when that is worth a stop (its own
record, reason "reopened").

Latency: a :class:`ReplanRecord`'s ``latency_ms`` runs from the arrival of the oldest reading of the poll that
found the blockage (our monotonic clock, stamped by the link's reader) to the first setpoint of the new path, or
to the first brake setpoint when the vehicle brakes first.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from .keepoff import KeepOff

log = logging.getLogger(__name__)

#: PX4's velocity response (s, measured on SITL braking from 9 m/s): the braking rule was measured with it.
PX4_RESPONSE_S = 0.6
#: The sight cap's floor (m/s): slow enough to stop within 0.2 m, so the vehicle creeps on where nothing ahead is
#: seen free rather than stand still (:meth:`ReplanningMixin._sight_cap_mps`).
SIGHT_CREEP_MPS = 0.5
#: The live layer looks this far (m) at most: a longer reading says only that nothing stands within it. A scan's
#: cost goes with the square of its range: ArduCopter SITL's proximity sensor (PRX1_TYPE 10) reads up to 200 m,
#: 18 ms per 45 degree sector over SF at eight sectors a cycle, and the mission fell seconds behind its setpoints.
#: 60 m is more than the braking distance of 1.5x ArduCopter's default cruise (10 m/s), which the sight cap looks at.
SENSING_HORIZON_M = 60.0
#: The most (s, wall clock) one poll spends on the readings queued since the last: when they come faster than the
#: layer takes them, the oldest are dropped (counted and logged) rather than holding up the setpoints (the link
#: keeps re-sending the last one meanwhile). At 0.1 s, ArduPilot's sectors at 5x (400 a second) queued behind a
#: replan were dropped in ordinary held-out flights.
DRAIN_BUDGET_S = 0.5
#: After the link comes back (s, our clock), how long a silent obstacle stream is put down to the outage, not said
#: to have stopped: the vehicle link calls it stopped 2 s after its last scan.
STREAM_GRACE_S = 3.0


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
                 max_range_m: float, bearing_error_rad: float = 0.0, position_error_m: float = 0.0) -> object: ...

    def check(self, position_ne: Sequence[float], waypoints_ne: np.ndarray) -> Blockage | None: ...

    def replan(self, position_ne: Sequence[float]) -> Route: ...

    def route_to(self, position_ne: Sequence[float], target_ne: Sequence[float]) -> Route: ...

    def segment_free(self, a_ne: Sequence[float], b_ne: Sequence[float]) -> bool: ...

    def discovered_ne(self) -> np.ndarray: ...

    # Optional: ``refine_job(position_ne, route_ne) -> (() -> Route | None) | None``, the search for a better
    # route under a prior on what the map gets wrong (``Replanner.refine_job``), started once the first setpoint of
    # a replanned route is out and run on a worker thread; and ``reroute_job(position_ne, route_ne)``, the same
    # kind of job asked for when ``add_scan``'s answer says it dropped observed obstacles (``cleared``) and the
    # planning grid changed (``changed``): a way they closed may be open again (``Replanner.reroute_job``); and
    # ``version``, an int that changes whenever the observed obstacles change the planning grid (the mission rounds
    # its corners again then: an arc widened round what stood there before may not keep the margin any more); and
    # ``viewpoint(position_ne, looked_from) -> (north_m, east_m) | None``, where to look from before giving the goal
    # up (``Replanner.viewpoint``: only under wide sectors).


class PositionFix(Protocol):
    """Scan matching against the map (planning's ``scanmatch.PositionFix``)."""

    @property
    def correction_ne(self) -> tuple[float, float]: ...

    @property
    def bound_m(self) -> float: ...

    def observe(self, time_s: float, north_m: float, east_m: float, bearings_rad, half_width_rad: float,
                distances_m, max_range_m: float, position_error_m: float, *,
                bearing_error_rad: float = 0.0, altitude_m: float | None = None) -> object: ...

    def describe(self) -> str: ...


#: A replan record's reason when the goal, given up, is in reach again (:meth:`ReplanningMixin._goal_again`).
GOAL_AGAIN = "goal in reach again"
#: Before giving the goal up under wide sectors, the vehicle flies to at most this many viewpoints to look at what
#: closes the way (:meth:`ReplanningMixin._viewpoint_route`), each this far (m) from the others and from itself.
MAX_VIEWPOINTS, VIEWPOINT_APART_M = 5, 3.0


@dataclass(frozen=True)
class ReplanRecord:
    """One replan: ``time_s`` (our clock), where (map ``north_m``, ``east_m``), ``reason`` and ``along_m`` of the
    blockage ("reopened", NaN: a reroute onto a way reopened when the layer dropped obstacles as noise), ``plan_ms``
    the planning, ``latency_ms`` reading in -> new setpoint out, ``braked`` whether the
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
    refine_ms: float = math.nan

    def describe(self) -> str:
        """One log line."""
        if self.reason == "reopened":
            return (f"a way closed by obstacles since dropped as noise, at ({self.north_m:.1f} N, {self.east_m:.1f} "
                    f"E): {'braked, then ' if self.braked else ''}rerouted: {len(self.waypoints)} waypoints, "
                    f"searched in {self.plan_ms:.1f} ms")
        if self.reason == GOAL_AGAIN:
            return (f"the goal in reach again at ({self.north_m:.1f} N, {self.east_m:.1f} E): "
                    f"{'braked, then ' if self.braked else ''}flying on to it: {len(self.waypoints)} waypoints, "
                    f"planned in {self.plan_ms:.1f} ms")
        what = (f"{self.outcome}: {len(self.waypoints)} waypoints" if self.waypoints is not None else self.outcome)
        refined = (f"; then refined under the stale-map prior in {self.refine_ms:.1f} ms"
                   if math.isfinite(self.refine_ms) else "")
        latency = (f", new setpoint {self.latency_ms:.1f} ms after the reading" if math.isfinite(self.latency_ms)
                   else "")
        return (f"path {self.reason} {self.along_m:.1f} m ahead at ({self.north_m:.1f} N, {self.east_m:.1f} E); "
                f"{'braked, then ' if self.braked else ''}{what}, planned in {self.plan_ms:.1f} ms{latency}{refined}")


def braking_distance_m(speed_mps: float, decel_mps2: float, reaction_s: float = 0.3) -> float:
    """Metres to stop from ``speed_mps``: ``v * reaction_s + v^2 / (2 decel)``.

    >>> round(braking_distance_m(10.0, 3.0), 2)
    19.67
    """
    v = max(float(speed_mps), 0.0)
    return v * reaction_s + v * v / (2.0 * max(float(decel_mps2), 1e-6))


def speed_to_stop_within_mps(room_m: float, decel_mps2: float, reaction_s: float = 0.3) -> float:
    """The fastest speed (m/s) whose :func:`braking_distance_m` fits in ``room_m`` (0 when there is no room).

    >>> round(speed_to_stop_within_mps(19.67, 3.0), 2), speed_to_stop_within_mps(-1.0, 3.0)
    (10.0, 0.0)
    """
    if not room_m > 0:
        return 0.0
    a, r = max(float(decel_mps2), 1e-6), max(float(reaction_s), 0.0)
    return a * (-r + math.sqrt(r * r + 2.0 * float(room_m) / a))


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


def _after_lead_in(waypoints: np.ndarray) -> np.ndarray:
    """A route planned from a lead-in's end (its first row), flown from the vehicle: the first row again, in front,
    for the vehicle's own position (which the mission writes there), so the lead-in is the first leg."""
    return np.vstack([waypoints[:1], waypoints])


def turn_lead_in_m(speed_mps: float, turn_rad: float, decel_mps2: float, lateral_accel_mps2: float,
                   reaction_s: float = 0.3, overshoot_m: float = 1.0) -> float:
    """How far (m) a vehicle at ``speed_mps`` must fly straight on, slowing down, before it can turn by
    ``turn_rad`` onto a new route that starts where it is; 0 when it can turn at once.

    Turning from a point at speed ``v`` on an arc of radius ``r = v^2 / lateral_accel`` carries the vehicle
    ``r (1 - cos(turn))`` off the new leg's line (``2 r`` for a reversal); up to ``overshoot_m`` of that
    is the path's own tolerance. Faster than that, the new route would start with a corner the vehicle can only
    cut: straight on it flies, diagonally back towards the new route's first leg, past whatever corner of a
    building stands between. The lead-in is what braking to the turnable speed takes (:func:`braking_distance_m`
    for the difference), so the route can start there instead.

    >>> turn_lead_in_m(10.0, math.radians(5.0), 2.5, 3.0), turn_lead_in_m(1.5, math.pi / 2, 2.5, 3.0)
    (0.0, 0.0)
    >>> round(turn_lead_in_m(10.0, math.pi, 2.5, 3.0), 2), round(turn_lead_in_m(10.0, math.pi / 2, 2.5, 3.0), 2)
    (22.7, 22.4)
    """
    v = max(float(speed_mps), 0.0)
    bulge = 1.0 - math.cos(min(abs(float(turn_rad)), math.pi))
    turnable = math.inf if bulge < 1e-9 else math.sqrt(lateral_accel_mps2 * overshoot_m / bulge)
    if v <= turnable:
        return 0.0
    return v * reaction_s + (v * v - turnable * turnable) / (2.0 * max(float(decel_mps2), 1e-6))


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
    fix : PositionFix or None
        Scan matching against the map (planning's ``scanmatch.PositionFix``): each whole scan stamped with its
        local position is matched to the map's buildings first, and every stamped reading is placed at its
        position corrected by :attr:`correction_ne` (the mission flies with that correction too), with the fix's
        bound for how far off that may still be. None: placed at the estimate as it is.
    keep_off : KeepOff or None
        Takes every horizontal scan fed to the layer, for the mission's sideways shift away from what reads too
        close (:mod:`.keepoff`).
    """

    vehicle: object
    obstacles: ObstacleMap | None
    clock: Callable[[], float]
    fix: PositionFix | None = None
    keep_off: KeepOff | None = None
    scans: int = 0
    heights: int = 0
    low_scans: int = 0
    records: list[ReplanRecord] = field(default_factory=list)
    reopened: bool = False  # the map dropped observed obstacles as noise since the mission last looked
    horizon_m: float = SENSING_HORIZON_M
    budget_s: float = DRAIN_BUDGET_S
    dropped: int = 0  # readings dropped unread: they came faster than the layer took them
    _cost_s: float = 0.0  # wall seconds per reading, lately (an exponential average)
    _oldest_s: float = math.nan
    _fix_logged_s: float = -math.inf
    _streamed: bool = False  # the obstacle stream has come at least once
    _silent: bool = False  # ... and has stopped since (until it comes back)
    _link_back_s: float = -math.inf  # when the link last came back (inf while it is down)

    @property
    def active(self) -> bool:
        """Replanning is on and the autopilot streams obstacle data."""
        return self.obstacles is not None and bool(getattr(self.vehicle, "sensing", False))

    def stream_change(self, link_ok: bool = True) -> str | None:
        """``"silent"`` the first time the obstacle stream is found stopped after it came, ``"back"`` when it comes
        again after that, else None (and always None with replanning off): while it is silent nothing is replanned,
        the route is the map's. A link that is down, or came back less than ``STREAM_GRACE_S`` ago, explains a
        silence: nothing is said for it."""
        if self.obstacles is None:
            return None
        if not link_ok:
            self._link_back_s = math.inf
            return None
        if self._link_back_s == math.inf:
            self._link_back_s = self.clock()
        if self.active:
            self._streamed = True
            if self._silent:
                self._silent = False
                return "back"
        elif self._streamed and not self._silent and self.clock() - self._link_back_s > STREAM_GRACE_S:
            self._silent = True
            return "silent"
        return None

    def drain(self, position_ne: Sequence[float], offset_ne: Sequence[float] | None = None, *,
              offset_down_m: float | None = None, min_altitude_m: float | None = None) -> bool:
        """Feed every reading queued since the last call to the map; True if there were any.

        A reading stamped with the local position it arrived at (``local_ne``, the autopilot's frame) is placed
        there, moved into the map frame by ``offset_ne`` (map minus local, north and east m); others (or all,
        without an offset) at ``position_ne``, the vehicle's map position now. One stamped with its down
        coordinate (``local_down_m``) from below ``min_altitude_m`` (map altitude, with ``offset_down_m`` map
        minus local down) is not the layer's: climbing or sinking, the sensor sees roofs the layer's footprint
        leaves out. It still places the vehicle: the fix matches it against the map at its own altitude, so the
        correction follows a drifting estimate down to the landing (:meth:`_fix_only`)."""
        readings = getattr(self.vehicle, "sensor_readings", None)
        if readings is None:
            return False
        got = readings()
        if not got or self.obstacles is None:
            return bool(got)
        got = self._within_budget(got)
        started = time.perf_counter()
        n, e = float(position_ne[0]), float(position_ne[1])
        offset = None if offset_ne is None else (float(offset_ne[0]), float(offset_ne[1]))
        batch: list = []  # sectors read at one place (ArduPilot sends one message per sector): one layer update

        def flush() -> None:
            if batch:
                sn, se, half, rng, err, pos_err = batch[0][:6]
                update = self.obstacles.add_scan(sn, se, np.concatenate([b[6] for b in batch]), half,
                                                 np.concatenate([b[7] for b in batch]), rng, err, pos_err)
                if getattr(update, "cleared", 0) and getattr(update, "changed", False):
                    self.reopened = True
                batch.clear()

        for r in got:
            if hasattr(r, "bearings_rad"):
                down = getattr(r, "local_down_m", None)
                if down is not None and offset_down_m is not None and min_altitude_m is not None \
                        and -(down + offset_down_m) < min_altitude_m:
                    self.low_scans += 1
                    self._fix_only(r, offset, -(down + offset_down_m))
                    continue
                if self.keep_off is not None:
                    self.keep_off.observe(r)
                at = getattr(r, "local_ne", None)
                bearings, distances, max_range = self._within_horizon(r)
                pos_err = float(getattr(r, "position_error_m", 0.0))
                if at is None or offset is None:
                    sn, se = n, e  # the mission's map position: corrected already
                else:
                    sn, se = at[0] + offset[0], at[1] + offset[1]
                    if self.fix is not None:
                        sn, se, pos_err = self._corrected(r, sn, se, bearings, distances, max_range, pos_err)
                key = (sn, se, float(r.half_width_rad), max_range, float(getattr(r, "bearing_error_rad", 0.0)),
                       pos_err)
                if batch and (batch[0][:6] != key or len(bearings) != 1
                              or any(float(b[6][0]) == float(bearings[0]) for b in batch)):
                    flush()  # a whole scan, another place, or the same sector again: its own update
                batch.append((*key, bearings, distances))
                if len(bearings) != 1:
                    flush()
                self.scans += 1
                received = float(getattr(r, "received_s", math.nan))
                if math.isfinite(received) and not received >= self._oldest_s:
                    self._oldest_s = received
                continue
            flush()
            self.heights += 1
            if self.keep_off is not None:
                self.keep_off.observe_height(r)
        flush()
        cost = (time.perf_counter() - started) / len(got)
        self._cost_s = cost if self._cost_s <= 0 else self._cost_s + 0.2 * (cost - self._cost_s)
        return True

    def _within_budget(self, got: list) -> list:
        """The newest of ``got`` that the layer takes within :attr:`budget_s` at its recent cost per reading;
        the older ones are dropped (counted in :attr:`dropped`, logged when dropping starts)."""
        room = len(got) if self._cost_s <= 0 else max(int(self.budget_s / self._cost_s), 1)
        if len(got) <= room:
            return got
        if not self.dropped:
            log.warning("sensor readings come faster than the live map takes them (%.1f ms each): keeping the "
                        "newest %d of %d queued", self._cost_s * 1e3, room, len(got))
        self.dropped += len(got) - room
        return got[-room:]

    def _within_horizon(self, r) -> tuple[np.ndarray, np.ndarray, float]:
        """A scan's bearings, distances and range, read no farther than :attr:`horizon_m`."""
        bearings = np.asarray(r.bearings_rad, float)
        distances, max_range = np.asarray(r.distances_m, float), float(r.max_range_m)
        if max_range > self.horizon_m:  # farther than the horizon reads as nothing within it
            distances = np.where(distances >= self.horizon_m, np.inf, distances)
            max_range = self.horizon_m
        return bearings, distances, max_range

    def _fix_only(self, r, offset: tuple[float, float] | None, altitude_m: float) -> None:
        """A stamped scan from below the layer's altitude, for the fix alone (matched at ``altitude_m``, m above
        the map's ground): without it the correction goes stale from the top of the descent, and a drifting
        estimate moves the vehicle off the goal on the way down."""
        at = getattr(r, "local_ne", None)
        if self.fix is None or at is None or offset is None:
            return
        bearings, distances, max_range = self._within_horizon(r)
        self._corrected(r, at[0] + offset[0], at[1] + offset[1], bearings, distances, max_range,
                        float(getattr(r, "position_error_m", 0.0)), altitude_m=altitude_m)

    def _corrected(self, r, north_m: float, east_m: float, bearings: np.ndarray, distances_m: np.ndarray,
                   max_range_m: float, position_error_m: float, altitude_m: float | None = None):
        """A stamped reading's map position corrected by the fix (matched first: a whole scan, or ArduPilot's
        sectors gathered by the fix over a few cycles), and how far off it may still be."""
        fix = self.fix
        t = float(getattr(r, "time_s", math.nan))
        fix.observe(t if math.isfinite(t) else self.clock(), north_m, east_m, bearings, float(r.half_width_rad),
                    distances_m, max_range_m, position_error_m,
                    bearing_error_rad=float(getattr(r, "bearing_error_rad", 0.0)), altitude_m=altitude_m)
        cn, ce = fix.correction_ne
        bound = fix.bound_m
        now = self.clock()
        if bound >= 0 and now - self._fix_logged_s >= 5.0:
            self._fix_logged_s = now
            log.info("position fix: %s", fix.describe())
        return north_m + cn, east_m + ce, min(position_error_m, bound) if bound >= 0 else position_error_m

    @property
    def correction_ne(self) -> tuple[float, float]:
        """What scan matching adds to the position estimate (map north, east m); zeros without a fix."""
        return (0.0, 0.0) if self.fix is None else self.fix.correction_ne

    def step(self, position_ne: Sequence[float], waypoints_ne: np.ndarray,
             offset_ne: Sequence[float] | None = None, **below) -> Blockage | None:
        """Drain the readings (see :meth:`drain`) and check the path ``position -> waypoints_ne``; the blockage,
        or None."""
        if not self.active:
            self.drain(position_ne)
            self._oldest_s = math.nan
            return None
        fresh = self.drain(position_ne, offset_ne, **below)
        if not fresh:
            return None
        blockage = self.obstacles.check(position_ne, waypoints_ne)
        if blockage is None:
            self._oldest_s = math.nan
        return blockage

    def keep_up(self, position_ne: Sequence[float], offset_ne: Sequence[float] | None = None, **below) -> None:
        """Drain the readings with no path to check (the descent over the goal): the layer, the keep-off and the
        fix stay current (see :meth:`drain`)."""
        if self.active:
            self.drain(position_ne, offset_ne, **below)
        else:
            self.drain(position_ne)
        self._oldest_s = math.nan

    def latency_ms(self) -> float:
        """Milliseconds since the oldest reading behind the current blockage arrived (NaN if unknown)."""
        return (self.clock() - self._oldest_s) * 1e3 if math.isfinite(self._oldest_s) else math.nan

    @property
    def blocking_reading_s(self) -> float:
        """When (our clock) the oldest reading behind the current blockage arrived (NaN if unknown)."""
        return self._oldest_s

    def record(self, entry: ReplanRecord) -> None:
        self.records.append(entry)
        self._oldest_s = math.nan
        log.info("replan: %s", entry.describe())

    def log_summary(self) -> None:
        """One log line at the end of a flight: scans taken, dropped as too low, obstacle cells found, replans."""
        if self.obstacles is None and not self.scans:
            return
        cells = self.discovered_ne()
        where = ""
        if len(cells):
            lo, hi = cells.min(axis=0), cells.max(axis=0)
            where = f" within ({lo[0]:.0f}..{hi[0]:.0f} N, {lo[1]:.0f}..{hi[1]:.0f} E)"
        log.info("sensing: %d scans (%d from below the altitude, dropped), %d observed obstacle cells%s, %d replans",
                 self.scans, self.low_scans, len(cells), where, len(self.records))
        if self.dropped:
            log.warning("sensing: %d readings dropped unread (they came faster than the live map took them)",
                        self.dropped)
        if self.fix is not None:
            log.info("position fix: %s", self.fix.describe())

    def discovered_ne(self) -> np.ndarray:
        """Map ``(north_m, east_m)`` of the observed obstacle cells, ``(K, 2)``."""
        if self.obstacles is None:
            return np.empty((0, 2))
        return np.asarray(self.obstacles.discovered_ne(), float).reshape(-1, 2)


def _along(here_ne: Sequence[float], start_ne: Sequence[float], turn_ne: Sequence[float]) -> float:
    """How far (m) the point ``here_ne`` lies along the leg from ``start_ne`` towards ``turn_ne`` (map north, east;
    negative: behind its start).

    >>> _along((12.0, 3.0), (0.0, 0.0), (10.0, 0.0)), _along((-4.0, 0.0), (0.0, 0.0), (10.0, 0.0))
    (12.0, -4.0)
    """
    leg = np.asarray(turn_ne, float) - np.asarray(start_ne, float)
    length = float(np.hypot(*leg))
    return 0.0 if length < 1e-9 else float((np.asarray(here_ne, float) - start_ne) @ leg) / length


class _Blocked(Exception):
    """Internal: the sensing step found the rest of the path blocked; carries the blockage."""

    def __init__(self, blockage: Blockage):
        super().__init__(f"path {blockage.reason} {blockage.along_m:.1f} m ahead")
        self.blockage = blockage


class _Rerouted(Exception):
    """Internal: a better route (map waypoints from the vehicle) to switch to at once."""

    def __init__(self, waypoints: np.ndarray):
        super().__init__("rerouted")
        self.waypoints = waypoints


class ReplanningMixin:
    """The mission's REPLANNING state (a mixin of :class:`~.mission.Mission`; uses its vehicle, clock, progress,
    speeds, ``_rounded`` paths, ``sensing``, ``replan_errors``, ``replan_margin_m``, ``max_replans`` and
    ``result``)."""

    _target_ne: tuple[float, float] | None = None
    _unreachable: str | None = None
    _pending: ReplanRecord | None = None
    _reading_s: float = math.nan  # arrival of the reading behind the blockage being handled
    _first_setpoint_ms: float = math.nan  # reading -> first new setpoint (the brake's, when braking)
    _refine_due: bool = False  # a replanned route to the goal is being flown: ask for a better one once
    _refining: Future | None = None  # that refinement, running on the worker thread
    _refine_retried: bool = False  # the refinement of this replan came too late once and was asked for again
    _refine_pool: ThreadPoolExecutor | None = None
    _lead_in_ne: tuple[float, float] | None = None  # the replanned route starts with a straight lead-in to here
    _reroute_from_m: float = math.nan  # the rest of the route flown when a reroute was asked for (NaN: a refinement)
    _viewpoint_ne: tuple[float, float] | None = None  # flying to this point to look before giving the goal up
    _viewpoint_blockage: Blockage | None = None  # the blockage that sent the vehicle there
    _looked_from: tuple[tuple[float, float], ...] = ()  # the viewpoints chosen so far
    _still_out_said: tuple[str, str] | None = None  # the last "goal still out of reach" logged (way, reason)

    @property
    def discovered_obstacles(self) -> np.ndarray:
        """Observed obstacle cells as ``(K, 6)`` boxes (1 m squares up to twice the flight altitude), for the view."""
        pts = self.sensing.discovered_ne()
        top = 2.0 * self.altitude_m
        out = np.empty((len(pts), 6))
        out[:, :2] = pts
        out[:, 2] = out[:, 5] = top / 2.0
        out[:, 3] = out[:, 4] = 0.5
        return out

    def _offset_ne(self) -> tuple[float, float]:
        """Map minus the autopilot's local frame, north and east m (the mission's datum)."""
        return self._offset.north_m, self._offset.east_m

    def _low(self) -> dict:
        """Which scans are too low for the layer: from below the flight altitude less the altitude tolerance."""
        return {"offset_down_m": self._offset.down_m, "min_altitude_m": self.altitude_m - self.altitude_tolerance_m}

    def _sense(self, p, waypoints: np.ndarray, i: int) -> None:
        """Feed the readings and check the rest of the path (from the vehicle through waypoints ``i:``)."""
        if (change := self.sensing.stream_change(self.vehicle.link_ok)) is not None:
            self._say("the obstacle sensor went silent: flying on the map alone, nothing replanned, until it "
                      "streams again" if change == "silent" else "the obstacle sensor streams again: replanning on")
        blockage = self.sensing.step((p.north_m, p.east_m), waypoints[i:, :2], self._offset_ne(), **self._low())
        if blockage is not None:
            raise _Blocked(blockage)

    def _sense_coming_down(self, p) -> None:
        """Feed the readings while coming down over the goal (:meth:`~.landing.LandingMixin._come_down`): the fix
        keeps placing the vehicle (scans from below the flight altitude are matched at their own), the keep-off
        keeps reading what stands round it. Without this nothing was read from the top of the descent to the
        touchdown, and the correction the vehicle came down with was the one it had there."""
        self.sensing.keep_up((p.north_m, p.east_m), self._offset_ne(), **self._low())

    def _sight_cap_mps(self, p, direction_ne) -> float:
        """Never outrun the sensor: while it streams, the fastest speed (m/s) along ``direction_ne`` (the path's,
        map north and east) from which the vehicle at map position ``p`` can stop, half a margin to spare, within
        the space seen free straight ahead (``seen_free_m`` of the obstacle map); ``inf`` when nothing limits it.
        A new obstacle can only stand where the sensor has not looked, and a wide sector (ArduPilot's 45 degrees)
        down a street reads the buildings beside it first: what stands behind them in that sector shows only once
        it is the nearest thing there. Never below ``SIGHT_CREEP_MPS`` (it stops from that within 0.2 m): where
        nothing ahead will ever be seen free (past the map's edge, half a margin beyond a goal at that edge) a cap
        of 0 held the vehicle still short of its goal until the leg timed out.

        The braking is :func:`braking_distance_m`'s, as for a replan's, with the autopilot's response beyond
        PX4's 0.6 s and the link's round trip added to its reaction time (:meth:`_reaction_s`): that rule was
        measured on PX4 over a fast link (braked replans keep more than the margin), and a vehicle slower to slow
        down, or told later, needs that much more."""
        seen_fn = getattr(self.sensing.obstacles, "seen_free_m", None)
        horizontal = math.hypot(float(direction_ne[0]), float(direction_ne[1]))
        if seen_fn is None or not self.sensing.active or horizontal < 1e-6:
            return math.inf
        decel, spare = self.speeds.accel_mps2, 0.5 * self.replan_margin_m
        reaction = self._reaction_s()
        need = braking_distance_m(self.speeds.cruise_mps * 1.5, decel, reaction) + spare
        seen = float(seen_fn(p.north_m, p.east_m, direction_ne[0] / horizontal, direction_ne[1] / horizontal, need))
        if seen >= need:
            return math.inf
        return max(speed_to_stop_within_mps(seen - spare, decel, reaction), SIGHT_CREEP_MPS)

    def _replan_in_flight(self, blockage: Blockage) -> np.ndarray:
        """PATH_BLOCKED -> REPLANNING -> WAYPOINT: brake first if the vehicle cannot stop short of the obstacle,
        then a new route from where it is (to the goal, or to the fallback point once the goal is out of reach)."""
        from .states import MissionEvent as E

        self._fire(E.PATH_BLOCKED)
        self._forget_refinement()  # a refinement of the route now blocked is moot
        if self._pending is None:
            self._reading_s, self._first_setpoint_ms = self.sensing.blocking_reading_s, math.nan
        # else the last replan's route was blocked before its first setpoint went out (seen more while braking):
        # this one answers the same reading, and a brake setpoint already sent for it still counts as the answer
        if len(self.sensing.records) >= self.max_replans:
            raise _abort(f"{self.max_replans} replans and still blocked")
        t = self.vehicle.telemetry
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        # The vehicle may stop short of the obstacle on the old path; if not, it still need not stop when the new
        # route leads straight on, away from the obstacle, slowly enough ahead (:meth:`_turn_onto`)
        reaction = self._reaction_s()
        stops_short = can_turn_in_time(blockage, speed, self.speeds.accel_mps2, self.replan_margin_m, reaction)
        braked = False
        viewing = self._viewpoint_ne is not None
        target = None if viewing else self._target_ne  # a viewpoint is a way to the goal: the goal is asked for
        lead_in = self._lead_in_ne = None
        while True:
            p = self._map_position()
            here = (p.north_m, p.east_m)
            self.sensing.drain(here, self._offset_ne(), **self._low())
            try:
                route = self._route_from(here, target)
            except self.replan_errors as exc:
                if target is not None or viewing or self.look_again_s <= 0:
                    return self._goal_out_of_reach(exc, blockage, braked, p)
                p = self._look_again(exc, braked)
                braked, here = True, (p.north_m, p.east_m)
                try:
                    route = self.sensing.obstacles.replan(here)
                except self.replan_errors as still:
                    return self._goal_out_of_reach(still, blockage, braked, p)
                log.info("looked again: the goal can be reached after all")
            if braked:
                break
            turn = self._turn_onto(route, here, target, stops_short)
            if turn is not None:
                route, lead_in = turn
                break
            if not stops_short:
                decel = self.speeds.accel_mps2
                log.info("braking first: %.1f m/s needs %.1f m to stop at %.1f m/s^2, %.1f m ahead (%s)", speed,
                         braking_distance_m(speed, decel, reaction), decel, blockage.along_m, blockage.reason)
            braked = True
            self._brake()  # and plan again from where it stopped
        self._lead_in_ne = lead_in
        if viewing:  # the goal is in reach again on the way to a viewpoint
            self._viewpoint_ne = self._target_ne = self._unreachable = None
        waypoints = route.waypoints if lead_in is None else _after_lead_in(route.waypoints)
        waypoints = self._flight_waypoints(waypoints, p)
        self._pending = ReplanRecord(self.clock(), p.north_m, p.east_m, blockage.reason, blockage.along_m,
                                     float(route.plan_ms), math.nan, braked, waypoints)
        self._refine_due, self._refine_retried = target is None, False
        self._say(f"obstacle on the path {blockage.along_m:.0f} m ahead ({blockage.reason}): "
                  f"{'braked and ' if braked else ''}replanned in {route.plan_ms:.0f} ms")
        self._fire(E.REPLANNED)
        return waypoints

    def _route_from(self, position_ne, target) -> Route:
        obstacles = self.sensing.obstacles
        return obstacles.replan(position_ne) if target is None else obstacles.route_to(position_ne, target)

    def _turn_onto(self, route: Route, here, target, stops_short: bool = True):
        """Whether the moving vehicle can take ``route`` (from ``here``) as it is: ``(route, None)`` when it can turn
        onto its first leg at once and slow down in time for every corner of the new route (:meth:`_slows_in_time`),
        ``(route from a lead-in point, the point)`` when it must first fly straight on to slow down
        (:func:`turn_lead_in_m`), it could stop short of the obstacle on the old path (``stops_short``), that leg
        is free (margins included: a lead-in into the margin of the obstacle just seen would be found blocked again
        at the next poll), a route from its end exists and the vehicle can slow down in time for the lead-in's end
        and every corner after it; None when it must brake to a stop first. Without this, a new route turning
        sharply from the vehicle's motion starts with a corner the vehicle can only cut (measured: 2.1 m from a
        pole with a 5 m margin, ArduPilot in wind). A vehicle that could not stop short of the obstacle on the old
        path need not stop either when the new route runs on the way it flies: past the visible end of a wall it
        follows, a brake to a stop at every new piece of the wall cost a held-out flight 4 stops in 20 s. It does
        stop rather than take a lead-in then: such a lead-in is about its braking distance, a stop in all but
        name, and the route planned from a stop uses what was seen meanwhile (taken anyway, seed 11's mission 3
        flew a 29 m lead-in along a wall and came back 25 m further: 6 s slower)."""
        t = self.vehicle.telemetry
        velocity = np.array([t.local_v_north_mps, t.local_v_east_mps], float)
        speed = float(np.hypot(*velocity))
        lead = self._lead_in_m(velocity, here, route.waypoints)
        if lead <= 0.0:
            if self._slows_in_time(speed, here, route.waypoints):
                return route, None
            log.info("the new route turns sooner than %.1f m/s can slow down for: braking first", speed)
            return None
        if not stops_short:
            return None
        point = (here[0] + velocity[0] / speed * lead, here[1] + velocity[1] / speed * lead)
        free = getattr(self.sensing.obstacles, "segment_free", None)
        if free is None or not free(here, point):
            log.info("turning onto the new route at %.1f m/s needs %.0f m straight on, not free: braking first",
                     speed, lead)
            return None
        try:
            ahead = self._route_from(point, target)
        except self.replan_errors:
            ahead = None
        if ahead is None or self._lead_in_m(velocity, point, ahead.waypoints) > lead + 0.5:
            log.info("no route from %.0f m straight on that %.1f m/s can turn onto: braking first", lead, speed)
            return None
        if not self._slows_in_time(speed, here, _after_lead_in(ahead.waypoints)):
            log.info("the route after %.0f m straight on turns sooner than %.1f m/s can slow down for: braking first",
                     lead, speed)
            return None
        log.info("turning onto the new route at %.1f m/s: %.0f m straight on to slow down first", speed, lead)
        return ahead, point

    def _slows_in_time(self, speed_mps: float, start_ne, waypoints: np.ndarray, tolerance_m: float = 1.0) -> bool:
        """Whether a vehicle at ``speed_mps`` leaving ``start_ne`` along the first leg of ``waypoints`` (map frame)
        can brake, at the mission's deceleration, to every part of the rounded path slower than its cruise (its
        corners, the end) before it gets there (within ``tolerance_m``): whether it is no faster than the path's
        own speed schedule asks for where it starts. No reaction time: the follower tells the autopilot to brake
        its response time early (:func:`~.follower.steer`'s ``brake_lag_s``), as on every path it flies."""
        if speed_mps < 0.5:
            return True
        s = self.speeds
        wps = np.array(waypoints, dtype=float)[:, :3]
        wps[0, :2] = start_ne[0], start_ne[1]
        wps[np.isnan(wps[:, 2]), 2] = self.altitude_m
        path = self._rounded(wps)
        limits = np.append(path.segment_speed_mps, 0.0)
        starts = np.append(path.s_m[:-1], path.length_m)
        slower = (limits < speed_mps) & (limits < s.cruise_mps - 1e-6)  # corners and the end, not the cruise
        need = (speed_mps**2 - limits[slower] ** 2) / (2.0 * max(s.accel_mps2, 1e-6))
        return bool(np.all(need <= starts[slower] + tolerance_m))

    def _lead_in_m(self, velocity_ne: np.ndarray, start_ne, waypoints: np.ndarray) -> float:
        """:func:`turn_lead_in_m` for a vehicle moving at ``velocity_ne`` onto the first leg of ``waypoints``
        (leaving ``start_ne``), with the autopilot's response beyond PX4's in the reaction time."""
        speed = float(np.hypot(*velocity_ne))
        wps = np.asarray(waypoints, float)[:, :2]
        legs = wps[1:] - np.asarray(start_ne, float)[:2]
        lengths = np.hypot(legs[:, 0], legs[:, 1])
        far = np.flatnonzero(lengths >= 0.5)
        if speed < 0.5 or len(far) == 0:
            return 0.0
        leg = legs[far[0]] / lengths[far[0]]
        turn = math.acos(max(-1.0, min(1.0, float(velocity_ne @ leg) / speed)))
        return turn_lead_in_m(speed, turn, self.speeds.accel_mps2, self.speeds.lateral_accel_mps2,
                              self._reaction_s())

    def _reaction_s(self) -> float:
        """Seconds (the autopilot's) from a reading's capture to the autopilot braking on our answer, on top of
        the braking itself: 0.3 s (the rule measured on PX4, whose velocity response is ``PX4_RESPONSE_S``), the
        autopilot's response beyond PX4's (``brake_lag_s``; ArduCopter's ~1 s), and the link's round trip (a
        reading arrives half of it late, the brake setpoint takes the other half). Without the round trip, 300 ms
        of latency each way took an ArduPilot-personality flight to 3.4 m from a wall its 45 degree sectors
        showed late (5 m margin)."""
        round_trip = float(getattr(self.vehicle, "round_trip_s", 0.0) or 0.0)
        return 0.3 + max(0.0, float(self.brake_lag_s) - PX4_RESPONSE_S) + self._autopilot_rate() * round_trip

    def _flight_waypoints(self, waypoints: np.ndarray, p) -> np.ndarray:
        from .path import leg_headings

        wps = np.array(waypoints, dtype=float).reshape(-1, 4)
        wps[np.isnan(wps[:, 2]), 2] = self.altitude_m
        wps[0, :3] = (p.north_m, p.east_m, wps[0, 2])
        wps[:, 3] = leg_headings(wps)
        self.result.waypoints = wps
        self._progress_s = 0.0
        return wps

    def _brake(self) -> None:
        """Command a hold where the vehicle is and wait (bounded) until it has nearly stopped."""
        p = self._map_position()
        target = self._to_local(p.north_m, p.east_m, p.altitude_m)
        heading = float(getattr(self.vehicle.telemetry, "heading_rad", 0.0) or 0.0)
        deadline = self.clock() + 10.0
        while self.clock() < deadline:
            self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading, velocity_ned=None)
            if not math.isfinite(self._first_setpoint_ms):
                self._first_setpoint_ms = (self.clock() - self._reading_s) * 1e3
            t = self.vehicle.telemetry
            if math.hypot(t.local_v_north_mps, t.local_v_east_mps) <= 2.0 * self.stop_speed_mps:
                return
            self._tick()

    def _look_again(self, exc: Exception, braked: bool):
        """Stop, hold ``look_again_s`` (autopilot seconds; ours if it gives none) feeding the sensor's readings to
        the live layer, and return the vehicle's map position."""
        if not braked:
            self._brake()
        p = self._map_position()
        self._say(f"{exc}: holding to look again for {self.look_again_s:g} s")
        log.info("looking again before giving the goal up: %s", exc)
        heading = float(getattr(self.vehicle.telemetry, "heading_rad", 0.0) or 0.0)

        def sense() -> None:
            q = self._map_position()
            self.sensing.drain((q.north_m, q.east_m), self._offset_ne(), **self._low())

        self._hold(p.north_m, p.east_m, p.altitude_m, heading, self.look_again_s, each=sense,
                   max_ours_s=10.0 * self.look_again_s)
        return self._map_position()

    def _goal_out_of_reach(self, exc: Exception, blockage: Blockage, braked: bool, p) -> np.ndarray:
        """Hold, say so, and fly to the nearest reachable safe point (or stay here) to land there."""
        from .states import MissionEvent as E

        if not braked:
            self._brake()
            p = self._map_position()
        here = (p.north_m, p.east_m)
        view = self._viewpoint_route(here, blockage)
        if view is not None:
            point, route = view
            self._say(f"{exc}: flying {math.dist(point, here):.0f} m to ({point[0]:.1f} N, {point[1]:.1f} E) to "
                      "look at what closes the way before giving it up")
            waypoints = self._flight_waypoints(route.waypoints, p)
            self.sensing.record(ReplanRecord(self.clock(), p.north_m, p.east_m, blockage.reason, blockage.along_m,
                                             float(route.plan_ms), math.nan, True, waypoints,
                                             outcome=f"{exc}; looking from ({point[0]:.1f} N, {point[1]:.1f} E)"))
            self._fire(E.REPLANNED)
            return waypoints
        why = str(exc)
        self._unreachable = why
        self._say(f"{why}: holding; landing at the nearest reachable safe point")
        log.warning("goal out of reach: %s", why)
        self.sensing.record(ReplanRecord(self.clock(), p.north_m, p.east_m, blockage.reason, blockage.along_m,
                                         math.nan, math.nan, True, None, outcome=why))
        fallback = getattr(exc, "fallback_ne", None)
        route = None
        if fallback is not None and math.dist(fallback, here) > 1.0:
            self._target_ne = (float(fallback[0]), float(fallback[1]))
            try:
                route = self.sensing.obstacles.route_to(here, self._target_ne)
            except self.replan_errors as again:
                log.warning("no route to the fallback point either: %s", again)
        self._fire(E.GOAL_UNREACHABLE)
        if route is None:
            self._target_ne = here
            return self._flight_waypoints(np.array([[p.north_m, p.east_m, self.altitude_m, 0.0]]), p)
        return self._flight_waypoints(route.waypoints, p)

    def _viewpoint_route(self, here, blockage: Blockage):
        """``(viewpoint, route there)`` for the next look before giving the goal up (the obstacle map's
        ``viewpoint``: only under wide sectors), or None: none left (``MAX_VIEWPOINTS``), none found, none
        ``VIEWPOINT_APART_M`` from here and from those looked from, or no route there. Sets the viewpoint as the
        target (the vehicle asks for the goal on the way, as on the way to a fallback point, and looks again on
        arrival: :meth:`_at_viewpoint`)."""
        self._viewpoint_ne = None
        find = getattr(self.sensing.obstacles, "viewpoint", None)
        if find is None or len(self._looked_from) >= MAX_VIEWPOINTS:
            return None
        point = find(here, self._looked_from)
        if point is None or any(math.dist(point, q) < VIEWPOINT_APART_M for q in (here, *self._looked_from)):
            return None
        try:
            route = self.sensing.obstacles.route_to(here, point)
        except self.replan_errors as exc:
            log.info("no route to the viewpoint (%.1f N, %.1f E): %s", point[0], point[1], exc)
            return None
        self._looked_from = (*self._looked_from, point)
        self._viewpoint_ne = self._target_ne = point
        self._viewpoint_blockage = blockage
        return point, route

    def _at_viewpoint(self, p) -> None:
        """At a viewpoint: stop and look (``look_again_s``), then fly on (raises :class:`_Rerouted`) to the goal if
        it is in reach, else to the next viewpoint or the fallback point (:meth:`_goal_out_of_reach`)."""
        from .states import MissionEvent as E

        self._fire(E.PATH_BLOCKED)  # the way to the goal, closed on what had been seen from further back
        where = f"at ({p.north_m:.1f} N, {p.east_m:.1f} E)"
        p = self._look_again(f"the goal still out of reach {where}", braked=False)
        here = (p.north_m, p.east_m)
        try:
            route = self.sensing.obstacles.replan(here)
        except self.replan_errors as exc:
            raise _Rerouted(self._goal_out_of_reach(exc, self._viewpoint_blockage, True, p)) from None
        self._fire(E.REPLANNED)
        # (the give-up is forgotten too: a viewpoint may follow a fallback point whose way was found blocked)
        self._fly_on_to_goal(p, route, np.asarray(route.waypoints, float), True, looked=f"looked {where}: ")

    def _setpoint_sent(self) -> None:
        """After a setpoint: the first one of a new route closes its replan record with the latency."""
        if self._pending is not None:
            rec = self._pending
            self._pending = None
            latency = self._first_setpoint_ms
            if not math.isfinite(latency):
                latency = (self.clock() - self._reading_s) * 1e3
            self.sensing.record(ReplanRecord(rec.time_s, rec.north_m, rec.east_m, rec.reason, rec.along_m,
                                             rec.plan_ms, latency, rec.braked, rec.waypoints, rec.outcome))
        if self._refine_due:
            self._refine_due = False
            self._refine()

    def _refine(self) -> None:
        """Once the replanned route's first setpoint is out: start the obstacle map's refinement under its prior
        (``refine_job``) on a worker thread; :meth:`_take_refined` switches to its route when it is done."""
        if self.result.waypoints is None:
            return
        ahead = np.asarray(self.result.waypoints, float)[:, :2]
        if self._lead_in_ne is not None:  # the route after its lead-in: the vehicle turns there whatever the route
            here, ahead = self._lead_in_ne, ahead[1:]
        else:
            p = self._map_position()
            here = (p.north_m, p.east_m)
        self._refine_from(here, np.vstack([here, ahead[1:]]))  # the route just replanned, from one poll further on

    def _refine_from(self, here, rest: np.ndarray) -> None:
        """Ask the obstacle map for a refinement of the route ``rest`` (from ``here`` to the goal) on the worker
        thread; :meth:`_take_refined` collects it."""
        job_of = getattr(self.sensing.obstacles, "refine_job", None)
        job = None if job_of is None or self._target_ne is not None else job_of(here, rest)
        if job is not None:
            self._run_on_worker(job)

    def _run_on_worker(self, job: Callable) -> None:
        """Start ``job`` on the refinement's worker thread (made on first use); :meth:`_take_refined` collects it."""
        if self._refine_pool is None:
            self._refine_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="refine")
        self._refining = self._refine_pool.submit(job)

    def _reroute_if_reopened(self, p, waypoints: np.ndarray, i: int) -> None:
        """The layer dropped observed obstacles as noise since the last poll, so a way they closed may be open
        again: flying to the goal with no replan or refinement under way, ask the obstacle map (``reroute_job``)
        for a route clearly better than the rest of this one (from the vehicle through waypoints ``i:``), on the
        refinement's worker thread; :meth:`_take_refined` takes it. Without this, an arc read across a wall's end
        closed the street beside it, the vehicle turned back, the cell was seen free and dropped at once, and the
        vehicle still flew the long way round it had just chosen."""
        sensing = self.sensing
        if not sensing.reopened or self._refining is not None or self._refine_due or self._pending is not None:
            return  # looked at once the replan or refinement under way is done
        sensing.reopened = False
        if self._target_ne is not None:
            self._goal_again(p)
            return
        job_of = getattr(sensing.obstacles, "reroute_job", None)
        if job_of is None:
            return
        here = (p.north_m, p.east_m)
        rest = np.vstack([here, np.asarray(waypoints, float)[i:, :2]])
        job = job_of(here, rest)
        if job is None:
            return
        self._reroute_from_m = float(np.sum(np.hypot(*np.diff(rest, axis=0).T)))
        self._run_on_worker(job)

    def _goal_again(self, p) -> None:
        """Flying to the fallback point (the goal given up), when the layer has dropped observed obstacles as noise
        or the vehicle is there: ask for the goal once more, and when it is in reach, fly on to it (raises
        :class:`_Rerouted`, braking first when the vehicle cannot turn onto the new route in time). What closed the
        way may have been the reading of a wide sector (ArduPilot's 45 degrees: the nearest point is anywhere on a
        24 m arc at 30 m) that views from the way to the fallback point see free; held-out missions flown against
        the ArduPilot personality gave up goals they could reach that way."""
        here = (p.north_m, p.east_m)
        route = self._goal_route(here)
        if route is None:
            return
        waypoints = np.asarray(route.waypoints, float)
        t = self.vehicle.telemetry
        velocity = np.array([t.local_v_north_mps, t.local_v_east_mps], float)
        braked = False
        if (self._lead_in_m(velocity, here, waypoints) > 0.0
                or not self._slows_in_time(float(np.hypot(*velocity)), here, waypoints)):
            self._brake()
            braked = True
            p = self._map_position()
            here = (p.north_m, p.east_m)
            route = self._goal_route(here)  # from where it stopped
            if route is None:
                return
            waypoints = np.asarray(route.waypoints, float)
        self._fly_on_to_goal(p, route, waypoints, braked)

    def _fly_on_to_goal(self, p, route, waypoints: np.ndarray, braked: bool, looked: str = "") -> None:
        """The goal given up (or looked for from a viewpoint) is in reach by ``route`` (its ``waypoints``, from map
        position ``p``): forget the fallback point or viewpoint, record it ("goal in reach again"), say so and
        raise :class:`_Rerouted`."""
        self._target_ne = self._unreachable = self._lead_in_ne = self._viewpoint_ne = None
        waypoints = self._flight_waypoints(waypoints, p)
        self.sensing.record(ReplanRecord(self.clock(), p.north_m, p.east_m, GOAL_AGAIN, math.nan,
                                         float(route.plan_ms), math.nan, braked, waypoints))
        self._say(f"{looked}the goal is in reach after all: {'braked and ' if braked else ''}flying on to it, "
                  f"{float(getattr(route, 'length_m', math.nan)):.0f} m")
        raise _Rerouted(waypoints)

    def _goal_route(self, here):
        """A route from map ``here`` to the goal, or None (logged) while it is out of reach."""
        try:
            return self.sensing.obstacles.replan(here)
        except self.replan_errors as exc:
            # asked at every change of the layer (the sensor's rate, near a wall): said once per way and reason
            said = ("fallback point" if self._viewpoint_ne is None else "viewpoint", str(exc))
            (log.debug if said == self._still_out_said else log.info)(
                "flying to the %s: the goal is still out of reach (%s)", *said)
            self._still_out_said = said
            return None

    def _take_rerouted(self, p, route, from_m: float) -> None:
        """A reopened way (:meth:`_reroute_if_reopened`) still clear from here becomes the route (raises
        :class:`_Rerouted`, with its own replan record, reason "reopened"): at once when the vehicle can turn onto
        it and slow down for its corners in time (:meth:`_turn_onto`'s rule), else after braking to a stop if the
        metres it saves on the rest of the route (``from_m`` long when asked for) are more than a stop and a start
        cost (speed^2 / deceleration, flown at cruise)."""
        here = (p.north_m, p.east_m)
        waypoints = np.asarray(route.waypoints, float)
        if self.sensing.obstacles.check(here, waypoints[1:, :2]) is not None:
            return
        t = self.vehicle.telemetry
        velocity = np.array([t.local_v_north_mps, t.local_v_east_mps], float)
        speed = float(np.hypot(*velocity))
        saved = from_m - float(getattr(route, "length_m", math.nan))
        braked = False
        if self._lead_in_m(velocity, here, waypoints) > 0.0 or not self._slows_in_time(speed, here, waypoints):
            if not saved > speed**2 / max(self.speeds.accel_mps2, 1e-6):
                log.info("replan: a reopened way saves %.0f m, not worth a stop from %.1f m/s", saved, speed)
                return
            self._brake()
            braked = True
            p = self._map_position()
            here = (p.north_m, p.east_m)
            if self.sensing.obstacles.check(here, waypoints[1:, :2]) is not None:
                return
        self._lead_in_ne = None
        waypoints = self._flight_waypoints(waypoints, p)
        self.sensing.record(ReplanRecord(self.clock(), p.north_m, p.east_m, "reopened", math.nan,
                                         float(route.plan_ms), math.nan, braked, waypoints))
        self._say(f"a way the map had closed is open again: {'braked and ' if braked else ''}rerouted, "
                  f"{saved:.0f} m shorter")
        raise _Rerouted(waypoints)

    def _forget_refinement(self) -> None:
        """Drop the refinement asked for last: one not started yet never runs (a wall seen a piece at a time is
        replanned at the sensor rate, faster than a refinement runs, and a queue of refinements of routes already
        given up would hold back the one for the route flown); a running one finishes unheeded."""
        future, self._refining = self._refining, None
        self._reroute_from_m = math.nan
        if future is not None:
            future.cancel()

    def _take_refined(self, p, flown: np.ndarray | None = None, i: int = 0) -> None:
        """Each poll of the flight: a finished refinement with a better route that is still clear of the live
        layer from where the vehicle is now becomes the route (raises :class:`_Rerouted`); every leg but the first
        is the refinement's, the first starts here, a poll or a few along (the replan's own rule, too). One that
        comes too late (the vehicle past its first turn) is asked for once more, from here along the rest of the
        route flown (``flown[i:]``, the waypoints the vehicle is on; not asked again without them)."""
        future = self._refining
        if future is None or not future.done():
            return
        self._refining = None
        from_m, self._reroute_from_m = self._reroute_from_m, math.nan
        try:
            route = future.result()
        except Exception as exc:  # noqa: BLE001 - a failed refinement leaves the replanned route, which is free
            log.warning("refining the route failed (%s); flying the replanned route", exc)
            return
        if route is None:
            return
        if math.isfinite(from_m):
            self._take_rerouted(p, route, from_m)
            return
        here = (p.north_m, p.east_m)
        waypoints = np.asarray(route.waypoints, float)
        lead_in, self._lead_in_ne = self._lead_in_ne, None
        if lead_in is not None and math.dist(here, lead_in) > 1.0:  # still on the lead-in: keep it
            waypoints = _after_lead_in(waypoints)
        if self.sensing.obstacles.check(here, waypoints[1:, :2]) is not None:
            log.info("replan: the refined route is blocked by what was seen since; flying the replanned route")
            return
        waypoints = waypoints[np.r_[True, np.hypot(*np.diff(waypoints[:, :2], axis=0).T) > 1e-6]]
        turn = waypoints[min(1, len(waypoints) - 1), :2]
        along = _along(here, waypoints[0, :2], turn)
        if along < 0.0:  # not at the route's start yet (on the lead-in): fly there first
            waypoints, turn = np.vstack([waypoints[:1], waypoints]), waypoints[0, :2]
        past_m = along - math.dist(waypoints[0, :2], turn)
        if past_m > self.replan_margin_m or not self.sensing.obstacles.segment_free(here, turn):
            # a slow search (a loaded CPU: 1.2 s, 12 m along): its first turn was 25 m behind the vehicle, and the leg
            # back there from here, which no search had checked, cut a building's margin (2.2 m from it). A turn
            # just passed (a vehicle slow in a tight spot reaches it while the search runs) is still taken.
            log.info("replan: the vehicle is %.0f m past the refined route's first turn (or the leg there from here "
                     "is not clear); flying the replanned route", past_m)
            # once more from here: held-out seed 11's first mission braked, replanned, and its refinement, 0.5 s
            # late on a loaded machine, was 12 m behind the vehicle and dropped (1.53x the true map's airborne time)
            if flown is not None and not self._refine_retried:
                self._refine_retried = True
                log.info("replan: refining again from here")
                self._refine_from(here, np.vstack([here, np.asarray(flown, float)[i:, :2]]))
            return
        waypoints = self._flight_waypoints(waypoints, p)
        records = self.sensing.records
        if records and records[-1].outcome == "replanned":
            records[-1] = replace(records[-1], waypoints=waypoints, refine_ms=float(route.plan_ms))
        log.info("replan: refined under the stale-map prior: %d waypoints, %.0f m, searched in %.1f ms",
                 len(waypoints), float(getattr(route, "length_m", math.nan)), float(route.plan_ms))
        raise _Rerouted(waypoints)

    def _stop_refining(self) -> None:
        """At the end of the mission: forget a refinement in flight and let its worker thread go."""
        self._refining = None
        if self._refine_pool is not None:
            self._refine_pool.shutdown(wait=False, cancel_futures=True)
            self._refine_pool = None

    def _check_reached_goal(self) -> None:
        """After landing: a mission whose goal went out of reach ends in an error (the CLI exits 1)."""
        from .errors import GoalUnreachableInFlight

        if self._unreachable is not None:
            p = self._map_position()
            raise GoalUnreachableInFlight(f"{self._unreachable}; landed at map ({p.north_m:.1f} N, {p.east_m:.1f} E) "
                                          "instead of the goal")


def _abort(why: str) -> Exception:
    from .recovery import _Abort

    return _Abort(why)
