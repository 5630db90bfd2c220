"""Configuration space: obstacles -> occupancy grid for one altitude and margin, and cells <-> map points.

Grid: a ``bool`` array, ``True`` = blocked, indexed ``grid[north_idx, east_idx]``. Row 0 is the *southern* edge;
the north index increases northwards. Cell ``(i, j)`` is the 1 m square ``north in [north_offset + i,
north_offset + i + 1)``, ``east in [east_offset + j, east_offset + j + 1)``. Plot it with ``origin="lower"`` to
get north up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from skyroute.planning.pruning import line_of_sight


def create_grid(data: np.ndarray, drone_altitude: float, safety_distance: float) -> tuple[np.ndarray, int, int]:
    """Rasterise obstacles into a 1 m occupancy grid for flight at one altitude.

    A cell is blocked when its 1 m square comes closer than ``safety_distance`` (in north or east, i.e. the
    obstacle footprint grown by the margin into a bigger rectangle, which is conservative) to any obstacle whose
    top plus ``safety_distance`` exceeds ``drone_altitude``. Every free cell therefore keeps at least the safety
    distance from every such obstacle over its whole square. Vectorised: one scatter and two cumulative sums, no
    per-obstacle Python loop.

    Parameters
    ----------
    data : (N, 6) array
        Obstacle rows ``north, east, alt, half_north, half_east, half_alt`` in metres.
    drone_altitude : float
        Flight altitude in metres above the map's ground.
    safety_distance : float
        Margin in metres, >= 0.

    Returns
    -------
    grid : (n_north, n_east) bool array
        ``True`` = blocked, ``grid[north_idx, east_idx]`` with the north index increasing northwards.
    north_offset, east_offset : int
        Map coordinates in metres of the south-west corner of cell ``(0, 0)`` (the classic exercise's values).

    Examples
    --------
    >>> box = np.array([[5.0, 5.0, 10.0, 1.0, 1.0, 10.0], [0.5, 0.5, 1.0, 0.5, 0.5, 1.0]])
    >>> grid, north_offset, east_offset = create_grid(box, drone_altitude=5, safety_distance=0)
    >>> grid.shape, north_offset, east_offset
    ((6, 6), 0, 0)
    >>> np.argwhere(grid).tolist()   # only the tall box: rows 4-5 are its north extent 4..6 m
    [[4, 4], [4, 5], [5, 4], [5, 5]]
    """
    data = np.asarray(data, dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != 6 or len(data) == 0:
        raise ValueError(f"obstacle data must be a non-empty (N, 6) array, got shape {data.shape}")
    # NaN compares False with everything: unchecked, it would make every obstacle "low" and the grid all free.
    if math.isnan(drone_altitude) or not (math.isfinite(safety_distance) and safety_distance >= 0):
        raise ValueError(
            f"drone_altitude must not be NaN and safety_distance must be finite and >= 0, got {drone_altitude}, "
            f"{safety_distance}"
        )
    if not np.isfinite(data).all():
        raise ValueError("obstacle data contains NaN or infinite values")
    north, east, alt, d_north, d_east, d_alt = data.T
    north_offset = int(np.floor(np.min(north - d_north)))
    east_offset = int(np.floor(np.min(east - d_east)))
    north_size = int(np.ceil(np.max(north + d_north))) - north_offset
    east_size = int(np.ceil(np.max(east + d_east))) - east_offset

    tall = alt + d_alt + safety_distance > drone_altitude
    # Cell i intersects the open interval (a, b) iff floor(a) <= i < ceil(b) (a, b relative to the offset).
    n_lo = np.clip(np.floor(north[tall] - d_north[tall] - safety_distance - north_offset), 0, north_size)
    n_hi = np.clip(np.ceil(north[tall] + d_north[tall] + safety_distance - north_offset), 0, north_size)
    e_lo = np.clip(np.floor(east[tall] - d_east[tall] - safety_distance - east_offset), 0, east_size)
    e_hi = np.clip(np.ceil(east[tall] + d_east[tall] + safety_distance - east_offset), 0, east_size)
    n_lo, n_hi, e_lo, e_hi = (a.astype(np.int64) for a in (n_lo, n_hi, e_lo, e_hi))

    # 2D difference array: +1 at each rectangle's low corner, -1 past its edges, +1 past the far corner.
    width = east_size + 1
    corners = np.concatenate([n_lo * width + e_lo, n_hi * width + e_hi, n_lo * width + e_hi, n_hi * width + e_lo])
    signs = np.repeat(np.array([1, 1, -1, -1], dtype=np.int32), len(n_lo))
    diff = np.bincount(corners, weights=signs, minlength=(north_size + 1) * width).astype(np.int32)
    counts = diff.reshape(north_size + 1, width).cumsum(axis=0).cumsum(axis=1)
    return counts[:north_size, :east_size] > 0, north_offset, east_offset


def map_to_cell(north_m: float, east_m: float, north_offset: int, east_offset: int) -> tuple[int, int]:
    """Grid cell ``(north_idx, east_idx)`` containing the map point ``(north_m, east_m)``."""
    return int(math.floor(north_m - north_offset)), int(math.floor(east_m - east_offset))


def cell_to_map(cell: Sequence[int], north_offset: int, east_offset: int) -> tuple[float, float]:
    """Map coordinates ``(north_m, east_m)`` of the centre of grid cell ``(north_idx, east_idx)``."""
    return north_offset + cell[0] + 0.5, east_offset + cell[1] + 0.5


def nearest_free_cell(grid: np.ndarray, cell: Sequence[int]) -> tuple[int, int] | None:
    """The free cell nearest (Euclidean) to ``cell``, which may lie off the grid; ``None`` if none is free.

    Searches square windows of doubling size, so the cost grows with the distance to free space, not with the
    grid.
    """
    i, j = int(cell[0]), int(cell[1])
    n, m = grid.shape
    half = 4
    while True:
        i0, i1 = max(i - half, 0), min(i + half + 1, n)
        j0, j1 = max(j - half, 0), min(j + half + 1, m)
        if i0 < i1 and j0 < j1:
            free = np.argwhere(~grid[i0:i1, j0:j1]) + (i0, j0)
            if len(free):
                d2 = ((free - (i, j)) ** 2).sum(axis=1)
                k = int(np.argmin(d2))
                # Every cell closer than the window's half size lies inside the window, so this is the nearest.
                if d2[k] <= half * half or (i0 == 0 and j0 == 0 and i1 == n and j1 == m):
                    return int(free[k, 0]), int(free[k, 1])
        elif half > n + m + abs(i) + abs(j):
            return None
        if i0 == 0 and j0 == 0 and i1 == n and j1 == m and not (~grid).any():
            return None
        half *= 2


def snap_start_cell(grid: np.ndarray, footprint: np.ndarray, cell: Sequence[int]) -> tuple[int, int] | None:
    """Where to join the free space from a start ``cell`` that lies inside the safety margin.

    Returns the free cell of ``grid`` nearest to ``cell`` whose straight leg from ``cell``'s centre touches no
    blocked cell of ``footprint`` (the obstacles at the same altitude without margin: ``create_grid(data,
    altitude, 0)``), so the way out of the margin never passes through a building. ``None`` if ``cell`` itself
    is blocked in ``footprint`` (the start touches a building) or no such cell exists.

    >>> grid = np.zeros((5, 7), dtype=bool); grid[:, 1:6] = True      # margin: only columns 0 and 6 free
    >>> footprint = np.zeros_like(grid); footprint[:, 2] = True         # a wall between the start and column 0
    >>> snap_start_cell(grid, footprint, (2, 3))                        # column 0 is nearer, but behind the wall
    (2, 6)
    """
    i, j = int(cell[0]), int(cell[1])
    n, m = grid.shape
    if not (0 <= i < n and 0 <= j < m) or footprint[i, j]:
        return None
    half = 4
    while True:
        i0, i1, j0, j1 = max(i - half, 0), min(i + half + 1, n), max(j - half, 0), min(j + half + 1, m)
        candidates = np.argwhere(~grid[i0:i1, j0:j1]) + (i0, j0)
        d2 = ((candidates - (i, j)) ** 2).sum(axis=1)
        whole_grid = i0 == 0 and j0 == 0 and i1 == n and j1 == m
        for k in np.argsort(d2, kind="stable"):
            if d2[k] > half * half and not whole_grid:
                break  # a nearer visible cell may lie outside this window
            if line_of_sight(footprint, (i, j), candidates[k]):
                return int(candidates[k, 0]), int(candidates[k, 1])
        if whole_grid:
            return None
        half *= 2
