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

from skyroute.maps import MAX_GRID_CELLS
from skyroute.planning import kernels
from skyroute.planning.pruning import line_of_sight


def grid_extent(data: np.ndarray) -> tuple[int, int, int, int]:
    """The grid :func:`create_grid` builds for ``data``: ``(north_offset, east_offset, n_north, n_east)``.

    The grid spans every footprint (whatever its height) rounded outwards to whole metres.

    Raises
    ------
    ValueError
        If ``data`` is not a non-empty ``(N, 6)`` array of finite numbers, or the grid would have more than
        :data:`skyroute.maps.MAX_GRID_CELLS` cells.
    """
    data = np.asarray(data, dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != 6 or len(data) == 0:
        raise ValueError(f"obstacle data must be a non-empty (N, 6) array, got shape {data.shape}")
    if not np.isfinite(data).all():
        raise ValueError("obstacle data contains NaN or infinite values")
    north, east, _, d_north, d_east, _ = data.T
    north_offset = math.floor(float(np.min(north - d_north)))
    east_offset = math.floor(float(np.min(east - d_east)))
    n_north = math.ceil(float(np.max(north + d_north))) - north_offset
    n_east = math.ceil(float(np.max(east + d_east))) - east_offset
    if n_north * n_east > MAX_GRID_CELLS:
        raise ValueError(
            f"the obstacles span {n_north} x {n_east} m: {n_north * n_east / 1e6:.0f} M cells at 1 m, more than "
            f"the {MAX_GRID_CELLS / 1e6:.0f} M-cell limit"
        )
    return north_offset, east_offset, n_north, n_east


def create_grid(data: np.ndarray, drone_altitude: float, safety_distance: float) -> tuple[np.ndarray, int, int]:
    """Rasterise obstacles into a 1 m occupancy grid for flight at one altitude.

    A cell is blocked when some point of its 1 m square is closer than ``safety_distance`` (Euclidean, in the
    horizontal plane) to the footprint of an obstacle that reaches the flight altitude: grown footprints have
    rounded corners. Every free cell therefore keeps at least the safety distance from every such footprint over
    its whole square, and no cell is blocked unless it comes that close (with no margin: unless it overlaps a
    footprint). Vertically the margin is a flat lid: an obstacle counts when its top plus ``safety_distance``
    exceeds ``drone_altitude``, and then with its whole horizontal margin, which keeps the drone at least the
    margin from the box in 3D too (conservative over a roof edge, where the true 3D distance is larger).

    Cost ``O(cells + boxes x rows per box)``, one row of counters besides the grid (``kernels.raster``).

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

    Raises
    ------
    ValueError
        For malformed data, a NaN altitude, a negative or non-finite margin, or a grid over the size limit
        (:func:`grid_extent`).

    Examples
    --------
    >>> box = np.array([[5.0, 5.0, 10.0, 1.0, 1.0, 10.0], [0.5, 0.5, 1.0, 0.5, 0.5, 1.0]])
    >>> grid, north_offset, east_offset = create_grid(box, drone_altitude=5, safety_distance=0)
    >>> grid.shape, north_offset, east_offset
    ((6, 6), 0, 0)
    >>> np.argwhere(grid).tolist()   # only the tall box: rows 4-5 are its north extent 4..6 m
    [[4, 4], [4, 5], [5, 4], [5, 5]]

    Rounded corners: a 1 m box in the cell north 5..6, east 5..6 with a 1.2 m margin (two low posts fix the
    map's extent). The corner cells are sqrt(2) = 1.41 m from the box, so they stay free:

    >>> boxes = np.array([[5.5, 5.5, 10, 0.5, 0.5, 10], [0.5, 0.5, 0.1, 0.5, 0.5, 0.1], [9.5, 9.5, 0.1, 0.5, 0.5, 0.1]])
    >>> grid = create_grid(boxes, drone_altitude=5, safety_distance=1.2)[0]
    >>> print("\\n".join("".join("#" if c else "." for c in row) for row in grid[7:2:-1, 3:8]))
    .###.
    #####
    #####
    #####
    .###.
    """
    north_offset, east_offset, n_north, n_east = grid_extent(data)
    grid = rasterise_window(data, drone_altitude, safety_distance, north_offset, east_offset, (n_north, n_east))
    return grid, north_offset, east_offset


def rasterise_window(
    data: np.ndarray, altitude_m: float, safety_m: float, north_offset: float, east_offset: float,
    shape: tuple[int, int],
) -> np.ndarray:
    """The cells of :func:`create_grid`'s rule in any window: ``shape`` cells whose cell ``(0, 0)`` has its
    south-west corner at map point ``(north_offset, east_offset)`` (whole metres). Boxes outside it cost only
    a vectorised test each."""
    data = np.asarray(data, dtype=np.float64)
    # NaN compares False with everything: unchecked, it would make every obstacle "low" and the grid all free.
    if math.isnan(altitude_m) or not (math.isfinite(safety_m) and safety_m >= 0):
        raise ValueError(
            f"drone_altitude must not be NaN and safety_distance must be finite and >= 0, got {altitude_m}, "
            f"{safety_m}"
        )
    n, m = int(shape[0]), int(shape[1])
    north, east, alt, d_north, d_east, d_alt = data.T
    lo_n, hi_n, lo_e, hi_e = north - d_north, north + d_north, east - d_east, east + d_east
    near = (alt + d_alt + safety_m > altitude_m) & (hi_n + safety_m > north_offset)
    near &= (lo_n - safety_m < north_offset + n) & (hi_e + safety_m > east_offset) & (lo_e - safety_m < east_offset + m)
    return kernels.rasterise(lo_n[near], hi_n[near], lo_e[near], hi_e[near], float(north_offset),
                             float(east_offset), float(safety_m), n, m)


def nearest_free_in_map(
    data: np.ndarray, altitude_m: float, safety_m: float, north_offset: int, east_offset: int,
    shape: tuple[int, int], cell: Sequence[int],
) -> tuple[tuple[int, int] | None, bool]:
    """Whether ``cell`` is blocked by :func:`create_grid`'s rule, and the free cell nearest to it, rasterising only
    square windows of doubling size around it (so a query on a 10 km map costs what its neighbourhood costs).

    ``north_offset``, ``east_offset`` and ``shape`` describe the grid (as :func:`grid_extent` returns them).
    Returns ``(nearest free cell or None if the grid has none, blocked)``; a free ``cell`` is its own nearest.
    """
    i, j = int(cell[0]), int(cell[1])
    n, m = int(shape[0]), int(shape[1])
    half = 8
    while True:
        i0, i1, j0, j1 = max(i - half, 0), min(i + half + 1, n), max(j - half, 0), min(j + half + 1, m)
        whole_grid = i0 == 0 and j0 == 0 and i1 == n and j1 == m
        if i0 < i1 and j0 < j1:
            window = rasterise_window(data, altitude_m, safety_m, north_offset + i0, east_offset + j0,
                                      (i1 - i0, j1 - j0))
            blocked = bool(window[i - i0, j - j0]) if (i0 <= i < i1 and j0 <= j < j1) else True
            free = np.argwhere(~window) + (i0, j0)
            if len(free):
                d2 = ((free - (i, j)) ** 2).sum(axis=1)
                k = int(np.argmin(d2))
                # Every cell nearer than the window's half size lies inside it, so this one is the nearest.
                if d2[k] <= half * half or whole_grid:
                    return (int(free[k, 0]), int(free[k, 1])), blocked
        if whole_grid:
            return None, True
        half *= 2


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
