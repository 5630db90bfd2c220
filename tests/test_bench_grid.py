"""Checks of the benchmark's own yardsticks on hand-drawn maps.

The reference and the path checker decide what "optimal" and "valid" mean in the table, so they get answers
worked out by hand here, independently of planning_utils.
"""

import math
import sys
from pathlib import Path

import numpy as np
from scipy.sparse.csgraph import dijkstra

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import bench_grid  # noqa: E402
import classic_astar  # noqa: E402

# Row 0 is south. '#' blocked. Going from (0, 0) to (1, 1): the diagonal squeezes between (0, 1) and (1, 0).
SQUEEZE = np.array([[c == "#" for c in row] for row in [".#.", "#..", "..."]])


def test_csr_reference_forbids_corner_cutting():
    dist = dijkstra(bench_grid.csr_graph(SQUEEZE), indices=0)
    # (0,0) is walled in: both orthogonal neighbours blocked, and the diagonal may not squeeze through.
    assert math.isinf(dist[1 * 3 + 1])


def test_csr_reference_costs_on_an_open_grid():
    open_grid = np.zeros((3, 4), dtype=bool)
    dist = dijkstra(bench_grid.csr_graph(open_grid), indices=0)
    assert abs(dist[2 * 4 + 3] - (2 * math.sqrt(2) + 1)) < 1e-12  # two diagonals then one step east
    assert dist[0 * 4 + 3] == 3


def test_csr_reference_goes_around_a_wall_end():
    # Wall on row 1, columns 0-1; from (0, 0) to (2, 0). Both diagonals past the wall's end, (0,1)->(1,2) and
    # (1,2)->(2,1), pass the blocked (1, 1), so the only way is six straight steps:
    # (0,0) (0,1) (0,2) (1,2) (2,2) (2,1) (2,0).
    grid = np.array([[c == "#" for c in row] for row in ["...", "##.", "..."]])
    dist = dijkstra(bench_grid.csr_graph(grid), indices=0)
    assert dist[2 * 3 + 0] == 6


def test_check_path_counts_corner_cuts_and_cost():
    check = bench_grid.check_path(SQUEEZE, [(0, 0), (1, 1), (2, 2)], (0, 0), (2, 2))
    assert check.corner_cuts == 1
    assert check.cost == 2 * math.sqrt(2)
    assert check.problem == ""
    bad = bench_grid.check_path(SQUEEZE, [(0, 0), (0, 1), (1, 1)], (0, 0), (1, 1))
    assert "blocked" in bad.problem


def test_classic_astar_squeezes_where_our_graph_does_not():
    path, cost = classic_astar.a_star(SQUEEZE, classic_astar.heuristic, (0, 0), (2, 2))
    assert path == [(0, 0), (1, 1), (2, 2)]
    assert cost == 2 * math.sqrt(2)
