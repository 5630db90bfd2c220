"""The exploration mission (issue 12): take off, explore the area round the start, collect the targets, come home.

:class:`ExplorationMission` is a :class:`~.mission.Mission` that reuses the mission's building blocks by calling
them (readiness, the altitude datum, arming, takeoff, the path follower, outage recovery, landing, making safe) and
replaces only the flight between takeoff and the landing:

1. **Frontier legs.** Ask the injected explorer (``skyroute.planning.explore.Explorer``) for the nearest reachable
   frontier (known free next to unknown, a Dijkstra on the live map), route to it on the live grid (optimal
   search, pruned) and fly the route with the mission's follower. Every poll the obstacle sensor's readings go
   into the live map (:class:`~.replanning.Sensing`) and, every ``decide_every_s``, the leg is re-decided: the
   route meets an observed obstacle or its margin (re-route; brake to a hold first when the vehicle could not
   stop short of it, :func:`~.replanning.can_turn_in_time`), the frontier was seen meanwhile (on to the next one,
   without stopping), a target was sighted, or the time budget ran out.
2. **Targets.** A LANDING_TARGET sighting (``vehicle.target_sightings()``, local NED, turned into the map frame
   with the mission's offset) sends the vehicle to the target: route there, descend straight down to
   ``collect_altitude_m``, hold ``collect_hold_s`` (autopilot time), climb straight back, carry on.
3. **Stuck.** No progress of ``stuck_progress_m`` towards the leg's end within ``stuck_window_s``, a frontier that
   cannot be routed to, or one reached without being cleared: the frontier (and the cells round it) is abandoned,
   and a stuck vehicle first backs off ``back_off_m`` along its flown track. Each frontier is tried at most twice;
   nothing is tried forever.
4. **Done** when no reachable frontier is left or ``explore_time_s`` (autopilot seconds since takeoff: simulated
   time against a sped-up simulator) has run out: route home, land there, disarm.

State machine: the legs are WAYPOINT -> WAYPOINT (the end of an exploring leg is a ``WAYPOINT_REACHED``, only the
leg home ends in ``GOAL_REACHED`` -> LANDING); everything else is the mission's table.

Frames: map metres ``(north_m, east_m)``, waypoints ``[north_m, east_m, altitude_m, heading_rad]``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .errors import FlightAborted, MissionError
from .mission import Mission
from .path import leg_headings
from .recovery import _Abort, _Resumed
from .replanning import Sensing, can_turn_in_time
from .states import MissionEvent as E
from .states import MissionState as S

log = logging.getLogger(__name__)


class Explorer(Protocol):
    """What the mission needs of the planning side (``skyroute.planning.explore.Explorer``)."""

    def add_scan(self, north_m: float, east_m: float, bearings_rad, half_width_rad: float, distances_m,
                 max_range_m: float, bearing_error_rad: float = 0.0, position_error_m: float = 0.0) -> object: ...

    def check(self, position_ne: Sequence[float], waypoints_ne: np.ndarray) -> object | None: ...

    def route_to(self, position_ne: Sequence[float], target_ne: Sequence[float],
                 extend_m: float = 0.0) -> np.ndarray: ...

    def next_frontier(self, position_ne: Sequence[float]) -> object | None: ...

    def is_frontier(self, point_ne: Sequence[float]) -> bool: ...

    def abandon(self, point_ne: Sequence[float]) -> int: ...

    def view(self, north_m: float, east_m: float) -> None: ...

    def coverage(self) -> float: ...

    def why_unreachable(self, position_ne: Sequence[float]) -> str: ...

    def discovered_ne(self) -> np.ndarray: ...


class _Redirect(Exception):
    """Internal: leave the current leg (``reason``: blocked, seen, target, time, stuck)."""

    def __init__(self, reason: str, blockage=None):
        super().__init__(reason)
        self.reason, self.blockage = reason, blockage


@dataclass
class Target:
    """A ground target: ``number`` (the beacon's), map ``north_m``/``east_m`` (mean of its sightings), when first
    seen and collected (our clock, s), and whether the collect was flown."""

    number: int
    north_m: float
    east_m: float
    sightings: int = 1
    seen_s: float = math.nan
    collected_s: float = math.nan
    failed: str = ""

    @property
    def collected(self) -> bool:
        return math.isfinite(self.collected_s)


@dataclass
class ExplorationStats:
    """What the exploration did: ``coverage`` (known share of the area, 0..1), the targets, the legs flown,
    redirects by reason, frontiers abandoned, why it stopped, and the airborne time (s, autopilot clock)."""

    coverage: float = 0.0
    targets: list[Target] = field(default_factory=list)
    legs: int = 0
    redirects: dict[str, int] = field(default_factory=dict)
    abandoned: int = 0
    stopped: str = ""
    explore_s: float = math.nan

    def summary(self) -> str:
        found = len(self.targets)
        visited = sum(t.collected for t in self.targets)
        return (f"coverage {100 * self.coverage:.1f} % of the area, targets found {found}, visited {visited}, "
                f"{self.legs} legs, {self.abandoned} frontiers abandoned, stopped: {self.stopped}")


class ExplorationMission(Mission):
    """Explore round the start and come home (see the module notes).

    Parameters
    ----------
    vehicle : Vehicle
        Also offers ``sensor_readings()`` / ``sensing`` (the obstacle sensor) and ``target_sightings()``.
    make_explorer : callable
        ``(start_north_m, start_east_m) -> Explorer`` for the area round where the vehicle stands; called once,
        before arming (the mission's planning step).
    explore_time_s : float
        The time budget (autopilot seconds from takeoff) before the vehicle heads home.
    collect_altitude_m, collect_hold_s : float
        The collect: descend to this height above the target and hold this long (autopilot seconds).
    decide_every_s, stuck_window_s, stuck_progress_m, back_off_m, arrive_m, carry_on_m : float
        Re-decide the leg this often (our clock); stuck when the leg's end came no closer than
        ``stuck_progress_m`` over ``stuck_window_s``; how far to back off along the track; an exploring leg ends
        within ``arrive_m`` of its end (without stopping there); and goes on up to ``carry_on_m`` past its
        frontier where that is free, so the vehicle does not brake for a frontier it will see before reaching.
    kwargs
        The :class:`~.mission.Mission`'s (``altitude_m``, ``map_origin``, ``vehicle_errors``, ...); its
        ``plan_fn`` and ``goal_ne`` are the mission's own (the goal is home: where the vehicle took off).
    """

    def __init__(self, vehicle, make_explorer: Callable[[float, float], Explorer], *, explore_time_s: float = 600.0,
                 collect_altitude_m: float = 2.0, collect_hold_s: float = 2.0, decide_every_s: float = 0.25,
                 stuck_window_s: float = 20.0, stuck_progress_m: float = 1.0, back_off_m: float = 10.0,
                 arrive_m: float = 1.5, carry_on_m: float = 10.0, **kwargs) -> None:
        super().__init__(vehicle, self._route_from, **kwargs)
        if not explore_time_s > 0:
            raise ValueError(f"explore_time_s must be > 0, got {explore_time_s}")
        self.make_explorer = make_explorer
        self.explorer: Explorer | None = None
        self.explore_time_s = float(explore_time_s)
        self.collect_altitude_m, self.collect_hold_s = float(collect_altitude_m), float(collect_hold_s)
        self.decide_every_s, self.stuck_window_s = float(decide_every_s), float(stuck_window_s)
        self.stuck_progress_m, self.back_off_m, self.arrive_m = float(stuck_progress_m), float(back_off_m), arrive_m
        self.carry_on_m = float(carry_on_m)
        self.stats = ExplorationStats()
        self.targets: dict[int, Target] = {}
        self._leg_end: tuple[float, float] | None = None  # where the current leg goes (None: just hold here)
        self._leg = np.empty((0, 4))
        self._leg_kind = ""  # "frontier", "target", "home", "back off", ""
        self._final_leg = False
        self._decided_s = -math.inf
        self._best_m, self._best_s = math.inf, math.nan
        self._explore_deadline_s = math.inf  # autopilot clock
        self._tries: dict[tuple[int, int], int] = {}

    # ------------------------------------------------------------------------------------- mission hooks
    def _route_from(self, north_m: float, east_m: float) -> np.ndarray:
        """The mission's plan_fn: before takeoff the takeoff point itself; in the air (after an outage) the route
        to the current leg's end."""
        if self.explorer is None:
            self.explorer = self.make_explorer(north_m, east_m)
            self.sensing = Sensing(self.vehicle, self.explorer, self.clock)
        if self._leg_end is None:
            return np.array([[north_m, east_m, math.nan, 0.0]])
        return self.explorer.route_to((north_m, east_m), self._leg_end)

    def _sense(self, p, waypoints: np.ndarray, i: int) -> None:
        """Not the mission's path check: exploring, every tick feeds the live map and the leg is re-decided
        (:meth:`_tick`), which also re-routes round what the sensor shows."""

    def _sense_coming_down(self, p) -> None:
        """Nothing more: exploring, every tick feeds the live map (:meth:`_tick`)."""

    def _last_leg(self) -> bool:
        return self._final_leg

    def _fire(self, event):
        if event is E.GOAL_REACHED and not self._final_leg:
            event = E.WAYPOINT_REACHED  # an exploring leg's end: the flight goes on
        return super()._fire(event)

    def _at_goal(self, wp: np.ndarray) -> bool:
        if self._leg_kind in ("frontier", "back off"):
            p = self._map_position()
            return (math.hypot(wp[0] - p.north_m, wp[1] - p.east_m) <= self.arrive_m
                    and abs(wp[2] - p.altitude_m) <= self.altitude_tolerance_m)
        return super()._at_goal(wp)

    def _tick(self, wake_on_sensor: bool = False) -> None:
        super()._tick()  # a poll's sleep: every tick feeds the live map below and re-decides the leg on its own
        if self.state not in (S.TAKEOFF, S.WAYPOINT) or self.explorer is None:
            return
        p = self._map_position()
        here = (p.north_m, p.east_m)
        # placed where each reading arrived and without the low ones (taking off, collecting at 2 m): as the
        # replanning mission feeds it, so a lagging poll or a low roof never paints the street
        self.sensing.drain(here, self._offset_ne(), **self._low())
        if p.altitude_m > 1.0:
            self.explorer.view(*here)
        self._take_sightings()
        if self.state is not S.WAYPOINT or not self._leg_kind:
            return
        now = self.clock()
        if now - self._decided_s < self.decide_every_s:
            return
        self._decided_s = now
        reason = self._redirect_reason(here)
        if reason is not None:
            raise reason

    # ------------------------------------------------------------------------------------------ deciding
    def _remaining(self, here: Sequence[float]) -> np.ndarray:
        """The current leg's waypoints still ahead of the vehicle (after the leg segment nearest to it)."""
        leg = self._leg
        if len(leg) < 2:
            return leg
        a, b = leg[:-1, :2], leg[1:, :2]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", np.asarray(here) - a, ab) / np.maximum((ab * ab).sum(axis=1), 1e-9), 0, 1)
        nearest = a + ab * t[:, None]
        k = int(np.argmin(np.hypot(*(nearest - here).T)))
        return leg[k + 1:]

    def _redirect_reason(self, here: tuple[float, float]) -> _Redirect | None:
        blockage = self.explorer.check(here, self._remaining(here)[:, :2])
        if blockage is not None:
            return _Redirect("blocked", blockage)
        if self._leg_kind in ("frontier", "back off"):
            if any(not t.collected and not t.failed for t in self.targets.values()):
                return _Redirect("target")
        if self._leg_kind == "frontier":
            if self._leg_end is not None and not self.explorer.is_frontier(self._leg_end):
                return _Redirect("seen")
            if self._time_over():
                return _Redirect("time")
        if self._leg_end is not None and self._leg_kind != "target":
            d = math.hypot(self._leg_end[0] - here[0], self._leg_end[1] - here[1])
            now = self.clock()
            if d < self._best_m - self.stuck_progress_m or math.isnan(self._best_s):
                self._best_m, self._best_s = d, now
            elif now - self._best_s > self.stuck_window_s:
                return _Redirect("stuck")
        return None

    def _time_over(self) -> bool:
        now = self._autopilot_time_s()
        if not math.isfinite(now):
            now = self.clock()
        return now >= self._explore_deadline_s

    def _take_sightings(self) -> None:
        take = getattr(self.vehicle, "target_sightings", None)
        if take is None:
            return
        cn, ce = self.sensing.correction_ne
        for s in take():
            north, east = s.north_m + self._offset.north_m + cn, s.east_m + self._offset.east_m + ce
            t = self.targets.get(s.target_num)
            if t is None:
                t = self.targets[s.target_num] = Target(s.target_num, north, east, seen_s=self.clock())
                self.stats.targets.append(t)
                log.info("target %d sighted at map (%.1f N, %.1f E)", s.target_num, north, east)
                self._say(f"target {s.target_num} sighted at ({north:.1f} N, {east:.1f} E)")
            elif not t.collected:
                t.sightings += 1
                k = 1.0 / t.sightings
                t.north_m += k * (north - t.north_m)
                t.east_m += k * (east - t.east_m)

    # --------------------------------------------------------------------------------------------- flight
    def _fly(self, waypoints: np.ndarray) -> None:
        try:
            home = (float(waypoints[0, 0]), float(waypoints[0, 1]))
            self.goal_ne = home
            try:
                self._takeoff(float(waypoints[0, 2]))
            except _Resumed:
                pass
            start = self._autopilot_time_s()
            self._explore_deadline_s = (start if math.isfinite(start) else self.clock()) + self.explore_time_s
            self._explore()
            self.stats.coverage = self.explorer.coverage()
            self.stats.explore_s = self._autopilot_time_s() - start
            self._say(f"exploration done ({self.stats.stopped}): {self.stats.summary()}; flying home")
            self._go_home(home)
            self._land()
        except MissionError:
            self.stats.coverage = self.explorer.coverage()
            raise
        except (_Abort, *self.vehicle_errors) as exc:
            self.stats.coverage = self.explorer.coverage()
            log.error("flight failed in state %s: %s", self.state.name, exc)
            outcome = self._make_safe(str(exc))
            raise FlightAborted(f"{exc}; {outcome}") from exc
        self.result.completed = True

    def _leg_to(self, waypoints: np.ndarray, kind: str, end: tuple[float, float] | None,
                final: bool = False) -> None:
        """Fly one leg (raises :class:`_Redirect` to leave it early); resumes after an outage."""
        wps = np.asarray(waypoints, float).reshape(-1, 4).copy()
        wps[np.isnan(wps[:, 2]), 2] = self.altitude_m
        p = self._map_position()
        here = np.array([[p.north_m, p.east_m, p.altitude_m, 0.0]])
        if math.hypot(*(wps[0, :2] - here[0, :2])) > 0.5 or abs(wps[0, 2] - p.altitude_m) > 0.5:
            wps = np.vstack([here, wps])
        wps[:, 3] = leg_headings(wps)
        self._leg, self._leg_kind, self._leg_end, self._final_leg = wps, kind, end, final
        self._best_m, self._best_s = math.inf, math.nan
        self._progress_s = 0.0
        self.stats.legs += 1
        try:
            while True:
                try:
                    if self._descent_point is not None:
                        self._finish_descent()
                    else:
                        self._follow(self._leg)
                    return
                except _Resumed:
                    if not self._descent_resumable():
                        self._leg = self._resume_path(self._leg)
        finally:
            self._leg_kind = ""

    def _explore(self) -> None:
        while True:
            if self._time_over():
                self.stats.stopped = "time budget used"
                return
            pending = [t for t in self.targets.values() if not t.collected and not t.failed]
            if pending:
                self._collect(pending[0])
                continue
            p = self._map_position()
            here = (p.north_m, p.east_m)
            frontier = self.explorer.next_frontier(here)
            if frontier is None:
                self.stats.stopped = "no reachable frontier left"
                if why := self.explorer.why_unreachable(here):
                    log.info("exploration stops with goals left: %s", why)
                return
            point = tuple(frontier.point_ne)
            key = (round(point[0]), round(point[1]))
            self._tries[key] = self._tries.get(key, 0) + 1
            if self._tries[key] > 2:
                self._give_up(point, "tried twice")
                continue
            try:
                route = self.explorer.route_to(here, point, self.carry_on_m)
            except self.no_path_errors as exc:
                self._give_up(point, f"no route: {exc}")
                continue
            try:
                self._leg_to(route, "frontier", point)
            except _Redirect as r:
                self._redirected(r, point)
                continue
            if self.explorer.is_frontier(point):  # reached, still unknown round it: nothing more to see here
                self._give_up(point, "reached without clearing it")

    def _give_up(self, point: Sequence[float], why: str) -> None:
        cells = self.explorer.abandon(point)
        self.stats.abandoned += 1
        log.info("frontier (%.1f N, %.1f E) abandoned (%s): %d cells", point[0], point[1], why, cells)

    def _redirected(self, r: _Redirect, point: Sequence[float] | None) -> None:
        self.stats.redirects[r.reason] = self.stats.redirects.get(r.reason, 0) + 1
        log.info("leg left: %s", r.reason)
        if r.reason == "blocked":
            t = self.vehicle.telemetry
            speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
            if not can_turn_in_time(r.blockage, speed, self.speeds.accel_mps2, self.explorer_safety_m()):
                self._brake()
        elif r.reason == "stuck":
            if point is not None:
                self._give_up(point, "no progress")
            self._back_off()

    def explorer_safety_m(self) -> float:
        area = getattr(self.explorer, "area", None)
        return float(getattr(area, "safety_m", 5.0))

    def _brake(self) -> None:
        """Hold where the vehicle is until it has (nearly) stopped."""
        p = self._map_position()
        target = self._to_local(p.north_m, p.east_m, self.altitude_m)
        deadline = self.clock() + 10.0
        self._say("braking to a hold: an obstacle ahead is too close to turn")
        while self.clock() < deadline:
            self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, self.vehicle.telemetry.heading_rad
                                    if hasattr(self.vehicle.telemetry, "heading_rad") else 0.0)
            t = self.vehicle.telemetry
            if math.hypot(t.local_v_north_mps, t.local_v_east_mps) < self.stop_speed_mps:
                return
            self._tick()

    def _back_off(self) -> None:
        """Fly back along the flown track to the latest point ``back_off_m`` from here."""
        p = self._map_position()
        track = np.array(self._track, float).reshape(-1, 4)
        far = np.hypot(track[:, 1] - p.north_m, track[:, 2] - p.east_m) >= self.back_off_m
        if not far.any():
            return
        k = int(np.flatnonzero(far)[-1])
        point = (float(track[k, 1]), float(track[k, 2]))
        try:
            route = self.explorer.route_to((p.north_m, p.east_m), point)
            self._leg_to(route, "back off", point)
        except self.no_path_errors as exc:
            log.info("back off impossible: %s", exc)
        except _Redirect as r:
            if r.reason == "blocked":
                self._redirected(r, None)

    def _collect(self, target: Target) -> None:
        """Route to the target, descend to the collect height, hold, climb back."""
        for _attempt in range(3):
            p = self._map_position()
            goal = (target.north_m, target.east_m)
            try:
                route = self.explorer.route_to((p.north_m, p.east_m), goal)
            except self.no_path_errors as exc:
                target.failed = f"no route: {exc}"
                self._say(f"target {target.number}: {target.failed}")
                return
            try:
                self._leg_to(route, "target", goal)
                break
            except _Redirect as r:
                self._redirected(r, None)
        else:
            target.failed = "the route kept being blocked"
            return
        p = self._map_position()
        n, e = target.north_m, target.east_m  # the latest estimate, refined on the way
        if math.hypot(n - p.north_m, e - p.east_m) > 3.0:  # no free cell near it at the altitude: descend here
            n, e = p.north_m, p.east_m
        self._say(f"target {target.number}: descending to {self.collect_altitude_m:g} m")
        self._vertical_to(n, e, self.collect_altitude_m)
        self._hold(n, e, self.collect_altitude_m, float(self._leg[-1, 3]), self.collect_hold_s)
        target.collected_s = self.clock()
        self._say(f"target {target.number} collected at ({n:.1f} N, {e:.1f} E); climbing back")
        self._vertical_to(n, e, self.altitude_m)

    def _vertical_to(self, north_m: float, east_m: float, altitude_m: float, tolerance_m: float = 0.2) -> None:
        """Climb or descend straight to ``altitude_m`` over the map point (a position setpoint; the autopilot's
        own vertical speed limit applies), within ``tolerance_m``."""
        target = self._to_local(north_m, east_m, altitude_m)
        heading = float(self._leg[-1, 3]) if len(self._leg) else 0.0
        deadline = self.clock() + self.takeoff_timeout_s
        while abs(self._map_position().altitude_m - altitude_m) > tolerance_m:
            if self.clock() > deadline:
                raise _Abort(f"did not reach {altitude_m:g} m over ({north_m:.1f} N, {east_m:.1f} E) within "
                             f"{self.takeoff_timeout_s:g} s")
            self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading)
            self._tick()

    def _go_home(self, home: tuple[float, float]) -> None:
        for _ in range(10):
            p = self._map_position()
            try:
                route = self.explorer.route_to((p.north_m, p.east_m), home)
            except self.no_path_errors as exc:
                raise _Abort(f"no route home from ({p.north_m:.1f} N, {p.east_m:.1f} E): {exc}") from exc
            route = np.asarray(route, float).copy()
            route[-1, :2] = home  # home itself, not its cell's centre
            try:
                self._leg_to(route, "home", home, final=True)
                return
            except _Redirect as r:
                self._redirected(r, None)
        raise _Abort("the route home kept being blocked")
