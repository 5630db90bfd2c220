"""bench/bench_planners.py helpers: the polygon tracer and the yardstick behind the benchmark's length ratios."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import bench_planners as bench  # noqa: E402


def test_one_blocked_cell_traces_counter_clockwise_inside_the_clockwise_map_frame():
    grid = np.zeros((5, 5), bool)
    grid[2, 2] = True  # north 2..3, east 2..3: (x=east, y=north) square (2, 2)-(3, 3)
    loops = sorted(bench.trace_loops(grid), key=bench.signed_area)
    assert [bench.signed_area(loop) for loop in loops] == [-25.0, 1.0]
    assert sorted(map(tuple, loops[1].tolist())) == [(2, 2), (2, 3), (3, 2), (3, 3)]


def test_cells_touching_at_a_corner_trace_as_one_obstacle():
    grid = np.zeros((6, 6), bool)
    grid[2, 2] = grid[3, 3] = True
    islands = [loop for loop in bench.trace_loops(grid) if bench.signed_area(loop) > 0]
    assert len(islands) == 1 and bench.signed_area(islands[0]) == 2.0


# --------------------------------------------------------------------------------------------------------------
# The yardstick: checked against a reference written here, which needs only numpy and scipy (so it runs under
# the README's ``.[test]`` install); the benchmark's own yardstick (extremitypathfinder, a bench-only peer) is
# compared with it where it is installed.


def _segment_enters_open_cells(p: np.ndarray, q: np.ndarray, cells: np.ndarray) -> bool:
    """Whether the segment ``p``-``q`` (x = east, y = north, cell units) passes through the open interior of any
    unit square ``cells`` ``(K, 2)`` ``[north_idx, east_idx]`` (touching an edge or a corner is allowed)."""
    lo = cells[:, ::-1].astype(float)  # (x0, y0)
    d = q - p
    t_lo, t_hi = np.zeros(len(cells)), np.ones(len(cells))
    for axis in range(2):
        if abs(d[axis]) < 1e-12:
            inside = (lo[:, axis] < p[axis]) & (p[axis] < lo[:, axis] + 1)
            t_hi = np.where(inside, t_hi, -1.0)
            continue
        a, b = (lo[:, axis] - p[axis]) / d[axis], (lo[:, axis] + 1 - p[axis]) / d[axis]
        t_lo, t_hi = np.maximum(t_lo, np.minimum(a, b)), np.minimum(t_hi, np.maximum(a, b))
    return bool((t_lo < t_hi - 1e-12).any())


def reference_length(grid: np.ndarray, start_cell, goal_cell) -> float:
    """The Euclidean shortest path between two cell centres among the blocked cells (and the map's edge), paths
    allowed to touch them: Dijkstra over the visibility graph of the obstacles' convex corners (grid vertices
    with exactly one blocked cell among the four around them, off the map counting as blocked), with an exact
    segment-against-open-square test. For grids without two blocked cells meeting only at a corner."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    n, m = grid.shape
    framed = np.pad(grid, 1, constant_values=True)
    around = framed[:-1, :-1].astype(int) + framed[1:, :-1] + framed[:-1, 1:] + framed[1:, 1:]  # (n + 1, m + 1)
    corners = [(float(j), float(i)) for i, j in np.argwhere(around == 1).tolist()]
    points = np.array([(start_cell[1] + 0.5, start_cell[0] + 0.5), (goal_cell[1] + 0.5, goal_cell[0] + 0.5),
                       *corners])
    blocked = np.argwhere(grid)
    rows, cols, lengths = [], [], []
    for a in range(len(points)):
        for b in range(a + 1, len(points)):
            if not _segment_enters_open_cells(points[a], points[b], blocked):
                rows.append(a)
                cols.append(b)
                lengths.append(float(np.hypot(*(points[b] - points[a]))) or 1e-300)
    graph = csr_matrix((lengths, (rows, cols)), shape=(len(points), len(points)))
    return float(dijkstra(graph, directed=False, indices=0)[1])


def has_a_pinch(grid: np.ndarray) -> bool:
    """Two blocked cells meeting only at a corner (with the other two free)."""
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    return bool(((a & d & ~b & ~c) | (b & c & ~a & ~d)).any())


def test_the_reference_wraps_a_wall_end_exactly():
    grid = np.zeros((10, 10), bool)
    grid[5, :7] = True  # a wall north 5..6, east 0..7
    # From cell (2, 2) to (8, 2): centres (2.5, 2.5) and (8.5, 2.5) round the corners (5, 7) and (6, 7).
    expected = math.hypot(2.5, 4.5) + 1 + math.hypot(2.5, 4.5)
    assert reference_length(grid, (2, 2), (8, 2)) == pytest.approx(expected)


def test_the_reference_bends_round_one_corner_of_a_block_in_the_way():
    grid = np.zeros((10, 10), bool)
    grid[4, 4] = True  # the diagonal (1.5, 1.5) -> (8.5, 8.5) crosses its centre; it bends at (x, y) = (5, 4)
    expected = math.hypot(3.5, 2.5) + math.hypot(3.5, 4.5)
    assert reference_length(grid, (1, 1), (8, 8)) == pytest.approx(expected)
    assert reference_length(grid, (1, 1), (1, 8)) == pytest.approx(7.0)  # in the open: a straight line
    walled = grid.copy()
    walled[:, 5] = True  # no way through
    assert reference_length(walled, (1, 1), (1, 8)) == math.inf


def random_pinch_free_grid(rng: np.random.Generator) -> np.ndarray:
    while True:
        grid = np.zeros((16, 16), bool)
        for _ in range(int(rng.integers(2, 7))):
            i, j = rng.integers(0, 14, size=2)
            h, w = rng.integers(1, 6, size=2)
            grid[i : i + h, j : j + w] = True
        if not has_a_pinch(grid):
            return grid


def connected_free_pair(grid: np.ndarray, rng: np.random.Generator):
    from scipy import ndimage

    labels, _ = ndimage.label(~grid)
    free = np.argwhere(~grid)
    while True:
        start, goal = (tuple(free[k]) for k in rng.integers(0, len(free), 2))
        if labels[start] == labels[goal]:
            return start, goal


@pytest.mark.parametrize("seed", range(8))
def test_the_reference_is_between_the_straight_line_and_the_grid_route(seed):
    import planning_utils as pu

    rng = np.random.default_rng(seed)
    grid = random_pinch_free_grid(rng)
    start, goal = connected_free_pair(grid, rng)
    length = reference_length(grid, start, goal)
    straight = math.dist(start, goal)
    assert straight - 1e-9 <= length <= pu.GridPlanner(grid).plan(start, goal).cost + 1e-9
    if pu.line_of_sight(grid, start, goal):  # the straight leg between the centres touches no blocked cell
        assert length == pytest.approx(straight)


def test_the_traced_polygons_have_the_references_corners():
    # What the benchmark hands extremitypathfinder must have exactly the corners a shortest path may bend at:
    # walking each loop with the blocked cells on its left, an obstacle's convex corner is a left turn.
    rng = np.random.default_rng(11)
    grid = random_pinch_free_grid(rng)
    framed = np.pad(grid, 1, constant_values=True)
    around = framed[:-1, :-1].astype(int) + framed[1:, :-1] + framed[:-1, 1:] + framed[1:, 1:]
    expected = {(j, i) for i, j in np.argwhere(around == 1).tolist()}  # (x, y)
    left_turns = set()
    for loop in bench.trace_loops(grid):
        before, after = loop - np.roll(loop, 1, axis=0), np.roll(loop, -1, axis=0) - loop
        left = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0] > 0
        left_turns |= {tuple(v) for v in loop[left].tolist()}
    assert len(expected) >= 8 and left_turns == expected


@pytest.mark.parametrize("seed", range(6))
def test_the_benchmarks_yardstick_agrees_with_the_reference(seed):
    pytest.importorskip("extremitypathfinder")  # the bench-only peer: pip install --no-deps extremitypathfinder
    rng = np.random.default_rng(100 + seed)
    grid = random_pinch_free_grid(rng)
    start, goal = connected_free_pair(grid, rng)
    assert bench.Yardstick(grid, start).length(start, goal) == pytest.approx(reference_length(grid, start, goal))


def test_clearance_is_the_distance_to_the_nearest_box_surface():
    box = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 5.0]])
    leg = np.array([[-10.0, 4.0, 5.0], [10.0, 4.0, 5.0]])  # 3 m east of the box's east face
    assert bench.min_clearance_m(leg, box) == pytest.approx(3.0)
    over = np.array([[0.0, 0.0, 12.0], [0.0, 0.0, 20.0]])  # 2 m above its top
    assert bench.min_clearance_m(over, box) == pytest.approx(2.0)


def test_the_bench_extra_would_not_downgrade_numpy():
    # `pip install ".[bench]"` must keep the runtime's numpy 2: no bench requirement may pin numpy below 2.
    from importlib import metadata

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    from packaging.requirements import Requirement

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    for line in project["optional-dependencies"]["bench"]:
        name = Requirement(line).name
        assert name != "extremitypathfinder", "its metadata pins numpy<2; install it with --no-deps instead"
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        for dependency in map(Requirement, requires):
            applies = dependency.marker is None or dependency.marker.evaluate({"extra": ""})
            if dependency.name == "numpy" and applies:
                assert dependency.specifier.contains("2.4.0", prereleases=True), f"{name} pins {dependency}"
