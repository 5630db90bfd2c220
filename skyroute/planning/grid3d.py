"""Altitude-aware planning on a 2.5D height map: the ``grid3d`` planner and the 3D collision checks.

The map becomes one float array ``floor_m[north_idx, east_idx]`` (same cells and offsets as
``cspace.create_grid``): the lowest altitude at which the cell is free, i.e. the highest
``top + safety_m`` of the obstacles whose grown footprint touches the cell (``-inf`` where none does). So
``floor_m > z`` is exactly ``create_grid(obstacles, z, safety_m)[0]`` for every altitude ``z``, and one array
serves every altitude.

``grid3d`` searches cells ``(north_idx, east_idx, level)`` with ``level`` altitudes ``base + k * dz``
(``dz <= 5`` m, chosen so the start and goal altitudes are both levels, up to the first level above every
obstacle): 8-connected horizontal moves at one level (no diagonal past a blocked side cell), and vertical moves
of one level costing ``climb_weight`` or ``descent_weight`` per metre. The cheapest route may climb over a low
building instead of going around it, and may end on a rooftop (``goal_alt_m`` at least the roof plus the
margin). A leg is accepted when, over every cell of its 2D supercover, it stays at or above the cell's floor
(:func:`leg_free`), so a leg never dips into a grown box; pruning uses the same test, so the flown route may
climb diagonally.

Memory: the search workspace has ``levels * cells`` entries (44 x 921 x 921 on the SF map at 5 m), allocated
per query with ``np.zeros`` / ``np.empty`` so the operating system maps only the pages the search touches.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from skyroute.planning import kernels
from skyroute.planning.cspace import cell_to_map, create_grid, map_to_cell, nearest_free_cell, snap_start_cell
from skyroute.planning.errors import BlockedCellError, NoPathError, OutsideGridError
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import headings_along, path_length

SQRT2 = math.sqrt(2.0)
MAX_LEVEL_STEP_M = 5.0


# --------------------------------------------------------------------------------------------------------------
# Height map


@njit(cache=True)
def _paint_max(floor, n_lo, n_hi, e_lo, e_hi, value):
    for k in range(n_lo.shape[0]):
        for i in range(n_lo[k], n_hi[k]):
            for j in range(e_lo[k], e_hi[k]):
                if value[k] > floor[i, j]:
                    floor[i, j] = value[k]


def floor_map(obstacles: np.ndarray, safety_m: float) -> tuple[np.ndarray, int, int]:
    """Lowest free altitude per cell: ``(floor_m, north_offset, east_offset)``.

    ``floor_m[i, j] > z`` equals ``create_grid(obstacles, z, safety_m)[0][i, j]`` for any altitude ``z``: the
    same footprints grown by ``safety_m`` and rounded outwards to whole cells, each painted with its
    ``top + safety_m``.

    >>> boxes = np.array([[2.0, 2.0, 5.0, 1.0, 1.0, 5.0], [0.5, 0.5, 1.0, 0.5, 0.5, 1.0]])
    >>> floor, north_offset, east_offset = floor_map(boxes, safety_m=0)
    >>> floor.tolist()
    [[2.0, -inf, -inf], [-inf, 10.0, 10.0], [-inf, 10.0, 10.0]]
    """
    obstacles = np.asarray(obstacles, dtype=np.float64)
    _, north_offset, east_offset = create_grid(obstacles, -math.inf, safety_m)  # shape and offsets only
    north, east, alt, d_north, d_east, d_alt = obstacles.T
    north_size = int(np.ceil(np.max(north + d_north))) - north_offset
    east_size = int(np.ceil(np.max(east + d_east))) - east_offset
    s = safety_m
    n_lo = np.clip(np.floor(north - d_north - s - north_offset), 0, north_size).astype(np.int64)
    n_hi = np.clip(np.ceil(north + d_north + s - north_offset), 0, north_size).astype(np.int64)
    e_lo = np.clip(np.floor(east - d_east - s - east_offset), 0, east_size).astype(np.int64)
    e_hi = np.clip(np.ceil(east + d_east + s - east_offset), 0, east_size).astype(np.int64)
    floor = np.full((north_size, east_size), -np.inf)
    _paint_max(floor, n_lo, n_hi, e_lo, e_hi, alt + d_alt + s)
    return floor, north_offset, east_offset


# --------------------------------------------------------------------------------------------------------------
# 3D collision checks


def legs_clear_of_boxes(points: np.ndarray, obstacles: np.ndarray, safety_m: float) -> np.ndarray:
    """For each leg of the polyline ``points`` ``(K, 3)`` ``[north_m, east_m, altitude_m]``: True if the segment
    stays out of the interior of every obstacle box grown by ``safety_m`` on all sides. Returns ``(K - 1,)`` bool.

    Slab test per leg, vectorised over the obstacles.

    >>> box = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 5.0]])           # 2 x 2 m, 10 m tall
    >>> legs_clear_of_boxes(np.array([[-5, 0, 5], [5, 0, 5], [5, 0, 20], [-5, 0, 12]]), box, 1.0).tolist()
    [False, True, True]
    """
    points = np.asarray(points, dtype=np.float64)
    obstacles = np.asarray(obstacles, dtype=np.float64)
    centre = obstacles[:, [0, 1, 2]]
    half = obstacles[:, [3, 4, 5]] + safety_m
    lo, hi = centre - half, centre + half
    clear = np.ones(max(len(points) - 1, 0), dtype=bool)
    for k in range(len(clear)):
        p0, d = points[k], points[k + 1] - points[k]
        enter = np.zeros(len(obstacles))
        leave = np.ones(len(obstacles))
        inside = np.ones(len(obstacles), dtype=bool)
        for axis in range(3):
            if d[axis] == 0.0:
                inside &= (lo[:, axis] < p0[axis]) & (p0[axis] < hi[:, axis])
            else:
                t1 = (lo[:, axis] - p0[axis]) / d[axis]
                t2 = (hi[:, axis] - p0[axis]) / d[axis]
                enter = np.maximum(enter, np.minimum(t1, t2))
                leave = np.minimum(leave, np.maximum(t1, t2))
        clear[k] = not np.any(inside & (enter < leave))
    return clear


@njit(cache=True)
def leg_free(floor, i0, j0, z0, i1, j1, z1):
    """True if the 3D leg from the centre of cell ``(i0, j0)`` at ``z0`` to the centre of ``(i1, j1)`` at ``z1``
    stays on the map and, over every cell of its 2D supercover, at or above that cell's floor.

    The leg's altitude is linear along it, so over one cell its lowest point is at the entry or exit of the
    cell's square (1e-9 m is kept in hand for rounding). A level leg therefore needs its supercover free at its
    altitude, and a climbing leg may pass low cells early and higher cells later.
    """
    n, m = floor.shape
    if not (0 <= i0 < n and 0 <= j0 < m and 0 <= i1 < n and 0 <= j1 < m):
        return False
    ni, nj = abs(i1 - i0), abs(j1 - j0)
    cells = np.empty((ni + nj + 1 + 2 * min(ni, nj), 2), np.int64)
    count = kernels.walk_supercover(np.zeros((1, 1), np.bool_), i0, j0, i1, j1, cells)
    low, high = min(z0, z1), max(z0, z1)
    di, dj, dz = float(i1 - i0), float(j1 - j0), z1 - z0
    for k in range(count):
        ci, cj = cells[k, 0], cells[k, 1]
        f = floor[ci, cj]
        if f <= low:
            continue
        if f > high:
            return False
        t_lo, t_hi = 0.0, 1.0  # the part of the leg over the closed square of cell (ci, cj)
        if di != 0.0:
            ta, tb = (ci - i0 - 0.5) / di, (ci - i0 + 0.5) / di
            t_lo, t_hi = max(t_lo, min(ta, tb)), min(t_hi, max(ta, tb))
        if dj != 0.0:
            ta, tb = (cj - j0 - 0.5) / dj, (cj - j0 + 0.5) / dj
            t_lo, t_hi = max(t_lo, min(ta, tb)), min(t_hi, max(ta, tb))
        lowest = z0 + dz * (t_hi if dz < 0 else t_lo) - 1e-9
        if f > lowest:
            return False
    return True


@njit(cache=True)
def legs_free(floor, a, b):
    """Batch :func:`leg_free` over rows ``[north_idx, east_idx, altitude_m]`` of ``a`` and ``b`` ``(E, 3)``."""
    out = np.empty(a.shape[0], np.bool_)
    for k in range(a.shape[0]):
        out[k] = leg_free(floor, int(a[k, 0]), int(a[k, 1]), a[k, 2], int(b[k, 0]), int(b[k, 1]), b[k, 2])
    return out


@njit(cache=True)
def prune_mask_3d(floor, path):
    """Greedy string pulling over rows ``[north_idx, east_idx, altitude_m]``: keep a point only where the leg from
    the last kept point would fail :func:`leg_free` (the path's own legs must pass it)."""
    keep = np.zeros(path.shape[0], np.bool_)
    keep[0] = True
    keep[-1] = True
    anchor = 0
    for k in range(2, path.shape[0]):
        a, b = path[anchor], path[k]
        if not leg_free(floor, int(a[0]), int(a[1]), a[2], int(b[0]), int(b[1]), b[2]):
            anchor = k - 1
            keep[anchor] = True
    return keep


# --------------------------------------------------------------------------------------------------------------
# Search


@njit(cache=True)
def _h(i, j, k, gi, gj, gk, levels, climb_weight, descent_weight):
    di, dj = abs(i - gi), abs(j - gj)
    dz = levels[gk] - levels[k]
    vertical = dz * climb_weight if dz > 0 else -dz * descent_weight
    return (SQRT2 - 1.0) * min(di, dj) + max(di, dj) + vertical


@njit(cache=True)
def astar3d(floor, levels, start, goal, climb_weight, descent_weight, state, g_cost, move):
    """A* over ``(level, north_idx, east_idx)`` cells; ``start``/``goal`` are ``(i, j, k)`` int arrays.

    ``state`` (zeros), ``g_cost`` and ``move`` are flat workspaces of ``levels.size * floor.size`` entries (the
    caller allocates them lazily, so untouched pages cost nothing). Returns ``(cells (K, 3), cost, expanded)``,
    ``cost`` -1 if unreachable.
    """
    n, m = floor.shape
    di = np.array([1, -1, 0, 0, 1, 1, -1, -1, 0, 0])
    dj = np.array([0, 0, 1, -1, 1, -1, 1, -1, 0, 0])
    dk = np.array([0, 0, 0, 0, 0, 0, 0, 0, 1, -1])
    plane = n * m
    si, sj, sk = start[0], start[1], start[2]
    gi, gj, gk = goal[0], goal[1], goal[2]
    s = sk * plane + si * m + sj
    t = gk * plane + gi * m + gj
    hf, hg, hv = kernels.new_heap()
    state[s], g_cost[s], move[s] = 1, 0.0, -1
    hf, hg, hv, size = kernels.heap_push(
        hf, hg, hv, 0, _h(si, sj, sk, gi, gj, gk, levels, climb_weight, descent_weight), 0.0, s
    )
    expanded = 0
    found = False
    while size > 0:
        v, fv, gv, size = kernels.heap_pop(hf, hg, hv, size)
        if state[v] == 2 or gv > g_cost[v]:
            continue
        state[v] = 2
        expanded += 1
        if v == t:
            found = True
            break
        k, rest = v // plane, v % plane
        i, j = rest // m, rest % m
        z = levels[k]
        for d in range(10):
            wi, wj, wk = i + di[d], j + dj[d], k + dk[d]
            if not (0 <= wi < n and 0 <= wj < m and 0 <= wk < levels.shape[0]):
                continue
            zw = levels[wk]
            if floor[wi, wj] > zw:
                continue
            if d < 4:
                step = 1.0
            elif d < 8:
                if floor[wi, j] > z or floor[i, wj] > z:
                    continue
                step = SQRT2
            elif d == 8:
                step = (zw - z) * climb_weight
            else:
                step = (z - zw) * descent_weight
            w = wk * plane + wi * m + wj
            if state[w] == 2:
                continue
            gw = gv + step
            if state[w] == 1 and gw >= g_cost[w]:
                continue
            state[w], g_cost[w], move[w] = 1, gw, d
            f = gw + _h(wi, wj, wk, gi, gj, gk, levels, climb_weight, descent_weight)
            hf, hg, hv, size = kernels.heap_push(hf, hg, hv, size, f, gw, w)
    if not found:
        return np.empty((0, 3), np.int64), -1.0, expanded
    count = 1
    v = t
    while v != s:
        d = move[v]
        v -= dk[d] * plane + di[d] * m + dj[d]
        count += 1
    cells = np.empty((count, 3), np.int64)
    v = t
    for c in range(count - 1, -1, -1):
        k, rest = v // plane, v % plane
        cells[c, 0], cells[c, 1], cells[c, 2] = rest // m, rest % m, k
        if c > 0:
            d = move[v]
            v -= dk[d] * plane + di[d] * m + dj[d]
    return cells, g_cost[t], expanded


def _check_cell(floor: np.ndarray, which: str, cell: tuple[int, int], altitude_m: float) -> tuple[int, int]:
    n, m = floor.shape
    if not (0 <= cell[0] < n and 0 <= cell[1] < m):
        raise OutsideGridError(which, cell, (n, m))
    if floor[cell] > altitude_m:
        raise BlockedCellError(which, cell, nearest_free_cell(floor > altitude_m, cell))
    return cell


def resolve_endpoints_3d(
    floor: np.ndarray,
    north_offset: int,
    east_offset: int,
    obstacles: np.ndarray,
    start_ne: Sequence[float],
    goal_ne: Sequence[float],
    altitude_m: float,
    goal_alt_m: float,
    snap_start: bool,
) -> tuple[tuple[int, int], tuple[int, int], np.ndarray | None]:
    """Start cell (free at ``altitude_m``), goal cell (free at ``goal_alt_m``) and a snapped start's lead-in point.

    Raises ``OutsideGridError`` or ``BlockedCellError`` like ``GridMap.plan``.
    """
    start_cell = map_to_cell(start_ne[0], start_ne[1], north_offset, east_offset)
    goal_cell = map_to_cell(goal_ne[0], goal_ne[1], north_offset, east_offset)
    lead_in = None
    n, m = floor.shape
    if snap_start and 0 <= start_cell[0] < n and 0 <= start_cell[1] < m and floor[start_cell] > altitude_m:
        footprint = create_grid(obstacles, altitude_m, 0.0)[0]  # same extent and offsets as ``floor``
        snapped = snap_start_cell(floor > altitude_m, footprint, start_cell)
        if snapped is not None:
            lead_in = np.array(cell_to_map(start_cell, north_offset, east_offset))
            start_cell = snapped
    start_cell = _check_cell(floor, "start", start_cell, altitude_m)
    return start_cell, _check_cell(floor, "goal", goal_cell, goal_alt_m), lead_in


def headings_3d(points: np.ndarray) -> np.ndarray:
    """Headings along ``(K, >=2)`` points (north, east first); a vertical leg keeps the previous heading."""
    points = np.asarray(points, dtype=np.float64)
    headings = headings_along(points[:, :2])
    if len(points) < 2:
        return headings
    horizontal = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1) > 0
    for k in range(1, len(points)):
        if not horizontal[k - 1]:
            headings[k] = headings[k - 1]
    if not horizontal[0]:  # climbing first: face along the first horizontal leg
        moving = np.flatnonzero(horizontal)
        headings[0] = headings[moving[0] + 1] if len(moving) else 0.0
        for k in range(1, (moving[0] + 1) if len(moving) else len(points)):
            headings[k] = headings[0]
    return headings


@dataclass(frozen=True)
class Grid3DPlanner:
    """``grid3d`` on one map and margin; the flight altitude ``altitude_m`` is the start's (and default goal's).

    ``climb_weight`` / ``descent_weight`` multiply vertical metres in the cost (horizontal metres cost 1).
    """

    obstacles: np.ndarray
    floor: np.ndarray
    north_offset: int
    east_offset: int
    altitude_m: float
    safety_m: float
    climb_weight: float = 1.5
    descent_weight: float = 1.0

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float, **weights) -> Grid3DPlanner:
        floor, north_offset, east_offset = floor_map(obstacles, safety_m)
        return cls(np.asarray(obstacles, dtype=np.float64), floor, north_offset, east_offset, float(altitude_m),
                   float(safety_m), **weights)

    def levels_for(self, goal_alt_m: float) -> np.ndarray:
        """Level altitudes: from the lower of start and goal up past the highest floor, both ends on a level."""
        low, high = sorted((self.altitude_m, goal_alt_m))
        steps = math.ceil((high - low) / MAX_LEVEL_STEP_M)
        dz = (high - low) / steps if steps else MAX_LEVEL_STEP_M
        finite = self.floor[np.isfinite(self.floor)]
        top = max(high, float(finite.max()) if finite.size else high)
        count = int(math.ceil((top - low) / dz - 1e-9)) + 1
        return low + dz * np.arange(count)

    def plan(
        self,
        start_ne: Sequence[float],
        goal_ne: Sequence[float],
        *,
        goal_alt_m: float | None = None,
        snap_start: bool = False,
    ) -> Plan:
        """Cheapest route from ``start_ne`` at ``altitude_m`` to ``goal_ne`` at ``goal_alt_m`` (default the same).

        Raises ``OutsideGridError``, ``BlockedCellError`` (start or goal cell not free at its altitude) or
        ``NoPathError``.
        """
        goal_alt = self.altitude_m if goal_alt_m is None else float(goal_alt_m)
        start_cell, goal_cell, lead_in = resolve_endpoints_3d(
            self.floor, self.north_offset, self.east_offset, self.obstacles, start_ne, goal_ne, self.altitude_m,
            goal_alt, snap_start,
        )
        levels = self.levels_for(goal_alt)
        start_level = int(np.argmin(np.abs(levels - self.altitude_m)))
        goal_level = int(np.argmin(np.abs(levels - goal_alt)))
        t0 = time.perf_counter()
        voxels = len(levels) * self.floor.size
        state = np.zeros(voxels, np.uint8)  # calloc: pages appear only where the search goes
        g_cost = np.empty(voxels, np.float64)
        move = np.empty(voxels, np.int8)
        cells, cost, expanded = astar3d(
            self.floor, levels, np.array([*start_cell, start_level]), np.array([*goal_cell, goal_level]),
            self.climb_weight, self.descent_weight, state, g_cost, move,
        )
        search_ms = (time.perf_counter() - t0) * 1e3
        if cost < 0:
            raise NoPathError(start_cell, goal_cell, int(expanded))
        path = np.column_stack([cells[:, :2].astype(np.float64), levels[cells[:, 2]]])
        pruned = path[prune_mask_3d(self.floor, path)]
        points = np.column_stack([pruned[:, 0] + self.north_offset + 0.5, pruned[:, 1] + self.east_offset + 0.5,
                                  pruned[:, 2]])
        raw = path[:, :2] + (self.north_offset + 0.5, self.east_offset + 0.5)
        if lead_in is not None:
            points = np.vstack([[lead_in[0], lead_in[1], self.altitude_m], points])
            raw = np.vstack([lead_in, raw])
        waypoints = np.column_stack([points, headings_3d(points)])
        return Plan(
            planner="grid3d",
            waypoints=waypoints,
            raw_path_ne=raw,
            length_m=path_length(points),
            cost_m=float(cost),
            search_ms=search_ms,
            expanded=int(expanded),
            extra={
                "levels": int(len(levels)),
                "level_step_m": round(float(levels[1] - levels[0]), 3) if len(levels) > 1 else 0.0,
                "climb_weight": self.climb_weight,
                "descent_weight": self.descent_weight,
                "max_altitude_m": float(points[:, 2].max()),
            },
            structure={},
        )
