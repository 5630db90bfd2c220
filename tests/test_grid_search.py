"""Search optimality and safety: hand-drawn maps with answers worked out by hand, and random maps checked against
an independent Dijkstra written here from scratch."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest

from planning_utils import (
    BlockedCellError,
    GridPlanner,
    NoPathError,
    OutsideGridError,
    a_star,
    heuristic,
    nearest_free_cell,
)
from skyroute.planning.search import python_a_star

SQRT2 = math.sqrt(2)
METHODS = ["jps", "astar"]


def dijkstra_cost(grid: np.ndarray, start, goal, weights: np.ndarray | None = None) -> float:
    """Reference: plain Dijkstra on the 8-connected graph without corner cutting; inf if unreachable. With
    ``weights``, a step costs its length times the mean weight of its two cells."""
    n, m = grid.shape
    dist = {tuple(start): 0.0}
    queue = [(0.0, tuple(start))]
    while queue:
        d, (i, j) = heapq.heappop(queue)
        if (i, j) == tuple(goal):
            return d
        if d > dist[(i, j)]:
            continue
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di == dj == 0:
                    continue
                a, b = i + di, j + dj
                if not (0 <= a < n and 0 <= b < m) or grid[a, b]:
                    continue
                if di and dj and (grid[i + di, j] or grid[i, j + dj]):
                    continue
                nd = d + (SQRT2 if di and dj else 1.0) * (1.0 if weights is None else
                                                          0.5 * (weights[i, j] + weights[a, b]))
                if nd < dist.get((a, b), math.inf):
                    dist[(a, b)] = nd
                    heapq.heappush(queue, (nd, (a, b)))
    return math.inf


def assert_valid_path(grid: np.ndarray, cells: np.ndarray, start, goal, cost: float) -> None:
    """Adjacent free cells, no corner cutting, from start to goal, and the steps add up to ``cost``."""
    cells = np.asarray(cells)
    assert tuple(cells[0]) == tuple(start) and tuple(cells[-1]) == tuple(goal)
    assert not grid[cells[:, 0], cells[:, 1]].any()
    steps = np.diff(cells, axis=0)
    assert (np.abs(steps).max(axis=1) == 1).all()
    diagonal = (steps != 0).all(axis=1)
    for (i, j), (di, dj) in zip(cells[:-1][diagonal], steps[diagonal]):
        assert not grid[i + di, j] and not grid[i, j + dj], "diagonal squeezes past a blocked corner"
    assert math.isclose(diagonal.sum() * SQRT2 + (~diagonal).sum(), cost, abs_tol=1e-9)


def random_grid(rng: np.random.Generator, shape=(40, 50), density=0.3, blob=True) -> np.ndarray:
    """Random obstacles: single cells plus rectangles, so both mazes and city-like blocks get tested."""
    grid = rng.random(shape) < density * (0.3 if blob else 1.0)
    if blob:
        for _ in range(int(shape[0] * shape[1] * density / 40)):
            i, j = rng.integers(0, shape[0]), rng.integers(0, shape[1])
            grid[i : i + rng.integers(1, 8), j : j + rng.integers(1, 8)] = True
    return grid


@pytest.mark.parametrize("method", METHODS)
def test_open_grid_costs_are_octile_distances(method):
    grid = np.zeros((10, 10), dtype=bool)
    planner = GridPlanner(grid, method)
    # 3 north, 7 east: 3 diagonals + 4 straight.
    path = planner.plan((0, 0), (3, 7))
    assert path.cost == pytest.approx(3 * SQRT2 + 4, abs=1e-12)
    assert_valid_path(grid, path.cells, (0, 0), (3, 7), path.cost)


@pytest.mark.parametrize("method", METHODS)
def test_wall_with_gap_forces_detour_through_gap(method):
    # North up; row index = north. Wall along east index 3 except a gap at north 4.
    #   north 4 . . . _ . .
    #   north 3 . . . # . .
    #   north 2 . . . # . .
    #   north 1 . . . # . .
    #   north 0 S . . # . G
    grid = np.zeros((5, 6), dtype=bool)
    grid[0:4, 3] = True
    path = GridPlanner(grid, method).plan((0, 0), (0, 5))
    # By hand: the gap (4, 3) can only be entered from (4, 2), because the diagonal from (3, 2) would pass the
    # wall cell (3, 3); likewise it can only be left to (4, 4). (0,0)->(4,2): 2 diagonals + 2 straight;
    # (4,2)->(4,3)->(4,4): 2 straight; (4,4)->(0,5): 1 diagonal + 3 straight. Total 3*sqrt2 + 7.
    assert path.cost == pytest.approx(3 * SQRT2 + 7, abs=1e-12)
    assert [4, 3] in path.cells.tolist()
    assert_valid_path(grid, path.cells, (0, 0), (0, 5), path.cost)


@pytest.mark.parametrize("method", METHODS)
def test_diagonal_never_squeezes_between_touching_blocks(method):
    # Two blocked cells touching at a corner: the only diagonal through that corner is forbidden.
    #   north 1  .  #
    #   north 0  #  .
    grid = np.array([[True, False], [False, True]])
    with pytest.raises(NoPathError):
        GridPlanner(grid, method).plan((0, 1), (1, 0))


@pytest.mark.parametrize("method", METHODS)
def test_moving_north_increases_the_north_index(method):
    grid = np.zeros((5, 1), dtype=bool)
    path = GridPlanner(grid, method).plan((0, 0), (4, 0))
    assert path.cells[:, 0].tolist() == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", range(40))
def test_cost_equals_dijkstra_on_random_maps(method, seed):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng, density=0.15 + 0.35 * rng.random(), blob=bool(seed % 2))
    planner = GridPlanner(grid, method)
    free = np.argwhere(~grid)
    for _ in range(5):
        start, goal = free[rng.integers(len(free))], free[rng.integers(len(free))]
        expected = dijkstra_cost(grid, start, goal)
        if math.isinf(expected):
            with pytest.raises(NoPathError):
                planner.plan(start, goal)
            continue
        path = planner.plan(start, goal)
        assert path.cost == pytest.approx(expected, abs=1e-9)
        assert_valid_path(grid, path.cells, start, goal, path.cost)


def test_planner_reuse_does_not_leak_state_between_queries():
    rng = np.random.default_rng(7)
    grid = random_grid(rng, shape=(60, 60), density=0.3)
    free = np.argwhere(~grid)
    reused = GridPlanner(grid)
    for _ in range(30):
        start, goal = free[rng.integers(len(free))], free[rng.integers(len(free))]
        try:
            fresh_cost = GridPlanner(grid).plan(start, goal).cost
        except NoPathError:
            with pytest.raises(NoPathError):
                reused.plan(start, goal)
            continue
        assert reused.plan(start, goal).cost == fresh_cost


def test_start_equal_to_goal_is_a_zero_cost_path():
    path = GridPlanner(np.zeros((3, 3), dtype=bool)).plan((1, 1), (1, 1))
    assert path.cost == 0 and path.cells.tolist() == [[1, 1]]


def test_outside_start_and_goal_are_typed_errors():
    planner = GridPlanner(np.zeros((4, 4), dtype=bool))
    with pytest.raises(OutsideGridError, match="start cell \\(-1, 0\\) is off the map"):
        planner.plan((-1, 0), (1, 1))
    with pytest.raises(OutsideGridError, match="goal"):
        planner.plan((0, 0), (1, 4))


def test_blocked_goal_error_names_the_nearest_free_cell():
    grid = np.zeros((9, 9), dtype=bool)
    grid[2:7, 3:9] = True
    with pytest.raises(BlockedCellError) as info:
        GridPlanner(grid).plan((0, 0), (4, 7))
    # From (4, 7) the block reaches 2 cells south/north (to rows 2..6) and 5 cells west: nearest free is
    # 3 rows away, (1, 7) or (7, 7); the search is symmetric so accept either.
    assert info.value.nearest_free in {(1, 7), (7, 7)}
    assert "nearest free cell is" in str(info.value)


def test_nearest_free_cell_matches_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(50):
        grid = random_grid(rng, shape=(30, 30), density=0.6)
        cell = tuple(rng.integers(-5, 35, size=2))
        free = np.argwhere(~grid)
        found = nearest_free_cell(grid, cell)
        if not len(free):
            assert found is None
            continue
        best = ((free - cell) ** 2).sum(axis=1).min()
        assert ((np.array(found) - cell) ** 2).sum() == best


def test_nearest_free_cell_of_full_grid_is_none():
    assert nearest_free_cell(np.ones((5, 5), dtype=bool), (2, 2)) is None


@pytest.mark.parametrize("seed", range(20))
def test_a_custom_heuristic_runs_the_python_a_star_and_stays_optimal(seed):
    rng = np.random.default_rng(500 + seed)
    grid = random_grid(rng, shape=(25, 30), density=0.15 + 0.3 * rng.random(), blob=bool(seed % 2))
    free = np.argwhere(~grid)
    calls = []

    def euclidean(position, goal_position):  # the classic heuristic, but not the object a_star knows
        calls.append(position)
        return math.hypot(position[0] - goal_position[0], position[1] - goal_position[1])

    for _ in range(3):
        start, goal = tuple(free[rng.integers(len(free))]), tuple(free[rng.integers(len(free))])
        expected = dijkstra_cost(grid, start, goal)
        if math.isinf(expected):
            with pytest.raises(NoPathError):
                a_star(grid, euclidean, start, goal)
            continue
        path, cost = a_star(grid, euclidean, start, goal)
        assert cost == pytest.approx(expected, abs=1e-9)
        assert_valid_path(grid, np.array(path), start, goal, cost)
    assert calls  # the heuristic was really asked


# A wall up column 6 with a gap in the top row, and a block in column 3 in front of the start. The cheapest way
# from S (4, 0) to G (4, 12) passes the block and climbs along the wall to the gap; a search pulled hard towards
# the goal (5 x the straight-line distance) runs into the block and the wall first and settles for a longer way.
#   north 8  . . . . . . . . . . . . .
#   north 7  . . . . . . # . . . . . .
#   north 6  . . . . . . # . . . . . .
#   north 5  . . . # . . # . . . . . .
#   north 4  S . . # . . # . . . . . G
#   north 3  . . . # . . # . . . . . .
#   north 2  . . . . . . # . . . . . .
#   north 1  . . . . . . # . . . . . .
#   north 0  . . . . . . # . . . . . .
TRAP = np.zeros((9, 13), dtype=bool)
TRAP[0:8, 6] = True
TRAP[3:6, 3] = True


def test_a_custom_heuristic_changes_the_search():
    def euclidean(a, b):
        return math.hypot(a[0] - b[0], a[1] - b[1])

    optimal = dijkstra_cost(TRAP, (4, 0), (4, 12))
    dijkstra = python_a_star(TRAP, lambda a, b: 0.0, (4, 0), (4, 12))
    guided = python_a_star(TRAP, euclidean, (4, 0), (4, 12))
    greedy_path, greedy_cost = a_star(TRAP, lambda a, b: 5 * euclidean(a, b), (4, 0), (4, 12))
    assert dijkstra.cost == pytest.approx(optimal) and guided.cost == pytest.approx(optimal)
    assert guided.expanded < dijkstra.expanded  # a better-informed heuristic expands fewer cells
    assert greedy_cost > optimal + 0.5  # an inadmissible one is followed, to a longer path
    assert_valid_path(TRAP, np.array(greedy_path), (4, 0), (4, 12), greedy_cost)
    assert a_star(TRAP, heuristic, (4, 0), (4, 12))[1] == pytest.approx(optimal)  # the compiled path


def test_a_querys_memory_does_not_grow_with_the_grid():
    # The same 60 x 60 neighbourhood alone and walled into a 3000 x 3000 grid (9 M cells): the search touches the
    # same cells, so its state table is the same size, and neither query allocates anything grid-sized.
    import tracemalloc

    rng = np.random.default_rng(11)
    small = random_grid(rng, shape=(60, 60), density=0.3)
    small[0, 0] = small[59, 59] = False
    big = np.ones((3000, 3000), dtype=bool)
    big[1500:1560, 1500:1560] = small
    results = []
    for grid, offset in ((small, 0), (big, 1500)):
        tracemalloc.start()
        planner = GridPlanner(grid)
        built = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        path = planner.plan((offset, offset), (offset + 59, offset + 59))
        query = tracemalloc.get_traced_memory()[1] - before  # numba's allocations are traced too
        tracemalloc.stop()
        results.append((path, built, query))
    (small_path, _, small_query), (big_path, big_built, big_query) = results
    assert big_path.cost == small_path.cost and big_path.expanded == small_path.expanded
    assert big_path.state_entries == small_path.state_entries < 4096
    assert big_query < 100_000 and small_query < 100_000
    # The planner's own tables: the padded grid (a byte per cell) and the jump scans' bit tables (another byte).
    assert big_built < 2.1 * big.size


def test_classic_a_star_signature_returns_tuples_and_cost():
    grid = np.zeros((3, 3), dtype=bool)
    path, cost = a_star(grid, heuristic, (0, 0), (2, 2))
    assert path == [(0, 0), (1, 1), (2, 2)]
    assert cost == pytest.approx(2 * SQRT2)


def test_classic_heuristic_is_euclidean():
    assert heuristic((0, 0), (3, 4)) == 5.0


def test_grid_planner_rejects_non_bool_grids():
    with pytest.raises(ValueError, match="bool"):
        GridPlanner(np.zeros((3, 3), dtype=np.uint8))


# ---------------------------------------------------------------------------------------------------------------
# The bit tables under jump point search, against plain NumPy and a cell-by-cell scan


def padded_bits_reference(grid: np.ndarray) -> np.ndarray:
    """The padded grid packed by NumPy: bit k of word w of row r = padded cell (r, 64 w + k), past the end 1."""
    padded = np.pad(grid, 1, constant_values=True)
    words = (padded.shape[1] + 63) // 64
    wide = np.ones((padded.shape[0], 64 * words), dtype=bool)
    wide[:, : padded.shape[1]] = padded
    return np.packbits(wide, axis=1, bitorder="little").view("<u8")


@pytest.mark.parametrize("shape", [(1, 1), (5, 62), (7, 63), (3, 64), (66, 65), (130, 129)])
def test_bit_packing_matches_numpy(shape):
    from skyroute.planning import kernels

    grid = np.random.default_rng(sum(shape)).random(shape) < 0.4
    np.testing.assert_array_equal(kernels.pack_rows(grid), padded_bits_reference(grid))
    np.testing.assert_array_equal(kernels.pack_columns(grid), padded_bits_reference(grid.T))


def scan_reference(padded: np.ndarray, r: int, c: int, step: int, target: int) -> int:
    """Cell by cell along row r from column c: -1 at a blocked cell, else the first cell that is the target or
    has a free side cell whose cell one step back is blocked."""
    x = c
    while True:
        x += step
        if padded[r, x]:
            return -1
        if x == target:
            return x
        for side in (r - 1, r + 1):
            if not padded[side, x] and padded[side, x - step]:
                return x


@pytest.mark.parametrize("seed", range(6))
def test_word_scans_stop_where_a_cell_by_cell_scan_does(seed):
    from skyroute.planning.kernels import bits

    rng = np.random.default_rng(seed)
    grid = rng.random((12, 200)) < [0.02, 0.1, 0.3][seed % 3]
    padded = np.pad(grid, 1, constant_values=True)
    tables = bits.scan_tables(bits.pack_rows(grid))
    free = np.argwhere(~padded)
    for r, c in free[rng.integers(len(free), size=200)]:
        target = int(rng.integers(0, 202)) if rng.random() < 0.3 else -1
        up = bits.scan_up(tables, int(r), int(c), target if target > c else -1)
        down = bits.scan_down(tables, int(r), int(c), target if 0 <= target < c else -1)
        assert up == scan_reference(padded, r, c, 1, target if target > c else -1)
        assert down == scan_reference(padded, r, c, -1, target if 0 <= target < c else -1)


def test_the_python_a_star_refuses_ends_off_the_grid_or_blocked_like_the_compiled_search():
    grid = np.zeros((4, 9), dtype=bool)  # not square: rows and columns must not be swapped
    grid[1:3, 3:6] = True
    with pytest.raises(OutsideGridError) as off:
        python_a_star(grid, lambda a, b: 0.0, (0, 0), (4, 0))  # one row beyond the last
    assert (off.value.which, tuple(off.value.cell)) == ("goal", (4, 0)) and "grid is 4 x 9 cells" in str(off.value)
    with pytest.raises(OutsideGridError):
        python_a_star(grid, lambda a, b: 0.0, (0, 9), (0, 0))  # one column beyond the last
    with pytest.raises(BlockedCellError) as blocked:
        python_a_star(grid, lambda a, b: 0.0, (1, 4), (0, 0))
    assert blocked.value.which == "start" and blocked.value.nearest_free in {(0, 4), (3, 4)}
    assert tuple(blocked.value.cell) == (1, 4) and str(blocked.value).startswith("start cell (1, 4) is inside")


def test_a_blocked_end_on_a_map_with_no_free_cell_says_so():
    err = BlockedCellError("goal", (1, 1), None)
    assert str(err) == "goal cell (1, 1) is inside an obstacle or its safety margin; no free cell on the map"
    with pytest.raises(BlockedCellError, match="no free cell on the map"):
        python_a_star(np.ones((3, 3), dtype=bool), lambda a, b: 0.0, (0, 0), (2, 2))


def test_the_classic_heuristic_is_the_euclidean_distance():
    assert heuristic((1, 2), (4, 6)) == 5.0 and heuristic((4, 6), (1, 2)) == 5.0 and heuristic((3, 3), (3, 3)) == 0


def test_no_path_errors_name_both_cells_and_the_cells_searched():
    walled = np.zeros((5, 7), dtype=bool)
    walled[:, 3] = True
    with pytest.raises(NoPathError, match=r"^no path from cell \(1, 1\) to cell \(2, 5\) \(searched \d+ cells\)$"):
        GridPlanner(walled).plan((1, 1), (2, 5))
    with pytest.raises(NoPathError) as info:
        python_a_star(walled, lambda a, b: 0.0, (1, 1), (2, 5))
    # Dijkstra (h = 0) expands every cell it can reach: the 5 x 3 cells west of the wall.
    assert str(info.value) == "no path from cell (1, 1) to cell (2, 5) (searched 15 cells)"


def test_an_unknown_search_method_is_refused_naming_the_choices():
    with pytest.raises(ValueError, match=r"unknown method 'bfs'; choose from \["):
        GridPlanner(np.zeros((3, 3), dtype=bool), method="bfs")


def test_check_cell_refuses_one_cell_beyond_each_edge_and_names_a_blocked_cell():
    grid = np.zeros((4, 9), dtype=bool)
    grid[2, 6] = True
    planner = GridPlanner(grid)
    for cell in ((4, 0), (0, 9), (-1, 0), (0, -1)):
        with pytest.raises(OutsideGridError):
            planner.check_cell("goal", cell)
    with pytest.raises(BlockedCellError) as info:
        planner.check_cell("goal", (2, 6))
    assert (info.value.which, tuple(info.value.cell)) == ("goal", (2, 6))
    assert planner.check_cell("start", (3, 8)) == (3, 8)


@pytest.mark.parametrize("seed", range(12))
def test_weighted_cost_equals_weighted_dijkstra_on_random_maps(seed):
    rng = np.random.default_rng(100 + seed)
    grid = random_grid(rng, density=0.15 + 0.3 * rng.random(), blob=bool(seed % 2))
    weights = np.where(rng.random(grid.shape) < 0.3, 1.0 + 4.0 * rng.random(grid.shape), 1.0)
    planner = GridPlanner(grid)
    free = np.argwhere(~grid)
    for _ in range(5):
        start, goal = free[rng.integers(len(free))], free[rng.integers(len(free))]
        expected = dijkstra_cost(grid, start, goal, weights)
        if math.isinf(expected):
            with pytest.raises(NoPathError):
                planner.plan_weighted(start, goal, weights)
            continue
        path = planner.plan_weighted(start, goal, weights)
        assert path.cost == pytest.approx(expected, abs=1e-9)
        steps = np.diff(path.cells, axis=0)
        a, b = path.cells[:-1], path.cells[1:]
        length = np.where((steps != 0).all(axis=1), SQRT2, 1.0)
        mean = 0.5 * (weights[a[:, 0], a[:, 1]] + weights[b[:, 0], b[:, 1]])
        assert float((length * mean).sum()) == pytest.approx(path.cost, abs=1e-9)  # the path is what it costs
        assert_valid_path(grid, path.cells, start, goal, float(length.sum()))


def test_unit_weights_give_the_unweighted_optimum():
    rng = np.random.default_rng(7)
    grid = random_grid(rng)
    free = np.argwhere(~grid)
    planner = GridPlanner(grid)
    for _ in range(10):
        start, goal = free[rng.integers(len(free))], free[rng.integers(len(free))]
        try:
            plain = planner.plan(start, goal).cost
        except NoPathError:
            continue
        assert planner.plan_weighted(start, goal, np.ones(grid.shape)).cost == pytest.approx(plain, abs=1e-9)


def test_weights_must_match_the_grid_and_never_go_below_one():
    planner = GridPlanner(np.zeros((4, 4), dtype=bool))
    with pytest.raises(ValueError, match="shape"):
        planner.plan_weighted((0, 0), (3, 3), np.ones((4, 5)))
    with pytest.raises(ValueError, match="at least 1"):
        planner.plan_weighted((0, 0), (3, 3), np.full((4, 4), 0.5))
