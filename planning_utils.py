"""Grid planning: read a city map, build the configuration space, search it with A*, prune, make waypoints.

The data flows one way::

    colliders.csv --read_colliders--> obstacles (N, 6) --create_grid--> grid[north_idx, east_idx]
        --GridPlanner.plan / a_star--> cells --prune_path--> cells --waypoints_from_cells--> (K, 4) waypoints

Conventions
-----------
* Map frame: local NED metres relative to the map's home ``lat0, lon0`` (see ``frames.py``). Obstacle rows are
  ``north, east, alt, half_north, half_east, half_alt``: box centre and half sizes in metres, ``alt`` upwards.
* Grid: a ``bool`` array, ``True`` = blocked, indexed ``grid[north_idx, east_idx]``. Row 0 is the *southern*
  edge; the north index increases northwards. Cell ``(i, j)`` is the 1 m square
  ``north in [north_offset + i, north_offset + i + 1)``, ``east in [east_offset + j, east_offset + j + 1)``.
  Plot it with ``origin="lower"`` to get north up.
* Moves: 8-connected, straight cost 1, diagonal cost sqrt(2). A diagonal move is only allowed when both
  orthogonal neighbours it passes are free, so a path never squeezes between two blocked cells that touch at a
  corner.
* Waypoints: ``[north_m, east_m, altitude_m, heading_rad]`` of cell centres; heading is the direction of the leg
  that arrives at the waypoint (radians from north towards east).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import grid_search

COLLIDERS_HEADER = ("posx", "posy", "posz", "halfsizex", "halfsizey", "halfsizez")
_HOME_RE = re.compile(
    r"^\s*lat0\s+(?P<lat>[-+0-9.eE]+)\s*,\s*lon0\s+(?P<lon>[-+0-9.eE]+)\s*$",
)


# --------------------------------------------------------------------------------------------------------------
# Errors


class MapFormatError(ValueError):
    """A map file that cannot be read; ``str()`` names the file and line."""

    def __init__(self, path: str | Path, line: int, problem: str):
        self.path = str(path)
        self.line = line
        self.problem = problem
        super().__init__(f"{self.path}:{line}: {problem}")


class PlanningError(Exception):
    """Base class for planning failures that users can cause (bad start, bad goal, no path)."""


class OutsideGridError(PlanningError):
    """A start or goal cell outside the map's grid."""

    def __init__(self, which: str, cell: tuple[int, int], shape: tuple[int, int]):
        self.which, self.cell, self.shape = which, cell, shape
        super().__init__(
            f"{which} cell {cell} is off the map (grid is {shape[0]} x {shape[1]} cells, north x east)"
        )


class BlockedCellError(PlanningError):
    """A start or goal cell inside an obstacle or its safety margin; ``nearest_free`` is the closest free cell."""

    def __init__(self, which: str, cell: tuple[int, int], nearest_free: tuple[int, int] | None):
        self.which, self.cell, self.nearest_free = which, cell, nearest_free
        hint = f"; nearest free cell is {nearest_free}" if nearest_free is not None else "; no free cell on the map"
        super().__init__(f"{which} cell {cell} is inside an obstacle or its safety margin{hint}")


class NoPathError(PlanningError):
    """Start and goal are both free but not connected."""

    def __init__(self, start: tuple[int, int], goal: tuple[int, int], expanded: int):
        self.start, self.goal, self.expanded = start, goal, expanded
        super().__init__(f"no path from cell {start} to cell {goal} (searched {expanded} cells)")


# --------------------------------------------------------------------------------------------------------------
# Map files


@dataclass(frozen=True)
class CityMap:
    """A city map: home position (degrees) and obstacle boxes ``(N, 6)`` in metres, map frame."""

    lat0_deg: float
    lon0_deg: float
    obstacles: np.ndarray
    path: str = "<memory>"


def read_colliders(path: str | Path) -> CityMap:
    """Read a ``colliders.csv`` map file.

    Format: line 1 ``lat0 <deg>, lon0 <deg>``; line 2 the header
    ``posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ``; then one row per box ``north, east, alt, half_north,
    half_east, half_alt`` in metres. Blank lines are ignored.

    Raises
    ------
    MapFormatError
        Naming the file and line, for a missing or garbled home line or header, a row without 6 numbers,
        a NaN or infinite value, a negative half size, or a file with no obstacles.
    OSError
        If the file cannot be opened.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise MapFormatError(path, 1, f"not a text file ({exc.reason})") from None
    lines = text.splitlines()
    if not lines:
        raise MapFormatError(path, 1, "empty file; expected 'lat0 <deg>, lon0 <deg>'")
    lat0, lon0 = _parse_home_line(path, lines[0])
    if len(lines) < 2 or [c.strip().lower() for c in lines[1].split(",")] != list(COLLIDERS_HEADER):
        got = lines[1].strip() if len(lines) >= 2 else "end of file"
        raise MapFormatError(path, 2, f"expected header 'posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ', got {got!r}")

    line_numbers = [n for n, line in enumerate(lines[2:], start=3) if line.strip()]
    if not line_numbers:
        raise MapFormatError(path, 3, "no obstacle rows after the header")
    rows = [lines[n - 1] for n in line_numbers]
    try:
        obstacles = np.loadtxt(rows, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError:
        obstacles = None
    if obstacles is None or obstacles.shape[1] != 6:
        for n, row in zip(line_numbers, rows):
            _parse_row(path, n, row)
        raise MapFormatError(path, line_numbers[0], "rows are not 6 comma-separated numbers")  # pragma: no cover

    bad_value = ~np.isfinite(obstacles).all(axis=1)
    if bad_value.any():
        n = line_numbers[int(np.argmax(bad_value))]
        raise MapFormatError(path, n, "NaN or infinite value")
    negative = (obstacles[:, 3:] < 0).any(axis=1)
    if negative.any():
        n = line_numbers[int(np.argmax(negative))]
        raise MapFormatError(path, n, "negative half size")
    return CityMap(lat0, lon0, obstacles, str(path))


def _parse_home_line(path: Path, line: str) -> tuple[float, float]:
    match = _HOME_RE.match(line)
    if match is None:
        raise MapFormatError(path, 1, f"expected 'lat0 <deg>, lon0 <deg>', got {line.strip()!r}")
    try:
        lat0, lon0 = float(match["lat"]), float(match["lon"])
    except ValueError:
        raise MapFormatError(path, 1, f"home is not two numbers: {line.strip()!r}") from None
    if not (-90.0 <= lat0 <= 90.0 and -180.0 <= lon0 <= 180.0):
        raise MapFormatError(path, 1, f"home lat0 {lat0}, lon0 {lon0} is outside [-90, 90] x [-180, 180]")
    return lat0, lon0


def _parse_row(path: Path, line_number: int, row: str) -> None:
    fields = row.split(",")
    if len(fields) != 6:
        raise MapFormatError(path, line_number, f"expected 6 columns, got {len(fields)}")
    for value in fields:
        try:
            float(value)
        except ValueError:
            raise MapFormatError(path, line_number, f"not a number: {value.strip()!r}") from None


def read_home(path: str | Path) -> tuple[float, float]:
    """Return the map's home ``(lat0_deg, lon0_deg)`` from line 1 of a ``colliders.csv`` file."""
    with open(path, encoding="utf-8") as f:
        return _parse_home_line(Path(path), f.readline())


# --------------------------------------------------------------------------------------------------------------
# Configuration space


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


# --------------------------------------------------------------------------------------------------------------
# Search


@dataclass(frozen=True)
class GridPath:
    """A searched path: ``cells`` ``(K, 2)`` int array from start to goal, optimal ``cost`` in cells (= metres at
    1 m resolution), and the number of cells ``expanded``."""

    cells: np.ndarray
    cost: float
    expanded: int


class GridPlanner:
    """Optimal 8-connected search on one occupancy grid, reusable across queries.

    ``method="jps"`` (default) is jump point search: A* that skips symmetric paths, same optimal cost, several
    times faster on city maps. ``method="astar"`` is the textbook A* (see ``grid_search.py`` for both loops).
    ``expanded`` counts expanded search nodes: every cell for A*, only jump points for JPS.

    Building the planner allocates its workspace once (O(grid)); each :meth:`plan` then touches only the cells
    it explores, so a 10 m query costs microseconds even on a 10 km map. The first call in a fresh environment
    compiles the kernels (a few seconds); numba caches the machine code on disk, so later processes skip that.

    Examples
    --------
    >>> grid = np.zeros((3, 5), dtype=bool)
    >>> grid[0:2, 2] = True                     # a wall from the south edge, leaving row 2 open
    >>> path = GridPlanner(grid).plan((0, 0), (0, 4))
    >>> [2, 2] in path.cells.tolist()          # through the gap
    True
    >>> bool(abs(path.cost - (4 + 2 * math.sqrt(2))) < 1e-9)   # no diagonal squeezes past the wall's end
    True
    """

    METHODS = {"jps": grid_search.jps, "astar": grid_search.astar}

    def __init__(self, grid: np.ndarray, method: str = "jps"):
        if method not in self.METHODS:
            raise ValueError(f"unknown method {method!r}; choose from {sorted(self.METHODS)}")
        self.method = method
        grid = np.asarray(grid)
        if grid.ndim != 2 or grid.dtype != np.bool_:
            raise ValueError(f"grid must be a 2D bool array (True = blocked), got {grid.dtype} {grid.shape}")
        self.grid = grid
        n, m = grid.shape
        self._width = m + 2
        padded = np.ones((n + 2, m + 2), dtype=np.bool_)
        padded[1:-1, 1:-1] = grid
        self._blocked = padded.ravel()
        size = padded.size
        self._g = np.empty(size, np.float64)
        self._parent = np.empty(size, np.int64)
        self._seen = np.zeros(size, np.int32)
        self._closed = np.zeros(size, np.int32)
        self._query = 0
        grid_search.warm_up()

    def _flat(self, cell: tuple[int, int]) -> int:
        return (cell[0] + 1) * self._width + cell[1] + 1

    def is_blocked_inside(self, cell: Sequence[int]) -> bool:
        """True if ``cell`` is on the grid and blocked."""
        n, m = self.grid.shape
        return 0 <= cell[0] < n and 0 <= cell[1] < m and bool(self.grid[cell[0], cell[1]])

    def check_cell(self, which: str, cell: Sequence[int]) -> tuple[int, int]:
        """Return ``cell`` as a tuple of ints, or raise :class:`OutsideGridError` / :class:`BlockedCellError`."""
        cell = (int(cell[0]), int(cell[1]))
        n, m = self.grid.shape
        if not (0 <= cell[0] < n and 0 <= cell[1] < m):
            raise OutsideGridError(which, cell, (n, m))
        if self.grid[cell]:
            raise BlockedCellError(which, cell, nearest_free_cell(self.grid, cell))
        return cell

    def plan(self, start: Sequence[int], goal: Sequence[int]) -> GridPath:
        """Cheapest path from ``start`` to ``goal`` (``(north_idx, east_idx)`` cells).

        Raises
        ------
        OutsideGridError, BlockedCellError
            If ``start`` or ``goal`` is off the grid or blocked.
        NoPathError
            If no path connects them.
        """
        start = self.check_cell("start", start)
        goal = self.check_cell("goal", goal)
        self._query += 1
        if self._query == np.iinfo(np.int32).max:  # stamps would wrap: start again from clean arrays
            self._seen[:] = 0
            self._closed[:] = 0
            self._query = 1
        s, t = self._flat(start), self._flat(goal)
        search = self.METHODS[self.method]
        cost, expanded = search(
            self._blocked, self._width, s, t, self._query, self._g, self._parent, self._seen, self._closed
        )
        if cost < 0:
            raise NoPathError(start, goal, expanded)
        flat = grid_search.trace_path(self._parent, t, self._width)
        cells = np.column_stack((flat // self._width - 1, flat % self._width - 1))
        return GridPath(cells, float(cost), int(expanded))


def heuristic(position: Sequence[float], goal_position: Sequence[float]) -> float:
    """Euclidean distance between two cells (the classic exercise's heuristic)."""
    return float(np.hypot(position[0] - goal_position[0], position[1] - goal_position[1]))


def a_star(
    grid: np.ndarray, h: Callable | None, start: Sequence[int], goal: Sequence[int]
) -> tuple[list[tuple[int, int]], float]:
    """Classic-exercise entry point: ``(path, cost)`` with ``path`` a list of ``(north_idx, east_idx)`` tuples.

    ``h`` is accepted for compatibility with the classic signature and ignored: the search always uses the
    octile distance, the exact cost on an empty 8-connected grid, which is consistent, so the result is optimal
    (any admissible ``h``, such as the classic Euclidean :func:`heuristic`, has the same optimal cost). For many
    queries on one grid, build a :class:`GridPlanner` once instead.
    """
    path = GridPlanner(np.asarray(grid, dtype=bool)).plan(start, goal)
    return [(int(i), int(j)) for i, j in path.cells], path.cost


# --------------------------------------------------------------------------------------------------------------
# Line of sight and pruning


def supercover(p0: Sequence[int], p1: Sequence[int]) -> np.ndarray:
    """Every cell touched by the segment between the centres of cells ``p0`` and ``p1``, as ``(K, 2)`` ints.

    >>> supercover((0, 0), (2, 2)).tolist()      # through two vertices: the side cells count
    [[0, 0], [1, 0], [0, 1], [1, 1], [2, 1], [1, 2], [2, 2]]
    >>> supercover((0, 0), (1, 2)).tolist()
    [[0, 0], [0, 1], [1, 1], [1, 2]]
    """
    i0, j0, i1, j1 = int(p0[0]), int(p0[1]), int(p1[0]), int(p1[1])
    out = np.empty((abs(i1 - i0) + abs(j1 - j0) + 1 + 2 * min(abs(i1 - i0), abs(j1 - j0)), 2), np.int64)
    count = grid_search.walk_supercover(np.zeros((1, 1), np.bool_), i0, j0, i1, j1, out)
    return out[:count]


def line_of_sight(grid: np.ndarray, p0: Sequence[int], p1: Sequence[int]) -> bool:
    """True if every cell the segment between cell centres ``p0`` and ``p1`` touches is free (and on the grid)."""
    n, m = grid.shape
    for p in (p0, p1):
        if not (0 <= p[0] < n and 0 <= p[1] < m):
            return False
    no_output = np.empty((0, 2), np.int64)
    return grid_search.walk_supercover(grid, int(p0[0]), int(p0[1]), int(p1[0]), int(p1[1]), no_output) == 0


def prune_line_of_sight(grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Greedy string pulling: keep a cell only where the straight leg from the last kept cell would touch a
    blocked cell (supercover check), so every returned leg is collision-free on ``grid``.

    ``cells`` is a ``(K, 2)`` path of adjacent, free cells; returns a ``(M, 2)`` subset, first and last kept.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    if len(cells) <= 2:
        return cells.copy()
    return cells[grid_search.prune_los_mask(np.asarray(grid, dtype=np.bool_), cells)]


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
    """Line-of-sight pruning (which also removes collinear cells): ``(K, 2)`` cells -> ``(M, 2)`` cells."""
    return prune_line_of_sight(grid, cells)


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


# --------------------------------------------------------------------------------------------------------------
# One call from map points to waypoints


@dataclass(frozen=True)
class Plan:
    """A planned route and how it was found; every planner returns one.

    ``waypoints`` is ``(K, 4)``: ``[north_m, east_m, altitude_m, heading_rad]`` in the map frame, the first at the
    start. ``raw_path_ne`` ``(R, 2)`` is the route before pruning in map metres (cell centres for grid planners),
    ``length_m`` the length of the flown (pruned) route, ``cost_m`` the optimal cost on the planner's own graph,
    ``search_ms`` the search time, ``expanded`` the number of nodes the search expanded. ``extra`` holds
    planner-specific numbers; ``structure`` what a plot may draw under the path (e.g. a graph's edges).
    """

    planner: str
    waypoints: np.ndarray
    raw_path_ne: np.ndarray
    length_m: float
    cost_m: float
    search_ms: float
    expanded: int
    extra: dict = field(default_factory=dict)
    structure: dict = field(default_factory=dict)

    def stats(self) -> dict:
        """Plain-number summary for printing or JSON."""
        return {
            "planner": self.planner,
            "cost_m": round(self.cost_m, 3),
            "length_m": round(self.length_m, 3),
            "expanded": int(self.expanded),
            "search_ms": round(self.search_ms, 3),
            "waypoints_before_pruning": int(len(self.raw_path_ne)),
            "waypoints_after_pruning": int(len(self.waypoints)),
            **self.extra,
        }


@dataclass(frozen=True)
class GridMap:
    """A configuration-space grid for one altitude and safety margin (metres), with its planner.

    The grid spans the obstacles' footprints, so two low posts mark the corners of this 80 m map; the wall is
    2 m thick, 60 m long and 20 m tall, and with a 2 m margin the route passes its end 32.5 m east:

    >>> boxes = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    >>> plan = GridMap.build(boxes, altitude_m=5, safety_m=2).plan((-20.0, 0.0), (20.0, 0.0))
    >>> plan.waypoints[:, :3].tolist()
    [[-19.5, 0.5, 5.0], [-3.5, 32.5, 5.0], [3.5, 32.5, 5.0], [20.5, 0.5, 5.0]]
    """

    obstacles: np.ndarray
    grid: np.ndarray
    north_offset: int
    east_offset: int
    altitude_m: float
    safety_m: float
    planner: GridPlanner

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float) -> GridMap:
        grid, north_offset, east_offset = create_grid(obstacles, altitude_m, safety_m)
        return cls(obstacles, grid, north_offset, east_offset, altitude_m, safety_m, GridPlanner(grid))

    def cell_of(self, north_m: float, east_m: float) -> tuple[int, int]:
        """Grid cell containing the map point ``(north_m, east_m)``."""
        return map_to_cell(north_m, east_m, self.north_offset, self.east_offset)

    def centre_of(self, cell: Sequence[int]) -> tuple[float, float]:
        """Map point ``(north_m, east_m)`` at the centre of ``cell``."""
        return cell_to_map(cell, self.north_offset, self.east_offset)

    def inside_obstacle(self, north_m: float, east_m: float) -> bool:
        """True if the point is inside an obstacle's footprint taller than the altitude (ignoring the margin)."""
        n, e, alt, dn, de, da = self.obstacles.T
        return bool(
            ((np.abs(n - north_m) < dn) & (np.abs(e - east_m) < de) & (alt + da > self.altitude_m)).any()
        )

    def snap_start(self, start_ne: Sequence[float]) -> tuple[tuple[int, int], np.ndarray | None]:
        """The start cell to search from, and the lead-in point when the start lies inside the safety margin.

        A start whose cell is blocked (but that touches no building) moves to the nearest free cell reachable by
        a straight leg that passes no building (:func:`snap_start_cell`); the route then begins at the centre of
        the start cell (the vehicle takes off inside that obstacle-free cell) and leads out to the snapped cell.
        Otherwise the start cell is returned unchanged with no lead-in, and the search reports the problem.
        """
        start_cell = self.cell_of(*start_ne)
        if not self.planner.is_blocked_inside(start_cell):
            return start_cell, None
        footprint = create_grid(self.obstacles, self.altitude_m, 0.0)[0]
        snapped = snap_start_cell(self.grid, footprint, start_cell)
        if snapped is None:
            return start_cell, None
        return snapped, np.array(self.centre_of(start_cell))

    def plan(self, start_ne: Sequence[float], goal_ne: Sequence[float], *, snap_start: bool = False) -> Plan:
        """Plan from map point ``start_ne`` to ``goal_ne`` (``(north_m, east_m)``), prune, make waypoints.

        The route runs between cell centres (within 0.71 m of the points). With ``snap_start``, a start inside
        the safety margin (but not touching a building) leads out to the nearest free cell (:meth:`snap_start`).

        Raises
        ------
        OutsideGridError, BlockedCellError, NoPathError
            As :meth:`GridPlanner.plan`.
        """
        start_cell, lead_in = self.snap_start(start_ne) if snap_start else (self.cell_of(*start_ne), None)
        goal_cell = self.cell_of(*goal_ne)
        t0 = time.perf_counter()
        path = self.planner.plan(start_cell, goal_cell)
        search_ms = (time.perf_counter() - t0) * 1e3
        pruned = prune_path(self.grid, path.cells)
        waypoints = waypoints_from_cells(pruned, self.north_offset, self.east_offset, self.altitude_m)
        raw = path.cells + (self.north_offset + 0.5, self.east_offset + 0.5)
        if lead_in is not None:
            points = np.vstack([lead_in, waypoints[:, :2]])
            waypoints = np.column_stack([points, np.full(len(points), self.altitude_m), headings_along(points)])
            raw = np.vstack([lead_in, raw])
        return Plan(
            planner="grid",
            waypoints=waypoints,
            raw_path_ne=raw,
            length_m=path_length(waypoints[:, :2]),
            cost_m=path.cost,
            search_ms=search_ms,
            expanded=path.expanded,
            extra={"start_cell": list(start_cell), "goal_cell": list(goal_cell)},
        )
