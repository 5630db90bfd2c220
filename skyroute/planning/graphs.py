"""Planners beyond the grid, behind one call: ``plan(name, obstacles, start_ne, goal_ne, altitude_m, safety_m)``.

=============  ==============================================================================  =================
name           what it searches                                                                module
=============  ==============================================================================  =================
grid           8-connected cells, optimal (JPS), line-of-sight pruned                          grid
medial-axis    skeleton of the free cells (scikit-image ``medial_axis``), 8-connected pixels    here
voronoi        Voronoi ridges of the C-space obstacle boundary (scipy.spatial), kept if free    here
any-angle      the grid's optimal route, string-pulled with sliding turns (any heading)          any_angle
grid3d         (north, east, altitude level) cells with climb/descent cost, rooftop goals      grid3d
prm            probabilistic roadmap sampled in (north, east, altitude), k-nearest edges        sampling
=============  ==============================================================================  =================

Every planner returns a ``plan.Plan`` with ``[north_m, east_m, altitude_m, heading_rad]`` waypoints and
raises the ``errors`` module's errors (``OutsideGridError``, ``BlockedCellError``, ``NoPathError``) for a bad start,
a bad goal or no path. The 2D planners fly at one altitude and put waypoints on cell centres of
``create_grid(obstacles, altitude_m, safety_m)``; every leg's supercover is free on that grid. The 3D planners
keep every leg clear of every obstacle box grown by ``safety_m``. :func:`colliding_legs` checks both.

The per-map structure (grid, skeleton, Voronoi graph, roadmap, height map) is built once per
``(obstacles, altitude_m, safety_m, options)`` and cached (:func:`structure_for`), so repeated queries only search;
``Plan.extra["build_ms"]`` reports the build, ``Plan.search_ms`` the query.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from skyroute.planning import PLANNERS, PLANNERS_3D, any_angle, grid3d, sampling
from skyroute.planning.cspace import cell_to_map, create_grid, map_to_cell
from skyroute.planning.errors import NoPathError
from skyroute.planning.grid import GridMap
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import (
    headings_along,
    line_of_sight,
    path_length,
    prune_line_of_sight,
    prune_path,
    waypoints_from_cells,
)

_CACHE_SIZE = 8
_LINK_CANDIDATES = (16, 64, 256)  # nearest roadmap nodes tried, in rounds, when linking a start or goal


# --------------------------------------------------------------------------------------------------------------
# Entry point


def plan(
    name: str,
    obstacles: np.ndarray,
    start_ne: Sequence[float],
    goal_ne: Sequence[float],
    altitude_m: float,
    safety_m: float,
    *,
    goal_alt_m: float | None = None,
    seed: int = 0,
    snap_start: bool = False,
    samples: int = 1000,
) -> Plan:
    """Plan with planner ``name`` from ``start_ne`` to ``goal_ne`` (map-frame ``(north_m, east_m)``).

    Parameters
    ----------
    name : str
        One of :data:`PLANNERS`.
    obstacles : (N, 6) array
        Obstacle boxes ``north, east, alt, half_north, half_east, half_alt`` in metres.
    start_ne, goal_ne : (2,) float
        Map points in metres.
    altitude_m, safety_m : float
        Flight altitude (the start's, and the goal's unless ``goal_alt_m``) and obstacle margin in metres.
    goal_alt_m : float, optional
        Goal altitude for the 3D planners (``grid3d``, ``prm``), e.g. just above a roof plus the margin. The 2D
        planners reject a goal altitude different from ``altitude_m``.
    seed, samples : int
        Random seed and number of roadmap nodes of ``prm`` (the others are deterministic).
    snap_start : bool
        A start inside the safety margin (not inside an obstacle) plans from the nearest free cell; the route
        then begins with a lead-in leg from the start point itself, which is exempt from the margin.

    Returns
    -------
    skyroute.planning.plan.Plan

    Raises
    ------
    ValueError
        For an unknown planner or a goal altitude a 2D planner cannot fly.
    skyroute.planning.errors.OutsideGridError, BlockedCellError, NoPathError
        For a start or goal off the map or blocked, or no path.

    Examples
    --------
    A wall 2 m thick, 60 m long and 20 m tall (as in ``GridMap``'s example); with a 2 m margin the cells north
    -3..3 m, east -32..32 m are blocked, so the route turns at the first free cell centres past the east end:

    >>> boxes = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    >>> route = plan("any-angle", boxes, (-20.0, 0.0), (20.0, 0.0), altitude_m=5, safety_m=2)
    >>> route.waypoints[:, :3].tolist()
    [[-19.5, 0.5, 5.0], [-3.5, 32.5, 5.0], [3.5, 32.5, 5.0], [20.5, 0.5, 5.0]]
    >>> colliding_legs(route, boxes, safety_m=2)
    []
    """
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose from {', '.join(PLANNERS)}")
    if name not in PLANNERS_3D and goal_alt_m is not None and goal_alt_m != altitude_m:
        raise ValueError(
            f"planner {name!r} flies at one altitude ({altitude_m} m); goal_alt_m needs grid3d or prm"
        )
    obstacles = np.asarray(obstacles, dtype=np.float64)
    options = {"seed": seed, "n_samples": samples} if name == "prm" else {}
    planner, build_ms = structure_for(name, obstacles, altitude_m, safety_m, **options)
    if name in PLANNERS_3D:
        result = planner.plan(start_ne, goal_ne, goal_alt_m=goal_alt_m, snap_start=snap_start)
    else:
        result = planner.plan(start_ne, goal_ne, snap_start=snap_start)
    return _with_extra(result, {"build_ms": round(build_ms, 3)})


def _with_extra(result: Plan, extra: dict) -> Plan:
    return dataclasses.replace(result, extra={**result.extra, **extra})


# --------------------------------------------------------------------------------------------------------------
# Per-map structures, cached


def _builder(name: str) -> Callable:
    return {
        "grid": GridMap.build,
        "medial-axis": MedialAxisRoadmap.build,
        "voronoi": VoronoiRoadmap.build,
        "any-angle": AnyAnglePlanner.build,
        "grid3d": grid3d.Grid3DPlanner.build,
        "prm": sampling.ProbabilisticRoadmap.build,
    }[name]


_cache: OrderedDict = OrderedDict()


def obstacles_key(obstacles: np.ndarray) -> str:
    """A digest of the obstacle array's shape and bytes, to key per-map caches."""
    obstacles = np.ascontiguousarray(obstacles, dtype=np.float64)
    digest = hashlib.blake2b(obstacles.tobytes(), digest_size=16)
    digest.update(str(obstacles.shape).encode())
    return digest.hexdigest()


def structure_for(name: str, obstacles: np.ndarray, altitude_m: float, safety_m: float, **options):
    """The planner object for ``name`` on this map, built on first use and kept (LRU, 8 entries).

    Returns ``(planner, build_ms)``: ``build_ms`` is the time the build took when it ran (also on cache hits).
    """
    key = (name, obstacles_key(obstacles), float(altitude_m), float(safety_m), tuple(sorted(options.items())))
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key]
    t0 = time.perf_counter()
    planner = _builder(name)(obstacles, altitude_m, safety_m, **options)
    entry = (planner, (time.perf_counter() - t0) * 1e3)
    _cache[key] = entry
    while len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return entry


def clear_cache() -> None:
    """Forget every cached per-map structure."""
    _cache.clear()


# --------------------------------------------------------------------------------------------------------------
# The shared collision check


def colliding_legs(
    plan_: Plan, obstacles: np.ndarray, safety_m: float, *, skip_lead_in: bool = False
) -> list[int]:
    """Indices of the legs of ``plan_`` that break its planner's collision rule (empty = collision-free).

    2D planners (all waypoints at one altitude, planner not in :data:`PLANNERS_3D`): every waypoint must be a
    cell centre of ``create_grid(obstacles, altitude, safety_m)`` and every leg's supercover free on that grid.
    3D planners: every leg (a 3D segment) must stay out of every obstacle box grown by ``safety_m`` on all
    sides (touching the grown box is allowed). ``skip_lead_in`` exempts leg 0, the lead-in of a snapped start.
    """
    waypoints = np.asarray(plan_.waypoints, dtype=np.float64)
    first = 1 if skip_lead_in else 0
    if len(waypoints) < 2:
        return []
    if plan_.planner in PLANNERS_3D:
        clear = grid3d.legs_clear_of_boxes(waypoints[:, :3], obstacles, safety_m)
        return [k for k in range(first, len(clear)) if not clear[k]]
    altitude = waypoints[0, 2]
    if not np.all(waypoints[:, 2] == altitude):
        return list(range(first, len(waypoints) - 1))
    grid, north_offset, east_offset = create_grid(obstacles, altitude, safety_m)
    bad = []
    for k in range(first, len(waypoints) - 1):
        cells = []
        for point in waypoints[k : k + 2, :2]:
            cell = map_to_cell(point[0], point[1], north_offset, east_offset)
            on_centre = np.allclose(cell_to_map(cell, north_offset, east_offset), point, atol=1e-9)
            cells.append(cell if on_centre else None)
        lead_in_start = k == 0 and skip_lead_in
        if cells[1] is None or (cells[0] is None and not lead_in_start):
            bad.append(k)
        elif not line_of_sight(grid, cells[0], cells[1]):
            bad.append(k)
    return bad


def legs_collision_free(
    plan_: Plan, obstacles: np.ndarray, safety_m: float, *, skip_lead_in: bool = False
) -> bool:
    """True if :func:`colliding_legs` finds no leg in collision."""
    return not colliding_legs(plan_, obstacles, safety_m, skip_lead_in=skip_lead_in)


# --------------------------------------------------------------------------------------------------------------
# Shared 2D machinery: endpoints on the grid, plans from cells


def free_mask(grid: np.ndarray) -> np.ndarray:
    """Our occupancy grid (True = blocked) as scikit-image's convention (True = free)."""
    return np.logical_not(grid)


def resolve_endpoints(
    gmap: GridMap, start_ne: Sequence[float], goal_ne: Sequence[float], snap_start: bool
) -> tuple[tuple[int, int], tuple[int, int], np.ndarray | None]:
    """Start and goal cells on ``gmap``'s grid, checked, and the lead-in point of a snapped start (or None).

    Raises ``OutsideGridError`` / ``BlockedCellError`` like ``GridMap.plan``.
    """
    start_cell, lead_in = gmap.snap_start(start_ne) if snap_start else (gmap.cell_of(*start_ne), None)
    start_cell = gmap.planner.check_cell("start", start_cell)
    goal_cell = gmap.planner.check_cell("goal", gmap.cell_of(*goal_ne))
    return start_cell, goal_cell, lead_in


def plan_from_cells(
    name: str,
    gmap: GridMap,
    cells: np.ndarray,
    cost_cells: float,
    search_ms: float,
    expanded: int,
    lead_in: np.ndarray | None,
    extra: dict,
    structure: dict,
) -> Plan:
    """A 2D ``Plan`` from a route of cells whose consecutive pairs are mutually visible: prune, waypoints."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    cells = cells[np.concatenate(([True], (np.diff(cells, axis=0) != 0).any(axis=1)))]  # a node on the start
    pruned = prune_path(gmap.grid, cells)
    waypoints = waypoints_from_cells(pruned, gmap.north_offset, gmap.east_offset, gmap.altitude_m)
    raw = cells + (gmap.north_offset + 0.5, gmap.east_offset + 0.5)
    if lead_in is not None:
        points = np.vstack([lead_in, waypoints[:, :2]])
        waypoints = np.column_stack([points, np.full(len(points), gmap.altitude_m), headings_along(points)])
        raw = np.vstack([lead_in, raw])
    return Plan(
        planner=name,
        waypoints=waypoints,
        raw_path_ne=raw,
        length_m=path_length(waypoints[:, :2]),
        cost_m=float(cost_cells),
        search_ms=search_ms,
        expanded=int(expanded),
        extra=extra,
        structure=structure,
    )


# --------------------------------------------------------------------------------------------------------------
# Any-angle


@dataclass(frozen=True)
class AnyAnglePlanner:
    """Any-angle routes on the grid: the optimal 8-connected route (jump point search), line-of-sight pruned, then
    pulled taut (``any_angle.taut_path``): each turn slides to the nearby cell that shortens its legs while they
    stay visible. Legs are supercover-free by construction; ``cost_m`` is the grid optimum it started from."""

    gmap: GridMap

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float) -> AnyAnglePlanner:
        return cls(GridMap.build(obstacles, altitude_m, safety_m))

    def plan(self, start_ne: Sequence[float], goal_ne: Sequence[float], *, snap_start: bool = False) -> Plan:
        start, goal, lead_in = resolve_endpoints(self.gmap, start_ne, goal_ne, snap_start)
        t0 = time.perf_counter()
        path = self.gmap.planner.plan(start, goal)
        cells, sweeps = any_angle.taut_path(self.gmap.grid, prune_line_of_sight(self.gmap.grid, path.cells))
        search_ms = (time.perf_counter() - t0) * 1e3
        extra = {"start_cell": list(start), "goal_cell": list(goal), "taut_sweeps": int(sweeps)}
        return plan_from_cells("any-angle", self.gmap, cells, path.cost, search_ms, path.expanded, lead_in, extra,
                               {})


# --------------------------------------------------------------------------------------------------------------
# Roadmaps on the grid: medial axis and Voronoi


@dataclass(frozen=True)
class Roadmap2D:
    """A graph whose nodes are free cells and whose edges are mutually visible cell pairs, on one grid.

    ``node_cells`` ``(M, 2)`` int; the graph in CSR form (``indptr``, ``indices``, ``weights`` in metres, both
    directions stored). A query links the start and the goal to the nearest nodes they can see (trying the 16,
    64, then 256 nearest; a direct start-goal leg counts too) and runs A* (``any_angle.roadmap_astar``).
    """

    name: str
    gmap: GridMap
    node_cells: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    tree: object  # scipy.spatial.cKDTree over node_cells
    extra: dict
    edges_ne: np.ndarray  # (E, 2, 2) edge segments in map metres, for plots

    @classmethod
    def from_edges(cls, name: str, gmap: GridMap, node_cells: np.ndarray, edges: np.ndarray, extra: dict):
        """Build from ``(E, 2)`` node index pairs (each undirected edge once, visible, no self-loops)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        m = len(node_cells)
        lengths = np.linalg.norm(node_cells[edges[:, 0]] - node_cells[edges[:, 1]], axis=1)
        rows = np.concatenate([edges[:, 0], edges[:, 1]])
        cols = np.concatenate([edges[:, 1], edges[:, 0]])
        csr = coo_matrix((np.concatenate([lengths, lengths]), (rows, cols)), shape=(m, m)).tocsr()
        components = int(connected_components(csr, directed=False)[0]) if m else 0
        extra = {**extra, "nodes": int(m), "edges": int(len(edges)), "components": components}
        tree = cKDTree(node_cells.astype(np.float64)) if m else None
        centre = np.array([gmap.north_offset + 0.5, gmap.east_offset + 0.5])
        edges_ne = np.stack([node_cells[edges[:, 0]], node_cells[edges[:, 1]]], axis=1) + centre
        return cls(name, gmap, node_cells, csr.indptr.astype(np.int64), csr.indices.astype(np.int64),
                   csr.data.astype(np.float64), tree, extra, edges_ne.reshape(-1, 2, 2))

    def structure(self) -> dict:
        """Edges ``(E, 2, 2)`` in map metres (north, east), for plots."""
        return {"edges": self.edges_ne}

    def _links(self, cell: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Nodes visible from ``cell`` among its nearest, and the leg lengths; empty if none is visible."""
        m = len(self.node_cells)
        if m == 0:
            return np.empty(0, np.int64), np.empty(0)
        for k in _LINK_CANDIDATES:
            k = min(k, m)
            dist, idx = self.tree.query(np.asarray(cell, dtype=np.float64), k=k)
            idx, dist = np.atleast_1d(idx), np.atleast_1d(dist)
            here = np.broadcast_to(np.asarray(cell, dtype=np.int64), (len(idx), 2))
            ok = any_angle.segments_visible(self.gmap.grid, np.ascontiguousarray(here), self.node_cells[idx])
            if ok.any() or k == m:
                return idx[ok].astype(np.int64), dist[ok]
        return np.empty(0, np.int64), np.empty(0)

    def plan(self, start_ne: Sequence[float], goal_ne: Sequence[float], *, snap_start: bool = False) -> Plan:
        start, goal, lead_in = resolve_endpoints(self.gmap, start_ne, goal_ne, snap_start)
        t0 = time.perf_counter()
        direct = math.hypot(goal[0] - start[0], goal[1] - start[1])
        if not line_of_sight(self.gmap.grid, start, goal):
            direct = math.inf
        start_nodes, start_costs = self._links(start)
        goal_nodes, goal_dist = self._links(goal)
        goal_costs = np.full(len(self.node_cells), np.inf)
        goal_costs[goal_nodes] = goal_dist
        goal_xy = np.asarray(goal, dtype=np.float64)
        nodes, cost, expanded = any_angle.roadmap_astar(
            self.indptr, self.indices, self.weights, self.node_cells.astype(np.float64),
            start_nodes, start_costs, goal_costs, goal_xy, direct,
        )
        search_ms = (time.perf_counter() - t0) * 1e3
        if cost < 0:
            raise NoPathError(start, goal, int(expanded))
        cells = np.vstack([np.asarray([start]), self.node_cells[nodes], np.asarray([goal])])
        extra = {**self.extra, "start_links": len(start_nodes), "goal_links": len(goal_nodes)}
        return plan_from_cells(self.name, self.gmap, cells, cost, search_ms, expanded, lead_in, extra,
                               self.structure())


def _unique_edges(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(E, 2)`` undirected edges from index arrays, each once, no self-loops."""
    pairs = np.column_stack([np.minimum(a, b), np.maximum(a, b)])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return np.unique(pairs, axis=0) if len(pairs) else pairs.reshape(0, 2)


class MedialAxisRoadmap(Roadmap2D):
    """Skeleton of the free space (``skimage.morphology.medial_axis``) as a graph of 8-connected pixels."""

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float) -> MedialAxisRoadmap:
        from skimage.morphology import medial_axis

        gmap = GridMap.build(obstacles, altitude_m, safety_m)
        skeleton = medial_axis(free_mask(gmap.grid))
        return cls.from_skeleton(gmap, skeleton)

    @classmethod
    def from_skeleton(cls, gmap: GridMap, skeleton: np.ndarray) -> MedialAxisRoadmap:
        """Nodes are skeleton pixels; edges join 8-neighbours, a diagonal only where both side cells are free."""
        n, m = skeleton.shape
        index = np.full((n + 2, m + 2), -1, np.int64)
        node_cells = np.argwhere(skeleton)
        index[1:-1, 1:-1][skeleton] = np.arange(len(node_cells))
        free = np.zeros((n + 2, m + 2), bool)
        free[1:-1, 1:-1] = free_mask(gmap.grid)

        def shifted(a, di, dj):  # a[i + di, j + dj] for every cell (i, j), padding outside
            return a[1 + di : n + 1 + di, 1 + dj : m + 1 + dj]

        pieces = []
        for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
            target = shifted(index, di, dj)
            ok = skeleton & (target >= 0)
            if di and dj:  # a diagonal leg's supercover includes both side cells
                ok &= shifted(free, di, 0) & shifted(free, 0, dj)
            pieces.append(np.column_stack([index[1:-1, 1:-1][ok], target[ok]]))
        edges = _unique_edges(*np.concatenate(pieces).T)
        return cls.from_edges("medial-axis", gmap, node_cells, edges, {})


class VoronoiRoadmap(Roadmap2D):
    """Voronoi ridges between the C-space obstacle boundary cells (and a frame around the map), kept where
    both ends are free cells that see each other."""

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float) -> VoronoiRoadmap:
        gmap = GridMap.build(obstacles, altitude_m, safety_m)
        return cls.from_grid(gmap)

    @classmethod
    def from_grid(cls, gmap: GridMap) -> VoronoiRoadmap:
        from scipy import ndimage
        from scipy.spatial import QhullError, Voronoi

        grid = gmap.grid
        n, m = grid.shape
        boundary = grid & ndimage.binary_dilation(free_mask(grid), structure=np.ones((3, 3), bool))
        frame = np.concatenate([
            np.column_stack([np.arange(-1, n + 1, 2), np.full_like(np.arange(-1, n + 1, 2), -1)]),
            np.column_stack([np.arange(-1, n + 1, 2), np.full_like(np.arange(-1, n + 1, 2), m)]),
            np.column_stack([np.full_like(np.arange(-1, m + 1, 2), -1), np.arange(-1, m + 1, 2)]),
            np.column_stack([np.full_like(np.arange(-1, m + 1, 2), n), np.arange(-1, m + 1, 2)]),
        ])
        sites = np.concatenate([np.argwhere(boundary), frame]).astype(np.float64) + 0.5
        try:
            diagram = Voronoi(sites)
        except QhullError:  # too few or degenerate sites: an empty roadmap (queries may still go direct)
            return cls.from_edges("voronoi", gmap, np.empty((0, 2), np.int64), np.empty((0, 2), np.int64), {})
        ridges = np.asarray(diagram.ridge_vertices, dtype=np.int64)
        ridges = ridges[(ridges >= 0).all(axis=1)]
        vertex_cells = np.floor(diagram.vertices).astype(np.int64)
        on_grid = ((vertex_cells >= 0) & (vertex_cells < (n, m))).all(axis=1)
        vertex_ok = on_grid.copy()
        vertex_ok[on_grid] = free_mask(grid)[vertex_cells[on_grid, 0], vertex_cells[on_grid, 1]]
        ridges = ridges[vertex_ok[ridges].all(axis=1)]
        # Merge vertices that fall in one cell, then keep ridges whose ends see each other.
        node_cells, inverse = np.unique(vertex_cells[vertex_ok], axis=0, return_inverse=True)
        node_of_vertex = np.full(len(vertex_cells), -1, np.int64)
        node_of_vertex[vertex_ok] = inverse.ravel()
        edges = _unique_edges(node_of_vertex[ridges[:, 0]], node_of_vertex[ridges[:, 1]])
        visible = any_angle.segments_visible(grid, node_cells[edges[:, 0]], node_cells[edges[:, 1]])
        edges = edges[visible]
        # Drop nodes no edge uses.
        used = np.unique(edges)
        renumber = np.full(len(node_cells), -1, np.int64)
        renumber[used] = np.arange(len(used))
        extra = {"sites": int(len(sites)), "ridges": int(len(ridges))}
        return cls.from_edges("voronoi", gmap, node_cells[used], renumber[edges], extra)
