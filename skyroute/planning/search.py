"""Optimal 8-connected grid search: :class:`GridPlanner` (compiled JPS / A*), the classic ``a_star`` and the
readable Python A* it runs for a custom heuristic.

Moves: 8-connected, straight cost 1, diagonal cost sqrt(2). A diagonal move is only allowed when both orthogonal
neighbours it passes are free, so a path never squeezes between two blocked cells that touch at a corner.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from skyroute.planning import kernels
from skyroute.planning.cspace import nearest_free_cell
from skyroute.planning.errors import BlockedCellError, NoPathError, OutsideGridError


@dataclass(frozen=True)
class GridPath:
    """A searched path: ``cells`` ``(K, 2)`` int array from start to goal, optimal ``cost`` in cells (= metres at
    1 m resolution), the number of nodes ``expanded``, and ``state_entries``, the size of the search's state table
    (the query's memory, which depends on the cells searched, not on the grid)."""

    cells: np.ndarray
    cost: float
    expanded: int
    state_entries: int = 0


class GridPlanner:
    """Optimal 8-connected search on one occupancy grid, reusable across queries.

    ``method="jps"`` (default) is jump point search: A* that skips symmetric paths, same optimal cost, several
    times faster on city maps. ``method="astar"`` is the textbook A* (see ``kernels/gridsearch.py`` for both).
    ``expanded`` counts expanded search nodes: every cell for A*, only jump points for JPS.

    Building the planner packs the grid into bit tables for JPS's scans (a byte per cell in all; the textbook
    A* keeps a padded byte copy instead); a query keeps its state in a hash table sized by the cells it
    stores, so a 10 m query costs microseconds and kilobytes even on a 10 km map. The first call in a fresh
    environment compiles the kernels (a few seconds); numba caches the machine code on disk, so later processes
    skip that.

    Examples
    --------
    >>> import math
    >>> grid = np.zeros((3, 5), dtype=bool)
    >>> grid[0:2, 2] = True                     # a wall from the south edge, leaving row 2 open
    >>> path = GridPlanner(grid).plan((0, 0), (0, 4))
    >>> [2, 2] in path.cells.tolist()          # through the gap
    True
    >>> bool(abs(path.cost - (4 + 2 * math.sqrt(2))) < 1e-9)   # no diagonal squeezes past the wall's end
    True
    """

    METHODS = {"jps": kernels.jps, "astar": kernels.astar}

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
        self._blocked: np.ndarray | None = None
        if method == "jps":  # the grid as bits, rows and columns, with what its straight scans need (kernels.bits)
            self._bits = (kernels.scan_tables(kernels.pack_rows(grid)), kernels.scan_tables(kernels.pack_columns(grid)))
        else:
            self._padded_blocked()
        _load(method)

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

    def plan(self, start: Sequence[int], goal: Sequence[int], max_cost: float = math.inf) -> GridPath:
        """Cheapest path from ``start`` to ``goal`` (``(north_idx, east_idx)`` cells).

        ``max_cost`` bounds the search: a goal that costs at least that much counts as unreachable.

        Raises
        ------
        OutsideGridError, BlockedCellError
            If ``start`` or ``goal`` is off the grid or blocked.
        NoPathError
            If no path connects them (within ``max_cost``).
        """
        start = self.check_cell("start", start)
        goal = self.check_cell("goal", goal)
        s, t = self._flat(start), self._flat(goal)
        if self.method == "jps":
            flat, cost, expanded, entries = kernels.jps(*self._bits, self._width, s, t, float(max_cost))
        else:
            flat, cost, expanded, entries = kernels.astar(self._blocked, self._width, s, t, float(max_cost))
        if cost < 0:
            raise NoPathError(start, goal, expanded)
        cells = np.column_stack((flat // self._width - 1, flat % self._width - 1))
        return GridPath(cells, float(cost), int(expanded), int(entries))

    def plan_weighted(self, start: Sequence[int], goal: Sequence[int], weights: np.ndarray,
                      max_cost: float = math.inf) -> GridPath:
        """Cheapest path when a step costs its length times the mean ``weights`` (``(n, m)``, every value >= 1)
        of the two cells it joins: the same graph as :meth:`plan`, textbook A* (``cost`` in weighted cells).

        >>> grid = np.zeros((3, 5), dtype=bool)
        >>> weights = np.ones((3, 5)); weights[0, 1:4] = 5.0   # the straight row is dear: go round by row 1
        >>> GridPlanner(grid).plan_weighted((0, 0), (0, 4), weights).cells[:, 0].max()
        np.int64(1)

        Raises as :meth:`plan`; ValueError if ``weights`` has another shape or a value below 1.
        """
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != self.grid.shape:
            raise ValueError(f"weights {weights.shape} and grid {self.grid.shape} differ in shape")
        if not weights.min(initial=1.0) >= 1.0:
            raise ValueError("every weight must be at least 1 (the heuristic assumes it)")
        start = self.check_cell("start", start)
        goal = self.check_cell("goal", goal)
        padded = np.ones((self.grid.shape[0] + 2, self._width), dtype=np.float64)
        padded[1:-1, 1:-1] = weights
        flat, cost, expanded, entries = kernels.weighted_astar(self._padded_blocked(), padded.ravel(), self._width,
                                                               self._flat(start), self._flat(goal), float(max_cost))
        if cost < 0:
            raise NoPathError(start, goal, expanded)
        cells = np.column_stack((flat // self._width - 1, flat % self._width - 1))
        return GridPath(cells, float(cost), int(expanded), int(entries))

    def _padded_blocked(self) -> np.ndarray:
        """The grid with a blocked border, flattened (what the textbook searches read); made once."""
        if self._blocked is None:
            n, m = self.grid.shape
            padded = np.ones((n + 2, m + 2), dtype=np.bool_)
            padded[1:-1, 1:-1] = self.grid
            self._blocked = padded.ravel()
        return self._blocked


def _load(method: str) -> None:
    """Load (or compile) the kernels of ``method`` with the argument types :meth:`GridPlanner.plan` uses, so that
    the first real query times only its search."""
    grid = np.zeros((1, 1), np.bool_)
    if method == "jps":
        tables = (kernels.scan_tables(kernels.pack_rows(grid)), kernels.scan_tables(kernels.pack_columns(grid)))
        kernels.jps(*tables, 3, 4, 4, math.inf)
    else:
        padded = np.ones((3, 3), np.bool_)
        padded[1, 1] = False
        if method == "weighted":
            kernels.weighted_astar(padded.ravel(), np.ones(9), 3, 4, 4, math.inf)
        else:
            kernels.astar(padded.ravel(), 3, 4, 4, math.inf)


def load_weighted_search() -> None:
    """Load (or compile) :meth:`GridPlanner.plan_weighted`'s kernel now, before it is needed in flight."""
    _load("weighted")


def heuristic(position: Sequence[float], goal_position: Sequence[float]) -> float:
    """Euclidean distance between two cells (the classic exercise's heuristic)."""
    return float(np.hypot(position[0] - goal_position[0], position[1] - goal_position[1]))


def a_star(
    grid: np.ndarray, h: Callable | None, start: Sequence[int], goal: Sequence[int]
) -> tuple[list[tuple[int, int]], float]:
    """Classic-exercise entry point: ``(path, cost)`` with ``path`` a list of ``(north_idx, east_idx)`` tuples.

    ``h(position, goal_position) -> float`` is the heuristic, as in the exercise. With ``h=None`` or the classic
    :func:`heuristic` itself, the compiled jump point search runs (:class:`GridPlanner`: the same optimal cost,
    around a thousand times faster than Python). With any other callable, :func:`python_a_star` runs: a readable
    Python A* that calls ``h`` for every cell it reaches, so a student who edits the heuristic sees the search
    change. Any admissible ``h`` (never above the true remaining cost, e.g. Euclidean or octile distance) gives
    the optimal cost; an inadmissible one (say ``3 * heuristic``) expands fewer cells and may return a longer
    path. For many queries on one grid, build a :class:`GridPlanner` once instead.

    Raises
    ------
    OutsideGridError, BlockedCellError, NoPathError
        As :meth:`GridPlanner.plan`.

    Examples
    --------
    >>> grid = np.zeros((3, 3), dtype=bool)
    >>> a_star(grid, heuristic, (0, 0), (2, 2))[0]
    [(0, 0), (1, 1), (2, 2)]
    >>> a_star(grid, lambda position, goal: 0.0, (0, 0), (2, 2))[0]     # Dijkstra: same optimal path
    [(0, 0), (1, 1), (2, 2)]
    """
    grid = np.asarray(grid, dtype=bool)
    if h is None or h is heuristic:
        path = GridPlanner(grid).plan(start, goal)
    else:
        path = python_a_star(grid, h, start, goal)
    return [(int(i), int(j)) for i, j in path.cells], path.cost


#: The 8 moves ``(north step, east step, cost)``.
MOVES = ((1, 0, 1.0), (-1, 0, 1.0), (0, 1, 1.0), (0, -1, 1.0),
         (1, 1, math.sqrt(2)), (1, -1, math.sqrt(2)), (-1, 1, math.sqrt(2)), (-1, -1, math.sqrt(2)))


def python_a_star(grid: np.ndarray, h: Callable, start: Sequence[int], goal: Sequence[int]) -> GridPath:
    """A* in plain Python on the same graph as :class:`GridPlanner`, calling ``h(cell, goal)`` for its heuristic.

    The open list is a heap of ``(g + h, order, g, cell)``; a cell popped with a ``g`` worse than the best known
    is a stale entry and is skipped, and a cell reached more cheaply later is pushed again (even if it was
    expanded before), so the result is optimal for every admissible ``h``, consistent or not. ``expanded``
    counts the cells taken off the heap and expanded.

    Raises
    ------
    OutsideGridError, BlockedCellError, NoPathError
        As :meth:`GridPlanner.plan`.
    """
    grid = np.asarray(grid, dtype=bool)
    n, m = grid.shape
    start, goal = _checked(grid, "start", start), _checked(grid, "goal", goal)
    best = {start: 0.0}
    came_from: dict[tuple[int, int], tuple[int, int]] = {}
    order = itertools.count()  # equal f: first pushed, first popped
    queue = [(float(h(start, goal)), next(order), 0.0, start)]
    expanded = 0
    while queue:
        _, _, g, cell = heapq.heappop(queue)
        if g > best[cell]:
            continue  # stale: a cheaper way to this cell was found after this entry was pushed
        expanded += 1
        if cell == goal:
            path = [cell]
            while path[-1] in came_from:
                path.append(came_from[path[-1]])
            return GridPath(np.array(path[::-1], dtype=np.int64), g, expanded, len(best))
        i, j = cell
        for di, dj, step in MOVES:
            a, b = i + di, j + dj
            if not (0 <= a < n and 0 <= b < m) or grid[a, b]:
                continue
            if di and dj and (grid[i + di, j] or grid[i, j + dj]):
                continue  # no diagonal past a blocked corner
            cost = g + step
            if cost < best.get((a, b), math.inf):
                best[(a, b)] = cost
                came_from[(a, b)] = cell
                heapq.heappush(queue, (cost + float(h((a, b), goal)), next(order), cost, (a, b)))
    raise NoPathError(start, goal, expanded)


def _checked(grid: np.ndarray, which: str, cell: Sequence[int]) -> tuple[int, int]:
    cell = (int(cell[0]), int(cell[1]))
    n, m = grid.shape
    if not (0 <= cell[0] < n and 0 <= cell[1] < m):
        raise OutsideGridError(which, cell, (n, m))
    if grid[cell]:
        raise BlockedCellError(which, cell, nearest_free_cell(grid, cell))
    return cell
