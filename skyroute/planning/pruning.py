"""Line of sight on the grid (supercover) and path pruning; cells -> waypoints.

Waypoints: ``[north_m, east_m, altitude_m, heading_rad]`` of cell centres; heading is the direction of the leg
that arrives at the waypoint (radians from north towards east).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from skyroute.planning import kernels


def supercover(p0: Sequence[int], p1: Sequence[int]) -> np.ndarray:
    """Every cell touched by the segment between the centres of cells ``p0`` and ``p1``, as ``(K, 2)`` ints.

    >>> supercover((0, 0), (2, 2)).tolist()      # through two vertices: the side cells count
    [[0, 0], [1, 0], [0, 1], [1, 1], [2, 1], [1, 2], [2, 2]]
    >>> supercover((0, 0), (1, 2)).tolist()
    [[0, 0], [0, 1], [1, 1], [1, 2]]
    """
    i0, j0, i1, j1 = int(p0[0]), int(p0[1]), int(p1[0]), int(p1[1])
    out = np.empty((abs(i1 - i0) + abs(j1 - j0) + 1 + 2 * min(abs(i1 - i0), abs(j1 - j0)), 2), np.int64)
    count = kernels.walk_supercover(np.zeros((1, 1), np.bool_), i0, j0, i1, j1, out)
    return out[:count]


def line_of_sight(grid: np.ndarray, p0: Sequence[int], p1: Sequence[int]) -> bool:
    """True if every cell the segment between cell centres ``p0`` and ``p1`` touches is free (and on the grid)."""
    n, m = grid.shape
    for p in (p0, p1):
        if not (0 <= p[0] < n and 0 <= p[1] < m):
            return False
    no_output = np.empty((0, 2), np.int64)
    return kernels.walk_supercover(grid, int(p0[0]), int(p0[1]), int(p1[0]), int(p1[1]), no_output) == 0


def prune_line_of_sight(grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Greedy string pulling: keep a cell only where the straight leg from the last kept cell would touch a
    blocked cell (supercover check), so every returned leg is collision-free on ``grid``.

    ``cells`` is a ``(K, 2)`` path of adjacent, free cells; returns a ``(M, 2)`` subset, first and last kept.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    if len(cells) <= 2:
        return cells.copy()
    return cells[kernels.prune_los_mask(np.asarray(grid, dtype=np.bool_), cells)]


def prune_collinear(points: np.ndarray, tolerance_m: float = 1e-6) -> np.ndarray:
    """Drop points that lie within ``tolerance_m`` metres of the straight line through their kept neighbours.

    Every dropped point is within the tolerance of the leg that replaces it (checked against all points the leg
    spans, so errors do not accumulate). Works on ``(K, D)`` arrays of cells or metres.

    >>> prune_collinear(np.array([[0, 0], [1, 1], [2, 2], [2, 3], [2, 4]])).tolist()
    [[0, 0], [2, 2], [2, 4]]
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) <= 2:
        return np.asarray(points).copy()
    keep = [0]
    anchor = 0
    for k in range(2, len(pts)):
        if _max_offset(pts[anchor], pts[k], pts[anchor + 1 : k]) > tolerance_m:
            anchor = k - 1
            keep.append(anchor)
    keep.append(len(pts) - 1)
    return np.asarray(points)[keep]


def _max_offset(a: np.ndarray, b: np.ndarray, pts: np.ndarray) -> float:
    """Largest distance in metres from ``pts`` to the segment ``a``-``b``."""
    ab = b - a
    denom = float(ab @ ab)
    t = np.zeros(len(pts)) if denom == 0 else np.clip((pts - a) @ ab / denom, 0.0, 1.0)
    return float(np.max(np.linalg.norm(pts - (a + t[:, None] * ab), axis=1)))


def prune_path(grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The two pruning steps: line-of-sight string pulling (:func:`prune_line_of_sight`), then the cells it kept
    that lie exactly on the line between their neighbours (:func:`prune_collinear` with a 1e-9 m tolerance:
    the greedy pass can keep one when a wall blocks a longer leg). ``(K, 2)`` cells -> ``(M, 2)`` cells.

    Dropping an exactly collinear cell is safe: the merged leg is the union of the two legs it replaces, so it
    touches the same cells.

    >>> grid = np.zeros((4, 9), dtype=bool)
    >>> prune_path(grid, np.array([[0, k] for k in range(9)])).tolist()
    [[0, 0], [0, 8]]
    """
    return prune_collinear(prune_line_of_sight(grid, cells), tolerance_m=1e-9)


def path_length(points: np.ndarray) -> float:
    """Total length of a polyline ``(K, D)`` in its own units (metres for map points)."""
    pts = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) if len(pts) > 1 else 0.0


def waypoints_from_cells(
    cells: np.ndarray, north_offset: float, east_offset: float, altitude_m: float
) -> np.ndarray:
    """Turn grid cells into waypoints ``[north_m, east_m, altitude_m, heading_rad]`` (map frame, cell centres).

    The heading of each waypoint points along the leg that arrives at it; the first waypoint takes the heading
    of the first leg (0 when there is only one waypoint).

    >>> waypoints_from_cells(np.array([[0, 0], [0, 10]]), 0, 0, 5).round(3).tolist()
    [[0.5, 0.5, 5.0, 1.571], [0.5, 10.5, 5.0, 1.571]]
    """
    cells = np.asarray(cells, dtype=np.float64).reshape(-1, 2)
    waypoints = np.empty((len(cells), 4))
    waypoints[:, 0] = cells[:, 0] + north_offset + 0.5
    waypoints[:, 1] = cells[:, 1] + east_offset + 0.5
    waypoints[:, 2] = altitude_m
    waypoints[:, 3] = headings_along(waypoints[:, :2])
    return waypoints


def headings_along(points_ne: np.ndarray) -> np.ndarray:
    """Heading in radians (from north towards east) of the leg arriving at each point; point 0 copies leg 1."""
    points_ne = np.asarray(points_ne, dtype=np.float64)
    if len(points_ne) < 2:
        return np.zeros(len(points_ne))
    legs = np.diff(points_ne, axis=0)
    headings = np.arctan2(legs[:, 1], legs[:, 0])
    return np.concatenate(([headings[0]], headings))
