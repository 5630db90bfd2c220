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


def test_yardstick_wraps_the_wall_end_exactly():
    pytest.importorskip("extremitypathfinder")
    grid = np.zeros((10, 10), bool)
    grid[5, :7] = True  # a wall north 5..6, east 0..7
    # From cell (2, 2) to (8, 2): centres (2.5, 2.5) and (8.5, 2.5) round the corners (5, 7) and (6, 7).
    expected = math.hypot(2.5, 4.5) + 1 + math.hypot(2.5, 4.5)
    assert bench.Yardstick(grid, (0, 0)).length((2, 2), (8, 2)) == pytest.approx(expected)


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
