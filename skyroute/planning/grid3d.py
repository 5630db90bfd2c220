"""Altitude-aware planning on a 2.5D height map: the ``grid3d`` planner and the 3D collision checks.

The map becomes one float array ``floor_m[north_idx, east_idx]`` (same cells and offsets as
``cspace.create_grid``): the lowest altitude at which the cell is free, i.e. the highest ``top + safety_m`` of the
obstacles whose footprint, grown by ``safety_m`` with rounded corners, covers the cell (``-inf`` where none does).
So ``floor_m > z`` is exactly ``create_grid(obstacles, z, safety_m)[0]`` for every altitude ``z``, and one array
serves every altitude. Vertically the margin is a flat lid ``safety_m`` above the roof over the whole grown
footprint, a superset of the 3D ball around the box (conservative over roof edges); boxes count from the ground up.

``grid3d`` finds the cheapest route over cells ``(north_idx, east_idx, level)`` with ``level`` altitudes
``base + k * dz`` (``dz <= 5`` m, chosen so the start and goal altitudes are both levels, up to the first level
above every obstacle): 8-connected horizontal moves at one level (no diagonal past a blocked side cell), and
vertical moves of one level costing ``climb_weight`` or ``descent_weight`` per metre. The cheapest route may climb
over a low building instead of going around it, and may end on a rooftop (``goal_alt_m`` at least the roof plus
the margin).

It does not search the voxels. Free space only grows with altitude (``floor_m <= z`` stays true above ``z``), so a
route whose highest level is ``L`` can climb to ``L`` over the start, fly all its horizontal moves at ``L`` and
descend over the goal without costing more: its horizontal moves are all free at ``L``, and it must climb and
descend at least that much anyway. The optimum is therefore

    min over L >= max(start level, goal level) of D_L + climb_weight (z_L - z_start) + descent_weight (z_L - z_goal)

with ``D_L`` the 2D optimum at level ``L`` (jump point search on ``floor_m > z_L``). Levels are tried upwards,
each search bounded by the best total so far, until the vertical cost plus the straight-line (octile) distance
alone reaches it. A leg is accepted when, over every cell of its 2D supercover, it stays at or above the cell's
floor (:func:`leg_free`), so a leg never dips into a grown box; the route is string-pulled with the same test, so
the flown route may climb diagonally.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyroute.planning import kernels
from skyroute.planning.cspace import (
    cell_to_map,
    create_grid,
    grid_extent,
    map_to_cell,
    nearest_free_cell,
    snap_start_cell,
)
from skyroute.planning.errors import BlockedCellError, NoPathError, OutsideGridError
from skyroute.planning.kernels import njit
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import headings_along, path_length

MAX_LEVEL_STEP_M = 5.0


# --------------------------------------------------------------------------------------------------------------
# Height map


def floor_map(obstacles: np.ndarray, safety_m: float) -> tuple[np.ndarray, int, int]:
    """Lowest free altitude per cell: ``(floor_m, north_offset, east_offset)``.

    ``floor_m[i, j] > z`` equals ``create_grid(obstacles, z, safety_m)[0][i, j]`` for any altitude ``z``: the
    same footprints grown by ``safety_m`` with rounded corners, each painted with its ``top + safety_m``
    (``kernels.raster.rasterise_max``).

    >>> boxes = np.array([[2.0, 2.0, 5.0, 1.0, 1.0, 5.0], [0.5, 0.5, 1.0, 0.5, 0.5, 1.0]])
    >>> floor, north_offset, east_offset = floor_map(boxes, safety_m=0)
    >>> floor.tolist()
    [[2.0, -inf, -inf], [-inf, 10.0, 10.0], [-inf, 10.0, 10.0]]
    """
    obstacles = np.asarray(obstacles, dtype=np.float64)
    north_offset, east_offset, n, m = grid_extent(obstacles)
    if not (math.isfinite(safety_m) and safety_m >= 0):
        raise ValueError(f"safety_m must be finite and >= 0, got {safety_m}")
    north, east, alt, d_north, d_east, d_alt = obstacles.T
    floor = kernels.rasterise_max(north - d_north, north + d_north, east - d_east, east + d_east,
                                  alt + d_alt + safety_m, float(north_offset), float(east_offset),
                                  float(safety_m), n, m)
    return floor, north_offset, east_offset


# --------------------------------------------------------------------------------------------------------------
# 3D collision checks


def legs_clear_of_boxes(points: np.ndarray, obstacles: np.ndarray, safety_m: float) -> np.ndarray:
    """For each leg of the polyline ``points`` ``(K, 3)`` ``[north_m, east_m, altitude_m]``: True if the segment
    stays out of every obstacle's grown prism (the 3D planners' collision rule). Returns ``(K - 1,)`` bool.

    A box's grown prism is the set of points below ``top + safety_m`` whose horizontal distance to the box's
    footprint is below ``safety_m`` (with no margin: inside the footprint and below the top), the same space
    :func:`floor_map` blocks; touching it is allowed. Exact: the part of the leg below the lid is a 2D segment,
    and its distance to the footprint rectangle is checked directly. Vectorised over the obstacles.

    >>> box = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 5.0]])           # 2 x 2 m, 10 m tall
    >>> legs_clear_of_boxes(np.array([[-5, 0, 5], [5, 0, 5], [5, 0, 20], [-5, 0, 12]]), box, 1.0).tolist()
    [False, True, True]
    """
    points = np.asarray(points, dtype=np.float64)
    obstacles = np.asarray(obstacles, dtype=np.float64)
    lo = obstacles[:, :2] - obstacles[:, 3:5]
    hi = obstacles[:, :2] + obstacles[:, 3:5]
    lid = obstacles[:, 2] + obstacles[:, 5] + safety_m
    clear = np.ones(max(len(points) - 1, 0), dtype=bool)
    for k in range(len(clear)):
        p0, p1 = points[k], points[k + 1]
        dz = p1[2] - p0[2]
        # The part of the leg below each lid: t in [t0, t1] of p0 + t (p1 - p0).
        if dz == 0.0:
            t0 = np.where(p0[2] < lid, 0.0, np.inf)
            t1 = np.ones(len(obstacles))
        elif dz > 0.0:
            t0, t1 = np.zeros(len(obstacles)), np.minimum((lid - p0[2]) / dz, 1.0)
        else:
            t0, t1 = np.maximum((lid - p0[2]) / dz, 0.0), np.ones(len(obstacles))
        below = t0 < t1
        if not below.any():
            continue
        d = p1[:2] - p0[:2]
        a = p0[:2] + t0[below, None] * d
        b = p0[:2] + t1[below, None] * d
        if safety_m > 0:
            inside = segment_rectangle_distance(a, b, lo[below], hi[below]) < safety_m
        else:
            inside = _segment_enters_open_rectangle(a, b, lo[below], hi[below])
        clear[k] = not inside.any()
    return clear


def segment_rectangle_distance(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Euclidean distance between 2D segments ``a``-``b`` and closed rectangles ``[lo, hi]``, row by row ``(M,)``.

    Zero if a segment meets its rectangle; otherwise the nearest pair is an endpoint against the rectangle or a
    rectangle corner against the segment.
    """
    def point_to_rectangle(p):
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return np.hypot(gap[:, 0], gap[:, 1])

    d = b - a
    length2 = (d * d).sum(axis=1)
    best = np.minimum(point_to_rectangle(a), point_to_rectangle(b))
    for corner in (lo, hi, np.column_stack([lo[:, 0], hi[:, 1]]), np.column_stack([hi[:, 0], lo[:, 1]])):
        t = np.clip(np.where(length2 > 0, ((corner - a) * d).sum(axis=1) / np.where(length2 > 0, length2, 1), 0), 0, 1)
        nearest = a + t[:, None] * d
        best = np.minimum(best, np.hypot(*(corner - nearest).T))
    return np.where(_segment_meets_rectangle(a, b, lo, hi), 0.0, best)


def _clip_interval(a: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Liang-Barsky: the ``[enter, leave]`` part of ``t in [0, 1]`` where ``a + t d`` is inside ``[lo, hi]``,
    and a mask of the rows whose segment runs along an axis outside the slab (never inside)."""
    enter, leave = np.zeros(len(a)), np.ones(len(a))
    outside = np.zeros(len(a), dtype=bool)
    for axis in range(2):
        still = d[:, axis] == 0.0
        outside |= still & ((a[:, axis] < lo[:, axis]) | (a[:, axis] > hi[:, axis]))
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo[:, axis] - a[:, axis]) / d[:, axis]
            t2 = (hi[:, axis] - a[:, axis]) / d[:, axis]
        enter = np.where(still, enter, np.maximum(enter, np.minimum(t1, t2)))
        leave = np.where(still, leave, np.minimum(leave, np.maximum(t1, t2)))
    return enter, leave, outside


def _segment_meets_rectangle(a, b, lo, hi) -> np.ndarray:
    enter, leave, outside = _clip_interval(a, b - a, lo, hi)
    return ~outside & (enter <= leave)


def _segment_enters_open_rectangle(a, b, lo, hi) -> np.ndarray:
    d = b - a
    enter, leave, _ = _clip_interval(a, d, lo, hi)
    strictly = np.ones(len(a), dtype=bool)
    for axis in range(2):
        still = d[:, axis] == 0.0
        strictly &= ~still | ((lo[:, axis] < a[:, axis]) & (a[:, axis] < hi[:, axis]))
    return strictly & (enter < leave)


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
# Endpoints and headings


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


# --------------------------------------------------------------------------------------------------------------
# The planner


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
    _levels: dict = field(default_factory=dict, repr=False, compare=False)  # altitude -> the level's search grid

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
        top = max(high, self._highest_floor)
        count = int(math.ceil((top - low) / dz - 1e-9)) + 1
        return low + dz * np.arange(count)

    @property
    def _highest_floor(self) -> float:
        finite = self.floor[np.isfinite(self.floor)]
        return float(finite.max()) if finite.size else -math.inf

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
        best, expanded, tried = self._best_level(levels, start_level, goal_level, start_cell, goal_cell)
        search_ms = (time.perf_counter() - t0) * 1e3
        if best is None:
            raise NoPathError(start_cell, goal_cell, expanded)
        cost, level, cells = best
        path = self._route(cells, levels[start_level], levels[level], levels[goal_level])
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
                "levels_searched": tried,
                "cruise_altitude_m": float(levels[level]),
                "climb_weight": self.climb_weight,
                "descent_weight": self.descent_weight,
                "max_altitude_m": float(points[:, 2].max()),
            },
            structure={"floor": (self.floor, self.north_offset, self.east_offset)},  # for plots
        )

    def _best_level(self, levels, start_level, goal_level, start_cell, goal_cell):
        """``((cost, level, flat 2D path), expanded, levels searched)`` for the cheapest cruise level, or
        ``(None, expanded, searched)`` if no level connects the two cells."""
        width = self.floor.shape[1] + 2
        start = (start_cell[0] + 1) * width + start_cell[1] + 1
        goal = (goal_cell[0] + 1) * width + goal_cell[1] + 1
        straight = kernels.octile(start_cell[0], start_cell[1], goal_cell[0], goal_cell[1])
        z_start, z_goal = levels[start_level], levels[goal_level]
        best, expanded, tried = None, 0, 0
        for level in range(max(start_level, goal_level), len(levels)):
            z = levels[level]
            vertical = self.climb_weight * (z - z_start) + self.descent_weight * (z - z_goal)
            bound = math.inf if best is None else best[0] - vertical
            if straight >= bound:
                break  # even a straight flight at this level (or higher) costs more than the best so far
            flat, cost, count, _ = kernels.jps(*self._level_grid(float(z)), width, start, goal, bound)
            expanded += count
            tried += 1
            if cost >= 0:
                best = (cost + vertical, level, np.column_stack((flat // width - 1, flat % width - 1)))
        return best, expanded, tried

    def _level_grid(self, z: float) -> tuple:
        """The scan tables of the cells blocked at altitude ``z``, as ``kernels.jps`` takes them; built once per
        altitude (a query at the planner's own altitude reuses the same levels)."""
        if z not in self._levels:
            blocked = self.floor > z
            self._levels[z] = (kernels.scan_tables(kernels.pack_rows(blocked)),
                               kernels.scan_tables(kernels.pack_columns(blocked)))
        return self._levels[z]

    @staticmethod
    def _route(cells: np.ndarray, z_start: float, z_cruise: float, z_goal: float) -> np.ndarray:
        """Rows ``[north_idx, east_idx, altitude_m]``: climb over the start, fly ``cells`` at the cruise level,
        descend over the goal."""
        path = np.column_stack([cells.astype(np.float64), np.full(len(cells), z_cruise)])
        if z_start != z_cruise:
            path = np.vstack([[cells[0, 0], cells[0, 1], z_start], path])
        if z_goal != z_cruise:
            path = np.vstack([path, [cells[-1, 0], cells[-1, 1], z_goal]])
        return path
