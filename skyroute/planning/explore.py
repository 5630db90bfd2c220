"""Frontier exploration on the live map: the area, its frontiers, the nearest reachable one, coverage, the map out.

Arrays in, arrays out (planning never imports the layers above). The explored area is the disk of
``radius_m`` round the start; the live layer (:class:`~.livemap.LiveMap`) covers that disk plus the sensor's range
and the margin, so walls at the disk's edge are seen. Grids are ``[north_idx, east_idx]``, cells 1 m.

* A **frontier** cell is known free (seen free by the sensor, not an observed obstacle), free on the planning grid
  (outside every margin, so the vehicle may fly there), inside the disk, and has a 4-neighbour that is unknown and
  inside the disk: flying there shows something new (the rover's "closest unexplored pixel").
* :func:`nearest_frontier` runs one Dijkstra (scikit-image's ``MCP_Geometric``, 8-connected, diagonal sqrt 2) from
  the vehicle's cell over the planning grid's free cells and takes the cheapest frontier at least ``min_m`` away
  that is not ``abandoned`` (the explorer abandons a frontier it reached without clearing, or could not reach,
  so it never loops on one).
* **Search cells** (for ground targets): cells free on the planning grid, at least a cell inside the free space,
  known free and inside the disk, that the downward camera has not looked at yet (:meth:`ExploreArea.view` marks
  its footprint round the vehicle, radius ``camera_radius_m``). The explorer's goals are the frontiers and the
  search cells, so it keeps going until it has both seen every wall it can reach and looked at every street.
* :func:`coverage` is the share of the disk's cells that are known.
* The saved map is the observed obstacle cells seen free at most once in eight hits (a wedge's reading puts its
  whole arc on the wall, which grazing sectors smear a cell or two into the street; those cells are seen free by
  the sectors that look across them).
* :func:`merged_boxes` turns occupied cells into ``colliders.csv`` boxes: each row's runs of occupied cells, runs
  with the same columns in consecutive rows merged into one rectangle.

>>> hits = np.zeros((5, 6), bool); hits[1:3, 1:4] = True; hits[4, 5] = True
>>> merged_boxes(hits, 10, 20, height_m=8.0).tolist()
[[12.0, 22.5, 4.0, 1.0, 1.5, 4.0], [14.5, 25.5, 4.0, 0.5, 0.5, 4.0]]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skyroute.planning.cspace import rasterise_window
from skyroute.planning.livemap import LiveMap


@dataclass(frozen=True)
class Frontier:
    """The chosen frontier: ``cell`` (north_idx, east_idx), ``point_ne`` its centre (map m), ``cost_m`` the path
    length to it on the planning grid (m), ``count`` the frontier cells left in the disk."""

    cell: tuple[int, int]
    point_ne: tuple[float, float]
    cost_m: float
    count: int


class ExploreArea:
    """The explored disk and the live layer over it.

    Parameters
    ----------
    obstacles : (N, 6) array
        The known map's boxes (may be empty).
    start_ne : (float, float)
        Centre of the explored disk (map m).
    radius_m, altitude_m, safety_m : float
    sensor_range_m : float
        The obstacle sensor's range: the layer reaches that far beyond the disk.
    camera_radius_m : float or None
        Radius of the downward camera's footprint on the ground (m); None: no target search (search cells off).
    live_kwargs
        Passed to :class:`~.livemap.LiveMap` (``confirm_hits``, ...).
    """

    def __init__(self, obstacles: np.ndarray, start_ne: Sequence[float], radius_m: float, altitude_m: float,
                 safety_m: float, sensor_range_m: float = 30.0, camera_radius_m: float | None = None,
                 **live_kwargs) -> None:
        if not (math.isfinite(radius_m) and radius_m > 0):
            raise ValueError(f"radius must be finite and > 0 m, got {radius_m}")
        self.start_ne = (float(start_ne[0]), float(start_ne[1]))
        self.radius_m, self.altitude_m, self.safety_m = float(radius_m), float(altitude_m), float(safety_m)
        reach = int(math.ceil(radius_m + sensor_range_m + safety_m + 2))
        self.north_offset = int(math.floor(self.start_ne[0])) - reach
        self.east_offset = int(math.floor(self.start_ne[1])) - reach
        shape = (2 * reach + 1, 2 * reach + 1)
        data = np.asarray(obstacles, float).reshape(-1, 6)
        if len(data):
            base = rasterise_window(data, altitude_m, safety_m, self.north_offset, self.east_offset, shape)
            footprint = rasterise_window(data, altitude_m, 0.0, self.north_offset, self.east_offset, shape)
        else:
            base, footprint = np.zeros(shape, bool), np.zeros(shape, bool)
        self.footprint = footprint
        self.live = LiveMap(base, footprint, self.north_offset, self.east_offset, safety_m, **live_kwargs)
        ii, jj = np.mgrid[0:shape[0], 0:shape[1]]
        centre_n = ii + self.north_offset + 0.5 - self.start_ne[0]
        centre_e = jj + self.east_offset + 0.5 - self.start_ne[1]
        self.disk = np.hypot(centre_n, centre_e) <= radius_m
        self.abandoned = np.zeros(shape, bool)
        self.viewed = np.zeros(shape, bool)
        self.camera_radius_m = camera_radius_m

    def cell_of(self, north_m: float, east_m: float) -> tuple[int, int]:
        return self.live.cell_of(north_m, east_m)

    def centre_of(self, cell: Sequence[int]) -> tuple[float, float]:
        return float(cell[0] + self.north_offset + 0.5), float(cell[1] + self.east_offset + 0.5)

    @property
    def known(self) -> np.ndarray:
        """Cells seen by the sensor, or the known map's own buildings."""
        return self.live.known | self.footprint

    def frontiers(self) -> np.ndarray:
        """The frontier mask (see the module notes), abandoned cells excluded."""
        return frontier_mask(self.known, self.live.hits | self.footprint, self.live.grid, self.disk) & ~self.abandoned

    def coverage(self) -> float:
        """Share of the disk's cells that are known (0..1)."""
        return coverage(self.known, self.disk)

    def view(self, north_m: float, east_m: float) -> None:
        """Mark the camera's footprint round the vehicle at map ``(north_m, east_m)`` as looked at."""
        if self.camera_radius_m is None:
            return
        r = self.camera_radius_m
        i, j = self.cell_of(north_m, east_m)
        k = int(math.ceil(r)) + 1
        n, m = self.viewed.shape
        i0, i1, j0, j1 = max(i - k, 0), min(i + k + 1, n), max(j - k, 0), min(j + k + 1, m)
        if i0 >= i1 or j0 >= j1:
            return
        ii, jj = np.mgrid[i0:i1, j0:j1]
        near = np.hypot(ii + self.north_offset + 0.5 - north_m, jj + self.east_offset + 0.5 - east_m) <= r
        self.viewed[i0:i1, j0:j1] |= near

    def search_cells(self) -> np.ndarray:
        """Cells the camera still has to look at (see the module notes); none without a camera."""
        if self.camera_radius_m is None:
            return np.zeros_like(self.viewed)
        grid = self.live.grid
        inner = ~grid
        inner[1:, :] &= ~grid[:-1, :]
        inner[:-1, :] &= ~grid[1:, :]
        inner[:, 1:] &= ~grid[:, :-1]
        inner[:, :-1] &= ~grid[:, 1:]
        return inner & self.live.known & ~self.live.hits & self.disk & ~self.viewed & ~self.abandoned

    def goals(self) -> np.ndarray:
        """Where the explorer may go next: the frontiers and the search cells."""
        return self.frontiers() | self.search_cells()

    def mapped_cells(self) -> np.ndarray:
        """Observed obstacle cells for the saved map (see the module notes)."""
        live = self.live
        return live.hits & (8 * live.free_count.astype(np.int64) <= live.hit_count.astype(np.int64))

    def abandon(self, point_ne: Sequence[float], radius_m: float = 4.0) -> int:
        """Abandon the frontier cells within ``radius_m`` of a point; how many cells were marked."""
        i, j = self.cell_of(*point_ne)
        r = int(math.ceil(radius_m))
        n, m = self.disk.shape
        i0, i1, j0, j1 = max(i - r, 0), min(i + r + 1, n), max(j - r, 0), min(j + r + 1, m)
        ii, jj = np.mgrid[i0:i1, j0:j1]
        near = np.hypot(ii - i, jj - j) <= radius_m
        before = int(self.abandoned[i0:i1, j0:j1].sum())
        self.abandoned[i0:i1, j0:j1] |= near
        return int(self.abandoned[i0:i1, j0:j1].sum()) - before

    def nearest_frontier(self, position_ne: Sequence[float], min_m: float = 3.0) -> Frontier | None:
        """The cheapest reachable frontier from the vehicle (see :func:`nearest_frontier`).

        A vehicle inside a margin (a wall seen late, or seen again nearer) is searched from where it joins the free
        space (:meth:`LiveMap.way_out`, as the routes to a frontier start), the straight leg there added to the cost:
        from the blocked cell itself every neighbour is blocked too, and nothing would be reachable."""
        mask = self.goals()
        start, lead = self.cell_of(*position_ne), 0.0
        n, m = self.live.shape
        if 0 <= start[0] < n and 0 <= start[1] < m and self.live.grid[start]:
            out = self.live.way_out(start)
            if out is not None:
                start, lead = out, math.dist(start, out)
        found = nearest_frontier(self.live.grid, mask, start, max(min_m - lead, 0.0))
        if found is None:
            return None
        cell, cost = found
        return Frontier(cell, self.centre_of(cell), cost + lead, int(mask.sum()))

    def occupied_boxes(self, height_m: float) -> np.ndarray:
        """Observed obstacle cells as merged ``colliders.csv`` boxes ``(K, 6)`` of ``height_m`` (m)."""
        return merged_boxes(self.mapped_cells(), self.north_offset, self.east_offset, height_m)


def frontier_mask(known: np.ndarray, occupied: np.ndarray, grid: np.ndarray, area: np.ndarray) -> np.ndarray:
    """Known-free cells, free on the planning ``grid``, in ``area``, with an unknown 4-neighbour in ``area``.

    >>> known = np.zeros((3, 5), bool); known[:, :2] = True
    >>> frontier_mask(known, np.zeros_like(known), np.zeros_like(known), np.ones_like(known)).astype(int).tolist()
    [[0, 1, 0, 0, 0], [0, 1, 0, 0, 0], [0, 1, 0, 0, 0]]
    """
    unknown = ~known & area
    touches = np.zeros_like(unknown)
    touches[1:, :] |= unknown[:-1, :]
    touches[:-1, :] |= unknown[1:, :]
    touches[:, 1:] |= unknown[:, :-1]
    touches[:, :-1] |= unknown[:, 1:]
    return known & ~occupied & ~grid & area & touches


def nearest_frontier(grid: np.ndarray, frontiers: np.ndarray, start_cell: Sequence[int],
                     min_m: float = 0.0) -> tuple[tuple[int, int], float] | None:
    """The frontier cell with the shortest 8-connected path from ``start_cell`` over the free cells of ``grid``
    (True = blocked), at least ``min_m`` along it, and that length (m); None if none is reachable.

    A start inside a margin (blocked) is searched from anyway: the vehicle is there.

    >>> g = np.zeros((5, 5), bool); g[1:4, 2] = True     # a wall east: round it by 4 diagonals, 4 sqrt 2
    >>> f = np.zeros_like(g); f[2, 4] = True; f[0, 0] = True
    >>> cell, cost = nearest_frontier(g, f, (2, 0)); cell, round(cost, 3)
    ((0, 0), 2.0)
    >>> cell, cost = nearest_frontier(g, f, (2, 0), min_m=3.0); cell, round(cost, 3)
    ((2, 4), 5.657)
    """
    from skimage.graph import MCP_Geometric

    n, m = grid.shape
    i, j = int(start_cell[0]), int(start_cell[1])
    if not (0 <= i < n and 0 <= j < m):
        return None
    costs = np.where(grid, np.inf, 1.0)
    costs[i, j] = 1.0
    mcp = MCP_Geometric(costs, fully_connected=True)
    cumulative, _ = mcp.find_costs([(i, j)])
    # MCP_Geometric charges half of each end cell's cost per step: with unit costs a path's cost is its length.
    candidates = frontiers & np.isfinite(cumulative) & (cumulative >= min_m)
    if not candidates.any():
        return None
    flat = np.where(candidates, cumulative, np.inf)
    k = int(np.argmin(flat))
    cell = (k // m, k % m)
    return cell, float(flat[cell])


def coverage(known: np.ndarray, area: np.ndarray) -> float:
    """Known share of ``area``'s cells (0..1).

    >>> coverage(np.array([True, False, True, True]), np.array([True, True, True, False]))
    0.6666666666666666
    """
    total = int(area.sum())
    return float((known & area).sum()) / total if total else 0.0


def merged_boxes(occupied: np.ndarray, north_offset: int, east_offset: int, height_m: float) -> np.ndarray:
    """Occupied cells as ``colliders.csv`` rows ``[north, east, alt, half_north, half_east, half_alt]`` (m):
    runs along each row (constant north index), merged with identical runs of the following rows; every box
    stands on the ground and is ``height_m`` tall. The union of the boxes is exactly the occupied cells."""
    occ = np.asarray(occupied, bool)
    boxes: list[list[float]] = []
    open_runs: dict[tuple[int, int], int] = {}  # (j0, j1) -> first row i
    n = occ.shape[0]
    for i in range(n + 1):
        runs: set[tuple[int, int]] = set()
        if i < n:
            row = np.concatenate([[False], occ[i], [False]])
            edges = np.flatnonzero(row[1:] != row[:-1])
            runs = {(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])}
        for run in [r for r in open_runs if r not in runs]:
            i0 = open_runs.pop(run)
            lo_n, hi_n = i0 + north_offset, i + north_offset
            lo_e, hi_e = run[0] + east_offset, run[1] + east_offset
            boxes.append([(lo_n + hi_n) / 2, (lo_e + hi_e) / 2, height_m / 2, (hi_n - lo_n) / 2,
                          (hi_e - lo_e) / 2, height_m / 2])
        for run in runs:
            open_runs.setdefault(run, i)
    boxes.sort(key=lambda b: (b[0] - b[3], b[1] - b[4]))
    return np.array(boxes, float).reshape(-1, 6)


class Explorer:
    """What the exploration mission needs of planning: the area, its live layer, routes on it.

    Parameters
    ----------
    area : ExploreArea
    method : {"grid", "any-angle"}
        How routes are pruned (:class:`~.replan.Replanner`).
    look_ahead_m : float
        How far along the remaining path :meth:`check` looks for observed obstacles.
    """

    def __init__(self, area: ExploreArea, *, method: str = "grid", look_ahead_m: float = 40.0) -> None:
        from skyroute.planning.replan import Replanner

        self.area = area
        # The margin round observed obstacles stays whole: a frontier out of reach is common here and only means
        # another one is chosen, not a reason to fly closer to what was seen (Replanner.replan's narrowing).
        self.replanner = Replanner(area.live, area.start_ne, area.altitude_m, look_ahead_m=look_ahead_m,
                                   method=method, min_margin_m=area.live.safety_m)

    # the sensing step's ObstacleMap (skyroute.flight.replanning)
    def add_scan(self, north_m: float, east_m: float, bearings_rad, half_width_rad: float, distances_m,
                 max_range_m: float, bearing_error_rad: float = 0.0, position_error_m: float = 0.0):
        return self.area.live.add_scan(north_m, east_m, bearings_rad, half_width_rad, distances_m, max_range_m,
                                       bearing_error_rad, position_error_m)

    def check(self, position_ne: Sequence[float], waypoints_ne: np.ndarray):
        """The first observed obstacle (or its margin) on the remaining path, or None (:meth:`Replanner.check`)."""
        return self.replanner.check(position_ne, waypoints_ne)

    def discovered_ne(self) -> np.ndarray:
        return self.area.live.hit_cells_ne()

    def clearance_m(self, north_m: float, east_m: float, direction_north: float, direction_east: float,
                    max_m: float) -> float:
        return self.area.live.clearance_m(north_m, east_m, direction_north, direction_east, max_m)

    def free_point(self, point_ne: Sequence[float]) -> tuple[float, float] | None:
        """The point itself if free on the live grid, else the nearest free cell's centre (None: none)."""
        from skyroute.planning.cspace import nearest_free_cell

        live = self.area.live
        cell = live.cell_of(*point_ne)
        n, m = live.shape
        if not (0 <= cell[0] < n and 0 <= cell[1] < m):
            return None
        if not live.grid[cell]:
            return float(point_ne[0]), float(point_ne[1])
        free = nearest_free_cell(live.grid, cell)
        return None if free is None else self.area.centre_of(free)

    def route_to(self, position_ne: Sequence[float], target_ne: Sequence[float], extend_m: float = 0.0) -> np.ndarray:
        """Waypoints ``(K, 4)`` from the position to the target (snapped to the nearest free cell) on the live grid;
        ``extend_m`` carries the last leg on past the target, as far as it stays free on the live grid and inside
        the disk (so a vehicle that will be sent on once the target is seen need not brake for it).

        Raises
        ------
        PlanningError
            (``GoalBlocked``, ``GoalUnreachable``, ``NoPathError``) when there is no route.
        """
        from skyroute.planning.errors import NoPathError

        goal = self.free_point(target_ne)
        if goal is None:
            raise NoPathError(f"no free cell near ({target_ne[0]:.1f} N, {target_ne[1]:.1f} E) on the grid")
        route = self.replanner.route_to(position_ne, goal).waypoints
        if extend_m > 0 and len(route) >= 2:
            route = self._extended(route, extend_m)
        return route

    def _extended(self, route: np.ndarray, extend_m: float, step_m: float = 0.25) -> np.ndarray:
        leg = route[-1, :2] - route[-2, :2]
        length = float(np.hypot(*leg))
        if length < 1e-6:
            return route
        unit = leg / length
        live, area = self.area.live, self.area
        n, m = live.shape
        reach = 0.0
        for s in np.arange(step_m, extend_m + 1e-9, step_m):
            i, j = live.cell_of(*(route[-1, :2] + s * unit))
            if not (0 <= i < n and 0 <= j < m) or live.grid[i, j] or not area.disk[i, j]:
                break
            reach = float(s)
        out = route.copy()
        out[-1, :2] = route[-1, :2] + reach * unit
        return out

    # frontiers
    def next_frontier(self, position_ne: Sequence[float], min_m: float = 3.0) -> Frontier | None:
        return self.area.nearest_frontier(position_ne, min_m)

    def is_frontier(self, point_ne: Sequence[float], within_cells: int = 1) -> bool:
        """Whether a frontier cell (not abandoned) lies within ``within_cells`` of the point's cell."""
        i, j = self.area.cell_of(*point_ne)
        mask = self.area.goals()
        n, m = mask.shape
        r = within_cells
        return bool(mask[max(i - r, 0):min(i + r + 1, n), max(j - r, 0):min(j + r + 1, m)].any())

    def abandon(self, point_ne: Sequence[float], radius_m: float = 4.0) -> int:
        return self.area.abandon(point_ne, radius_m)

    def view(self, north_m: float, east_m: float) -> None:
        """The camera looked down at map ``(north_m, east_m)``."""
        self.area.view(north_m, east_m)

    def coverage(self) -> float:
        return self.area.coverage()

    def why_unreachable(self, position_ne: Sequence[float]) -> str:
        """When :meth:`next_frontier` found nothing: how many goal cells are left out of reach of the map point, and
        whether its own cell is inside an observed obstacle's margin; "" when none is left."""
        area = self.area
        left = int(area.goals().sum())
        if left == 0:
            return ""
        i, j = area.cell_of(*position_ne)
        grid = area.live.grid
        inside = 0 <= i < grid.shape[0] and 0 <= j < grid.shape[1] and bool(grid[i, j])
        return (f"{left} frontier and search cells, none reachable from ({position_ne[0]:.1f} N, "
                f"{position_ne[1]:.1f} E){'; that cell is inside an obstacle margin' if inside else ''}")
