"""Receding-horizon replanning on the live layer: is the rest of the path still clear, and if not, a new one.

:meth:`Replanner.check` walks the remaining path (from the vehicle's position through the waypoints still ahead)
against the observed obstacles of a :class:`~.livemap.LiveMap`, up to ``look_ahead_m`` along it: *blocked* where
it crosses an observed obstacle cell, *margin* where it only comes within the safety margin of one.
:meth:`Replanner.replan` plans from the vehicle's position to the goal on the live planning grid (the map's
C-space or the inflated observed obstacles) with the optimal grid search, prunes it with the grid's
line-of-sight rule (and, for ``method="any-angle"``, pulls it taut), so every new leg is free on the live grid.

The live layer is 2D, at the flight altitude: every 2D planner replans this way (the route it started from came
from its own structure, a new one from the grid search, which is optimal on the same grid), and observed
obstacles count as reaching above the altitude (their tops were never seen), so a replan never climbs over them.

:meth:`Replanner.refine` then picks again among the detours under a stale-map prior: unseen cells near observed
obstacles cost more, the nearer the more (a wall seen in part likely continues; a street blocked once is often
blocked again), and so do unseen cells near the route the map chose (:meth:`Replanner.suspect_route`: once the map
proved wrong on its own route, the rest of that route is the likeliest place for it to be wrong again), searched
with per-cell costs; slower, so the mission runs it off its loop (:meth:`Replanner.refine_job`).

When the goal cannot be reached any more, :meth:`Replanner.fallback` finds the nearest safe point that can:
free on the live grid (and landable, if a landing grid is given), in the vehicle's connected free space.

Frames: map metres ``(north_m, east_m)``; waypoints ``[north_m, east_m, altitude_m, heading_rad]``. Whether the
vehicle can turn onto a new route without stopping first is the mission's call (``skyroute.flight.replanning``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from skyroute.planning import any_angle
from skyroute.planning.errors import NoPathError, PlanningError
from skyroute.planning.livemap import LiveMap
from skyroute.planning.pruning import headings_along, line_of_sight, path_length, prune_path
from skyroute.planning.search import GridPlanner, load_weighted_search

log = logging.getLogger(__name__)

METHODS = ("grid", "any-angle")
#: The stale-map prior (:meth:`Replanner.refine`): an unseen cell next to an observed obstacle costs this many times
#: its length, falling linearly with its distance to 1 at this many metres. Weight and radius chosen on the offline
#: model of the held-out check (bench/bench_replan.py --compare-prior); the linear fall-off (a flat 3x out to 100 m
#: before) on the same model's 393 fresh missions (WRITEUP, "A prior on what the map gets wrong").
SUSPECT_WEIGHT, SUSPECT_RADIUS_M = 3.0, 100.0
#: The prior's second half (:meth:`Replanner.suspect_route`): unseen cells this close to the map's own route (m)
#: cost this many times their length once an obstacle was observed. Chosen on the same model (WRITEUP).
ROUTE_WEIGHT, ROUTE_RADIUS_M = 3.0, 20.0
#: Once observed obstacles were dropped as noise (:meth:`Replanner.reroute_job`), a way they closed counts as
#: reopened when it beats the rest of the route flown by this share of its cost plus these metres (under the prior).
#: Set on the offline model of the held-out check (bench/bench_replan.py, 40 seeds); judged by plain length instead,
#: the switch gave up the prior's choices and made as many missions worse as better.
REOPEN_GAIN, REOPEN_GAIN_M = 0.05, 5.0
#: When the goal is out of reach at the full margin round observed obstacles, :meth:`Replanner.replan` narrows that
#: margin in steps of this many metres down to this share of the safety margin (the map's buildings keep it whole):
#: a hit cell counts whole and an oblique arc lies up to a metre in front of the face it saw, so the inflated layer
#: overstates what was seen (:meth:`.livemap.LiveMap.set_margin`). 0.8 keeps 4 m of a 5 m margin, above issue 11's
#: 3.5 m clearance bar; held-out seed 24's mission 1 (offline model) needed 4 m past a wall's end.
NARROW_STEP_M, MIN_MARGIN_SHARE = 0.5, 0.8
#: :meth:`Replanner.viewpoint`: a metre through observed obstacles or their margins costs up to this many metres of
#: free street (the full weight where a hit within the margin was hit this many times more often than seen free,
#: a tenth of it at least), and this many times more again within this many metres (cells) of a point already
#: looked from. Chosen on the offline model of the held-out check, ArduPilot sectors (WRITEUP).
VIEW_CROSSING_WEIGHT, VIEW_SURE_HITS = 20.0, 10.0
VIEW_LOOKED_WEIGHT, VIEW_LOOKED_RADIUS_M = 10.0, 15
#: Coarse cell (m) of the prior's distances (to the nearest observed obstacle, to the map's route).
_SUSPECT_CELL_M = 4


class GoalBlocked(PlanningError):
    """The goal itself lies within the margin of an observed obstacle."""

    def __init__(self, goal_ne: Sequence[float], fallback_ne: tuple[float, float] | None):
        self.goal_ne, self.fallback_ne = tuple(goal_ne), fallback_ne
        super().__init__(f"the goal ({goal_ne[0]:.1f} N, {goal_ne[1]:.1f} E) is blocked by an obstacle the map "
                         "does not show" + _fallback_text(fallback_ne))


class GoalUnreachable(PlanningError):
    """Observed obstacles cut the goal off from the vehicle."""

    def __init__(self, goal_ne: Sequence[float], fallback_ne: tuple[float, float] | None):
        self.goal_ne, self.fallback_ne = tuple(goal_ne), fallback_ne
        super().__init__(f"the goal ({goal_ne[0]:.1f} N, {goal_ne[1]:.1f} E) cannot be reached: obstacles the map "
                         "does not show cut it off" + _fallback_text(fallback_ne))


def _distance_m(cells: np.ndarray) -> np.ndarray:
    """Metres from each cell to the nearest True cell of ``cells`` (1 m cells), measured on a coarse grid of
    ``_SUSPECT_CELL_M`` cells (between the coarse cells holding them; 0 in a coarse cell holding one)."""
    f = _SUSPECT_CELL_M
    n, m = cells.shape
    padded = np.zeros((-(-n // f) * f, -(-m // f) * f), bool)
    padded[:n, :m] = cells
    coarse = padded.reshape(padded.shape[0] // f, f, padded.shape[1] // f, f).any(axis=(1, 3))
    distance = ndimage.distance_transform_edt(~coarse) * f
    return np.repeat(np.repeat(distance, f, axis=0), f, axis=1)[:n, :m]


def _within(cells: np.ndarray, radius_m: float) -> np.ndarray:
    """Cells within ``radius_m`` of a True cell of ``cells`` (:func:`_distance_m`)."""
    return _distance_m(cells) <= radius_m


def _fallback_text(fallback_ne) -> str:
    if fallback_ne is None:
        return "; no reachable safe point"
    return f"; nearest reachable safe point ({fallback_ne[0]:.1f} N, {fallback_ne[1]:.1f} E)"


@dataclass(frozen=True)
class Blockage:
    """Where the remaining path first meets an observed obstacle: ``reason`` ``"blocked"`` (crosses one) or
    ``"margin"`` (within the safety margin), ``along_m`` metres along the remaining path from the vehicle,
    ``point_ne`` the map point."""

    reason: str
    along_m: float
    point_ne: tuple[float, float]


@dataclass(frozen=True)
class Replan:
    """A new route: ``waypoints`` (K, 4) from the vehicle's position to the goal, ``plan_ms`` the time it took,
    ``length_m`` its length, ``expanded`` the search's expanded nodes, ``snapped`` whether the start lay within the
    margin of an observed obstacle and the route first leads out of it."""

    waypoints: np.ndarray
    plan_ms: float
    length_m: float
    expanded: int
    snapped: bool
    margin_m: float | None = None  # the margin round observed obstacles, when this replan narrowed it


class Replanner:
    """Checks the rest of the path and replans it on a live layer (see the module notes).

    Parameters
    ----------
    live : LiveMap
    goal_ne : (float, float)
        The goal (map metres).
    altitude_m : float
        Flight altitude of the new waypoints.
    look_ahead_m : float
        How far along the remaining path :meth:`check` looks.
    method : {"grid", "any-angle"}
    landable : (n, m) bool array, optional
        Cells where the vehicle may descend and land (e.g. free of every building's margin at all lower
        altitudes); :meth:`fallback` picks among them.
    step_m : float
        Sampling step of :meth:`check` along the path (finer than a cell).
    suspect_weight, suspect_radius_m : float
        The stale-map prior of :meth:`refine`: a cell never seen next to an observed obstacle costs
        ``suspect_weight`` times its length, falling linearly with its distance to 1 at ``suspect_radius_m``
        (weight 1 turns the prior off).
    route_weight, route_radius_m : float
        Its second half, once :meth:`suspect_route` named the map's route: a cell never seen within
        ``route_radius_m`` of that route costs ``route_weight`` times its length (1 turns it off).
    min_margin_m : float, optional
        The narrowest margin (m) :meth:`replan` may keep round observed obstacles when the goal is out of reach at
        a wider one (default: ``MIN_MARGIN_SHARE`` of the layer's safety margin; the safety margin itself turns
        narrowing off).
    """

    def __init__(self, live: LiveMap, goal_ne: Sequence[float], altitude_m: float, *, look_ahead_m: float = 60.0,
                 method: str = "grid", landable: np.ndarray | None = None, step_m: float = 0.25,
                 suspect_weight: float = SUSPECT_WEIGHT, suspect_radius_m: float = SUSPECT_RADIUS_M,
                 route_weight: float = ROUTE_WEIGHT, route_radius_m: float = ROUTE_RADIUS_M,
                 min_margin_m: float | None = None) -> None:
        for weight, radius in ((suspect_weight, suspect_radius_m), (route_weight, route_radius_m)):
            if not weight >= 1.0 or not radius >= 0.0:
                raise ValueError(f"a prior's weight must be >= 1 and its radius >= 0, not {weight}, {radius}")
        self.suspect_weight, self.suspect_radius_m = float(suspect_weight), float(suspect_radius_m)
        self.route_weight, self.route_radius_m = float(route_weight), float(route_radius_m)
        self._route_near: np.ndarray | None = None
        if self.suspect_weight > 1.0 and self.suspect_radius_m > 0.0 or self.route_weight > 1.0:
            load_weighted_search()  # compiled (or loaded from numba's disk cache) before the flight, not in it
        if method not in METHODS:
            raise ValueError(f"unknown replanning method {method!r}; choose from {METHODS}")
        self.live, self.goal_ne, self.altitude_m = live, (float(goal_ne[0]), float(goal_ne[1])), float(altitude_m)
        self.look_ahead_m, self.method, self.step_m = float(look_ahead_m), method, float(step_m)
        self.landable = None if landable is None else np.asarray(landable, dtype=bool)
        self.min_margin_m = MIN_MARGIN_SHARE * live.safety_m if min_margin_m is None else float(min_margin_m)
        if not 0.0 <= self.min_margin_m <= live.safety_m:
            raise ValueError(f"min_margin_m must lie in [0, {live.safety_m:g}] m, not {self.min_margin_m:g}")
        self._planner: GridPlanner | None = None
        self._planner_version = -1

    # ------------------------------------------------------------------------------------------ checking
    def check(self, position_ne: Sequence[float], waypoints_ne: np.ndarray) -> Blockage | None:
        """The first point within ``look_ahead_m`` where the path ``position -> waypoints_ne[0] -> ...`` meets an
        observed obstacle or its margin, else None.

        A hit 10 m north of the sensor (cell north 15..16 m), 2 m margin: the path north meets the margin 2 m before
        the hit cell, at north 13 m, 7.5 m from the start:

        >>> live = LiveMap(np.zeros((30, 30), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
        >>> _ = live.add_scan(5.5, 15.5, np.radians([0.0]), np.radians(1.0), np.array([10.0]), 30.0)
        >>> Replanner(live, (28.5, 15.5), 5.0).check((5.5, 15.5), np.array([[28.5, 15.5]]))
        Blockage(reason='margin', along_m=7.5, point_ne=(13.0, 15.5))
        """
        pts = np.vstack([np.asarray(position_ne, float)[None, :2], np.asarray(waypoints_ne, float)[:, :2]])
        live = self.live
        travelled = 0.0
        first_margin: Blockage | None = None
        leaving = True  # a vehicle already within an observed obstacle's margin (braked there) may fly out of it
        for a, b in zip(pts[:-1], pts[1:]):
            leg = b - a
            length = float(np.hypot(*leg))
            if length < 1e-9:
                continue
            steps = np.arange(0.0, length + 1e-9, self.step_m)
            if steps[-1] < length:
                steps = np.append(steps, length)
            steps = steps[travelled + steps <= self.look_ahead_m]
            if len(steps) == 0:
                break
            samples = a + steps[:, None] * (leg / length)
            cells = np.floor(samples - (live.north_offset, live.east_offset)).astype(np.int64)
            n, m = live.shape
            on = (cells[:, 0] >= 0) & (cells[:, 0] < n) & (cells[:, 1] >= 0) & (cells[:, 1] < m)
            ci, cj = np.where(on, cells[:, 0], 0), np.where(on, cells[:, 1], 0)
            hit = on & live.hits[ci, cj]
            near = on & live.inflated[ci, cj]
            if leaving:
                outside = np.flatnonzero(~near)
                near[: outside[0] if len(outside) else len(near)] = False
                leaving = len(outside) == 0
            if near.any() and first_margin is None:
                k = int(np.argmax(near))
                first_margin = Blockage("margin", round(travelled + float(steps[k]), 3),
                                        (float(samples[k, 0]), float(samples[k, 1])))
            if hit.any():
                k = int(np.argmax(hit))
                block = Blockage("blocked", round(travelled + float(steps[k]), 3),
                                 (float(samples[k, 0]), float(samples[k, 1])))
                return block if first_margin is None or first_margin.along_m >= block.along_m else first_margin
            travelled += length
            if travelled > self.look_ahead_m:
                break
        return first_margin

    # ------------------------------------------------------------------------------------------- sensing
    def add_scan(self, north_m: float, east_m: float, bearings_rad, half_width_rad: float, distances_m,
                 max_range_m: float, bearing_error_rad: float = 0.0, position_error_m: float = 0.0):
        """Feed one scan to the live layer (:meth:`LiveMap.add_scan`)."""
        return self.live.add_scan(north_m, east_m, bearings_rad, half_width_rad, distances_m, max_range_m,
                                  bearing_error_rad, position_error_m)

    def discovered_ne(self) -> np.ndarray:
        """Map ``(north_m, east_m)`` of every observed obstacle cell's centre, ``(K, 2)``."""
        return self.live.hit_cells_ne()

    @property
    def version(self) -> int:
        """Changes whenever the observed obstacles change the planning grid (:attr:`LiveMap.version`)."""
        return self.live.version

    def clearance_m(self, north_m: float, east_m: float, direction_north: float, direction_east: float,
                    max_m: float) -> float:
        """How far the horizontal ray from the point along the unit direction stays out of every observed
        obstacle's margin, up to ``max_m`` (m); the map's own buildings are the map's clearance function's."""
        return self.live.clearance_m(north_m, east_m, direction_north, direction_east, max_m)

    def seen_free_m(self, north_m: float, east_m: float, direction_north: float, direction_east: float,
                    max_m: float) -> float:
        """How far the horizontal ray from the point along the unit direction runs through space the sensor has
        seen free, up to ``max_m`` (m): beyond it a new obstacle could stand unseen (:meth:`LiveMap.seen_free_m`)."""
        return self.live.seen_free_m(north_m, east_m, direction_north, direction_east, max_m)

    def segment_free(self, a_ne: Sequence[float], b_ne: Sequence[float]) -> bool:
        """True if the straight leg between two map points touches only free cells of the live grid (the map's
        buildings and the observed obstacles, each with its margin; the grid's line-of-sight rule).

        >>> live = LiveMap(np.zeros((30, 30), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
        >>> _ = live.add_scan(5.5, 15.5, np.radians([0.0]), np.radians(1.0), np.array([10.0]), 30.0)
        >>> r = Replanner(live, (28.5, 15.5), 5.0)
        >>> r.segment_free((5.5, 15.5), (10.5, 15.5)), r.segment_free((5.5, 15.5), (20.5, 15.5))
        (True, False)
        """
        return line_of_sight(self.live.grid, self.live.cell_of(*a_ne[:2]), self.live.cell_of(*b_ne[:2]))

    # ---------------------------------------------------------------------------------------- replanning
    def _grid_planner(self) -> GridPlanner:
        if self._planner is None or self._planner_version != self.live.version:
            self._planner = GridPlanner(self.live.grid)
            self._planner_version = self.live.version
        return self._planner

    def goal_blocked(self) -> bool:
        """True if the goal's cell is blocked on the live grid by an observed obstacle (not by the map)."""
        i, j = self.live.cell_of(*self.goal_ne)
        n, m = self.live.shape
        return 0 <= i < n and 0 <= j < m and bool(self.live.inflated[i, j])

    def _start_cell(self, position_ne: Sequence[float]) -> tuple[tuple[int, int], bool]:
        live = self.live
        cell = live.cell_of(*position_ne)
        n, m = live.shape
        if not (0 <= cell[0] < n and 0 <= cell[1] < m) or not live.grid[cell]:
            return cell, False
        # Inside the margin: lead out to the nearest free cell seen by a straight leg that crosses no obstacle.
        snapped = live.way_out(cell)
        return (cell, False) if snapped is None else (snapped, True)

    def replan(self, position_ne: Sequence[float]) -> Replan:
        """A route from ``position_ne`` to the goal on the live grid.

        When the goal is blocked or cut off at the margin kept round observed obstacles, that margin is narrowed
        in ``NARROW_STEP_M`` steps down to ``min_margin_m`` until it is not (the route says so in ``margin_m``,
        and the layer keeps the narrower margin from then on); when none helps, the margin is put back and the
        error raised, its fallback found at the wider margin.

        Raises
        ------
        GoalBlocked, GoalUnreachable
            With the nearest reachable safe point (:meth:`fallback`) when there is one.
        PlanningError
            When the vehicle's own position has no way out (off the grid, or boxed in).
        """
        t0 = time.perf_counter()
        live = self.live
        kept = live.margin_m
        margin = kept
        while True:
            try:
                route = self._route(position_ne, t0)
            except (GoalBlocked, GoalUnreachable):
                margin = round(margin - NARROW_STEP_M, 6)
                if margin < self.min_margin_m - 1e-9 or not live.hits.any():
                    break
                live.set_margin(margin)
                continue
            if live.margin_m == kept:
                return route
            log.warning("the goal is out of reach %g m from the obstacles the map does not show; keeping %g m "
                        "from them from now on", kept, live.margin_m)
            return replace(route, margin_m=live.margin_m)
        live.set_margin(kept)
        if self.goal_blocked():
            raise GoalBlocked(self.goal_ne, self.fallback(position_ne))
        raise GoalUnreachable(self.goal_ne, self.fallback(position_ne))

    def _route(self, position_ne: Sequence[float], t0: float) -> Replan:
        """:meth:`replan` at the layer's margin as it stands (its errors without a fallback point)."""
        live = self.live
        if self.goal_blocked():
            raise GoalBlocked(self.goal_ne, None)
        start, snapped = self._start_cell(position_ne)
        goal = live.cell_of(*self.goal_ne)
        planner = self._grid_planner()
        try:
            path = planner.plan(start, goal)
        except NoPathError as exc:
            raise GoalUnreachable(self.goal_ne, None) from exc
        points = self._points(path.cells, position_ne, snapped)
        waypoints = np.column_stack([points, np.full(len(points), self.altitude_m), headings_along(points)])
        plan_ms = (time.perf_counter() - t0) * 1e3
        return Replan(waypoints, plan_ms, path_length(points), path.expanded, snapped)

    # ------------------------------------------------------------------------------ the stale-map prior
    def suspect_route(self, route_ne: np.ndarray) -> None:
        """Name the route the map chose (``(K, 2+)`` map points, e.g. the first plan's waypoints): once an
        obstacle the map does not show has been observed, unseen cells within ``route_radius_m`` of it cost
        ``route_weight`` times their length under the prior (:meth:`suspect_weights`).

        Where a map proved wrong on the route it chose, the rest of that route is the likeliest place for it to be
        wrong again: a change that matters is one across the way the map sends you (a closed street, a site along
        it), and a detour that rejoins the map's route soon after the first obstacle often meets the next. Cells
        the sensor has seen free are exempt, as for the other half of the prior.

        >>> live = LiveMap(np.zeros((40, 40), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
        >>> r = Replanner(live, (35.5, 35.5), 5.0, suspect_weight=1.0, route_radius_m=4.0)
        >>> r.suspect_route(np.array([[25.5, 0.5], [25.5, 39.5]]))
        >>> r.suspect_weights() is None    # nothing observed yet: the map is trusted
        True
        >>> _ = live.add_scan(30.5, 5.5, np.radians([180.0]), np.radians(1.0), np.array([10.0]), 30.0)
        >>> w = r.suspect_weights(); float(w[25, 30]), float(w[35, 30]), float(w[25, 5])  # on, off, seen free
        (3.0, 1.0, 1.0)
        """
        route = np.asarray(route_ne, float)[:, :2]
        live = self.live
        n, m = live.shape
        on = np.zeros((n, m), bool)
        for a, b in zip(route[:-1], route[1:]):
            k = max(2, int(math.ceil(float(np.hypot(*(b - a))) / 0.5)) + 1)
            cells = np.floor(a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
                             - (live.north_offset, live.east_offset)).astype(np.int64)
            inside = (cells[:, 0] >= 0) & (cells[:, 0] < n) & (cells[:, 1] >= 0) & (cells[:, 1] < m)
            on[cells[inside, 0], cells[inside, 1]] = True
        self._route_near = _within(on, self.route_radius_m) if self.route_weight > 1.0 and on.any() else None

    def suspect_weights(self) -> np.ndarray | None:
        """Per-cell cost factors of the prior, ``(n, m)``, or None when it adds nothing (no observed obstacle, or
        turned off): on cells never seen (neither free nor hit), ``suspect_weight`` next to an observed obstacle
        cell, falling linearly to 1 at ``suspect_radius_m`` from it, and ``route_weight`` within
        ``route_radius_m`` of the map's route (:meth:`suspect_route`), the larger where both hold (distances on a
        4 m coarse grid); 1 elsewhere.

        The fall-off, not a flat weight out to the radius: with a flat one, a street just beyond the radius cost
        a third of one just inside it, and a detour was sent round the far side of that edge whatever lay between
        (held-out seed 11's mission 3: 100 m north of a wall, 1.57x the true route's metres on the offline model;
        1.28x with the fall-off)."""
        if not self._prior_applies():
            return None
        return self._weights(self.live.hits, self.live.known)

    def _prior_applies(self) -> bool:
        """The prior is on and has something to go on (an observed obstacle)."""
        on = self.suspect_weight > 1.0 and self.suspect_radius_m > 0.0 or self._route_near is not None
        return on and bool(self.live.hits.any())

    def _weights(self, hits: np.ndarray, known: np.ndarray) -> np.ndarray:
        weights = np.ones(hits.shape)
        if self.suspect_weight > 1.0 and self.suspect_radius_m > 0.0:
            near = np.clip(1.0 - _distance_m(hits) / self.suspect_radius_m, 0.0, 1.0)
            weights += (self.suspect_weight - 1.0) * near
        if self._route_near is not None:
            weights[self._route_near] = np.maximum(weights[self._route_near], self.route_weight)
        weights[known] = 1.0
        return weights

    def prior_cost(self, points_ne: np.ndarray, weights: np.ndarray | None = None) -> float:
        """A route's length under the prior: metres along ``points_ne`` (``(K, 2)`` map) times the weight of the
        cell under each half-metre sample (its plain length without the prior)."""
        points = np.asarray(points_ne, float)[:, :2]
        weights = self.suspect_weights() if weights is None else weights
        if weights is None:
            return path_length(points)
        live, total = self.live, 0.0
        n, m = live.shape
        for a, b in zip(points[:-1], points[1:]):
            length = float(np.hypot(*(b - a)))
            if length < 1e-9:
                continue
            k = max(1, int(math.ceil(length / 0.5)))
            mid = a + (np.arange(k)[:, None] + 0.5) / k * (b - a)
            cells = np.floor(mid - (live.north_offset, live.east_offset)).astype(np.int64)
            ci, cj = np.clip(cells[:, 0], 0, n - 1), np.clip(cells[:, 1], 0, m - 1)
            total += length / k * float(weights[ci, cj].sum())
        return total

    def refine(self, position_ne: Sequence[float], current_ne: np.ndarray, *, min_gain: float = 0.02) -> Replan | None:
        """A route to the goal under the stale-map prior, or None when it would not be better than ``current_ne``
        (the route flown now, ``(K, 2+)`` map points from the vehicle) by more than ``min_gain`` of its cost.

        Where the map was found wrong it is likely wrong nearby too (a wall across a street continues beyond
        what the sensor saw; a street blocked once is often blocked again further on): the search (textbook A*
        with per-cell costs, :meth:`~.search.GridPlanner.plan_weighted`) makes unseen cells near observed
        obstacles dearer (:meth:`suspect_weights`), so the route keeps away from them when another is not much
        longer. Every leg is free on the live grid, as :meth:`replan`'s; only the choice among routes differs.
        Slower than :meth:`replan` (tens of ms on SF), so the mission flies :meth:`replan`'s route first and runs
        this off its loop (:meth:`refine_job`).
        """
        job = self.refine_job(position_ne, current_ne, min_gain=min_gain)
        return None if job is None else job()

    def refine_job(self, position_ne: Sequence[float], current_ne: np.ndarray, *, min_gain: float = 0.02,
                   min_gain_m: float = 0.0, reopened: bool = False) -> Callable[[], Replan | None] | None:
        """:meth:`refine` in two halves: this one copies what it needs of the live layer (its grid, hits and seen
        cells: well under a millisecond on SF) and returns None at once when the prior is off or has nothing to go
        on; the callable it returns does the rest on that copy (the weights, ~10 ms on SF, and the search, which
        releases the GIL), touches nothing the sensing step changes, and may run on another thread. Its route must
        beat ``current_ne`` by ``min_gain`` of its cost plus ``min_gain_m``.

        ``reopened``: the layer has just dropped observed obstacles as noise (:class:`~.livemap.ScanUpdate`'s
        ``cleared``), so a way they closed may be open again and the route flown need no longer be the shortest on
        the live grid: the search runs even when that route crosses no doubtful cell, and with plain lengths when
        the prior is off or has nothing to go on. A detour taken round an obstacle that was never there is given
        up for the way it closed, instead of flown to its end."""
        live = self.live
        prior = self._prior_applies()
        if not (prior or reopened) or self.goal_blocked():
            return None
        current_ne = np.asarray(current_ne, float)[:, :2].copy()
        start, snapped = self._start_cell(position_ne)
        goal = live.cell_of(*self.goal_ne)
        grid, hits, known, goal_ne = live.grid.copy(), live.hits.copy(), live.known.copy(), self.goal_ne
        here = tuple(float(v) for v in position_ne[:2])

        def search() -> Replan | None:
            t0 = time.perf_counter()
            weights = self._weights(hits, known) if prior else None

            def cost(points: np.ndarray) -> float:
                return path_length(points) if weights is None else self.prior_cost(points, weights)

            current = cost(current_ne)
            if not reopened and current <= (1.0 + min_gain) * path_length(current_ne):
                return None  # it crosses no doubtful cell: no route is cheaper under the prior than the shortest
            # A cell path costs up to ~8 % more than its pruned legs: search no further than could still win.
            planner = GridPlanner(grid, method="jps" if weights is None else "astar")
            bound = 1.1 * current + 2.0
            try:
                path = (planner.plan(start, goal, max_cost=bound) if weights is None
                        else planner.plan_weighted(start, goal, weights, max_cost=bound))
            except PlanningError:
                return None
            points = self._points(path.cells, here, snapped, grid, goal_ne)
            if current - cost(points) <= min_gain * current + min_gain_m:
                return None
            waypoints = np.column_stack([points, np.full(len(points), self.altitude_m), headings_along(points)])
            return Replan(waypoints, (time.perf_counter() - t0) * 1e3, path_length(points), path.expanded, snapped)

        return search

    def reroute_job(self, position_ne: Sequence[float], current_ne: np.ndarray, *, min_gain: float = REOPEN_GAIN,
                    min_gain_m: float = REOPEN_GAIN_M) -> Callable[[], Replan | None] | None:
        """Once the layer dropped observed obstacles as noise: :meth:`refine_job` with ``reopened``, asking that
        the new route beat the rest of the one flown (``current_ne``) by ``min_gain`` of its cost plus
        ``min_gain_m`` (under the prior, as :meth:`refine` compares)."""
        return self.refine_job(position_ne, current_ne, min_gain=min_gain, min_gain_m=min_gain_m, reopened=True)

    def _points(self, path_cells: np.ndarray, position_ne: Sequence[float], snapped: bool,
                grid: np.ndarray | None = None, goal_ne: Sequence[float] | None = None) -> np.ndarray:
        """A searched cell path pruned (and pulled taut for any-angle) on ``grid`` (default: the live grid) into
        map points from the vehicle to ``goal_ne`` (default: the goal)."""
        live = self.live
        grid = live.grid if grid is None else grid
        goal_ne = self.goal_ne if goal_ne is None else goal_ne
        cells = prune_path(grid, path_cells)
        if self.method == "any-angle":
            cells = any_angle.taut_path(grid, cells)[0]
        points = cells + (live.north_offset + 0.5, live.east_offset + 0.5)
        here = np.asarray(position_ne, float)[:2]
        points = np.vstack([here, points if snapped else points[1:]]) if len(points) > 1 else np.vstack([here,
                                                                                                        points])
        points[-1] = goal_ne  # the goal itself (within its cell, which is free)
        return points

    def fallback(self, position_ne: Sequence[float]) -> tuple[float, float] | None:
        """The free (and landable) cell centre nearest the goal that the vehicle can reach from ``position_ne``
        (4-connected free space on the live grid: the search's diagonal rule never joins more), or None."""
        live = self.live
        start, _ = self._start_cell(position_ne)
        n, m = live.shape
        if not (0 <= start[0] < n and 0 <= start[1] < m) or live.grid[start]:
            return None
        labels, _count = ndimage.label(~live.grid)
        mine = labels == labels[start]
        if self.landable is not None:
            mine &= self.landable
        cells = np.argwhere(mine)
        if len(cells) == 0:
            return None
        centres = cells + (live.north_offset + 0.5, live.east_offset + 0.5)
        k = int(np.argmin(np.hypot(*(centres - self.goal_ne).T)))
        return float(centres[k, 0]), float(centres[k, 1])

    def viewpoint(self, position_ne: Sequence[float],
                  looked_from: Sequence[Sequence[float]] = ()) -> tuple[float, float] | None:
        """Where to look from, when the goal is out of reach on the live layer, before giving it up: the last free
        cell centre (map metres) of the cheapest way to the goal on the map's own grid on which a metre through
        observed obstacles or their margins costs up to ``VIEW_CROSSING_WEIGHT`` metres, the more the surer the
        layer is of them (:meth:`_crossing_weights`), and ``VIEW_LOOKED_WEIGHT`` times more near a point in
        ``looked_from``: the edge of the least certain, thinnest observed closure between the vehicle and the goal,
        one margin from it. None when the layer has seen only fine sectors, the map itself cuts the goal off, or
        that edge is where the vehicle is.

        Wide sectors (ArduPilot's 45 degrees) mark the whole arc at a reading's range, and an arc through free
        street beside a wall's end, inflated, can close the only way on. Only a view from where that wedge's
        nearest obstacle lies beyond those cells sees them free; holding where the way was found closed often has
        none (a map building nearer in every wedge that covers them), flying up to the closure's edge often does
        (held-out seed 14's mission 0, offline model: given up at its start before, at the goal at 1.03x the true
        route's metres after its looks). Fine sectors (PX4's 5 degrees) place their hits well enough that a
        closure they show is one: there this returns None and the goal is given up at once.
        """
        live = self.live
        if not live.wide_sectors:
            return None
        start, _ = self._start_cell(position_ne)
        goal = live.cell_of(*self.goal_ne)
        n, m = live.shape
        if not (0 <= start[0] < n and 0 <= start[1] < m and 0 <= goal[0] < n and 0 <= goal[1] < m):
            return None
        weights = self._crossing_weights()
        if len(looked_from):
            ii, jj = np.ogrid[0:n, 0:m]
            for point in looked_from:
                ci, cj = live.cell_of(float(point[0]), float(point[1]))
                near = (ii - ci) ** 2 + (jj - cj) ** 2 <= VIEW_LOOKED_RADIUS_M**2
                weights[near & live.inflated] *= VIEW_LOOKED_WEIGHT
        try:
            path = GridPlanner(live.base).plan_weighted(start, goal, weights)
        except PlanningError:
            return None
        cells = path.cells
        closed = live.grid[cells[:, 0], cells[:, 1]]
        k = int(np.argmax(closed))
        if not closed[k] or k == 0:
            return None
        i, j = cells[k - 1]
        return float(i + live.north_offset + 0.5), float(j + live.east_offset + 0.5)

    def _crossing_weights(self) -> np.ndarray:
        """:meth:`viewpoint`'s cost per metre of each cell: 1 on free street, and through an observed obstacle or
        its margin ``VIEW_CROSSING_WEIGHT`` times how sure the layer is of the surest hit within the margin (its
        hits over its times seen free plus one, over ``VIEW_SURE_HITS``, between a tenth and 1).

        A wall flown along is hit hundreds of times and never seen free; a wide arc's cells through free street are
        hit a few times and seen free about as often (held-out seed 17's mission 1, offline model: a median of 28
        hits and 0 frees against 2 and 2). Weighted alike, every crossing of a wall's margins costs the same, the
        cheapest was the real wall beside the vehicle, and three looks crept along it without reaching the false
        closure at its end."""
        live = self.live
        weights = np.ones(live.shape)
        cells = np.argwhere(live.hits)
        if not len(cells):
            return weights
        r = int(math.ceil(live.margin_m)) + 1
        n, m = live.shape
        i0, j0 = np.maximum(cells.min(axis=0) - r, 0)
        i1, j1 = np.minimum(cells.max(axis=0) + r + 1, (n, m))
        window = (slice(i0, i1), slice(j0, j1))
        sure = np.where(live.hits[window],
                        live.hit_count[window] / (live.free_count[window].astype(np.float64) + 1.0), 0.0)
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        nearest = ndimage.maximum_filter(sure, footprint=yy**2 + xx**2 <= (live.margin_m + 0.5) ** 2)
        share = np.clip(nearest / VIEW_SURE_HITS, 0.1, 1.0)
        weights[window] = np.where(live.inflated[window], 1.0 + (VIEW_CROSSING_WEIGHT - 1.0) * share, 1.0)
        return weights

    def route_to(self, position_ne: Sequence[float], target_ne: Sequence[float]) -> Replan:
        """A route to another point (e.g. the fallback), like :meth:`replan`."""
        saved = self.goal_ne
        self.goal_ne = (float(target_ne[0]), float(target_ne[1]))
        try:
            return self.replan(position_ne)
        finally:
            self.goal_ne = saved
