"""Configuration space, pruning and waypoints (the map reader has tests/test_maps.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning_utils import (
    BlockedCellError,
    GridMap,
    GridPlanner,
    NoPathError,
    create_grid,
    headings_along,
    line_of_sight,
    nearest_free_cell,
    path_length,
    prune_collinear,
    prune_path,
    supercover,
    waypoints_from_cells,
)
from tests.test_grid_search import random_grid

# ---------------------------------------------------------------------------------------------------------------
# Configuration space


def point_to_footprint_m(north: float, east: float, box) -> float:
    """Exact horizontal distance from a point to a box's footprint (0 inside)."""
    gap_n = max(box[0] - box[3] - north, north - (box[0] + box[3]), 0.0)
    gap_e = max(box[1] - box[4] - east, east - (box[1] + box[4]), 0.0)
    return math.hypot(gap_n, gap_e)


def cell_to_footprint_m(north0: float, east0: float, box) -> float:
    """Exact distance from the 1 m square [north0, north0 + 1] x [east0, east0 + 1] to a box's footprint: the
    point-to-box distance of the square's point nearest the box (clamp the box centre into the square)."""
    return point_to_footprint_m(min(max(box[0], north0), north0 + 1), min(max(box[1], east0), east0 + 1), box)


def reaches(box, altitude, safety) -> bool:
    return box[2] + box[5] + safety > altitude


def brute_force_grid(data, altitude, safety):
    """Reference: every cell square against every box with the exact distance above, in plain Python loops.
    Blocked iff some point of the square is closer than the margin to a box that reaches the altitude (with no
    margin: iff the square overlaps the footprint's interior)."""
    north, east, alt, dn, de, da = data.T
    n0 = int(np.floor(np.min(north - dn)))
    e0 = int(np.floor(np.min(east - de)))
    shape = (int(np.ceil(np.max(north + dn))) - n0, int(np.ceil(np.max(east + de))) - e0)
    grid = np.zeros(shape, dtype=bool)
    for i in range(shape[0]):
        for j in range(shape[1]):
            for box in data:
                if not reaches(box, altitude, safety):
                    continue
                if safety > 0:
                    hit = cell_to_footprint_m(n0 + i, e0 + j, box) < safety
                else:
                    hit = (n0 + i + 1 > box[0] - box[3] and n0 + i < box[0] + box[3]
                           and e0 + j + 1 > box[1] - box[4] and e0 + j < box[1] + box[4])
                if hit:
                    grid[i, j] = True
                    break
    return grid, n0, e0


def random_obstacles(rng, count=12, extent=30.0):
    centre = rng.uniform(-extent, extent, size=(count, 2))
    half = rng.uniform(0.2, 4.0, size=(count, 2))
    height = rng.uniform(1.0, 30.0, size=count)
    return np.column_stack([centre, height / 2, half, height / 2])


@pytest.mark.parametrize("seed", range(15))
def test_create_grid_matches_an_exact_distance_reference(seed):
    rng = np.random.default_rng(seed)
    data = random_obstacles(rng)
    altitude, safety = rng.uniform(0, 25), [0.0, 1.0, 5.0, rng.uniform(0, 6)][seed % 4]
    grid, n0, e0 = create_grid(data, altitude, safety)
    expected, en0, ee0 = brute_force_grid(data, altitude, safety)
    assert (n0, e0) == (en0, ee0)
    np.testing.assert_array_equal(grid, expected)


@pytest.mark.parametrize("seed", range(20))
def test_no_free_cell_comes_within_the_margin_and_no_blocked_cell_is_far_from_every_box(seed):
    rng = np.random.default_rng(100 + seed)
    data = random_obstacles(rng, count=int(rng.integers(1, 25)))
    if seed % 2:
        data = np.round(data, 1)  # boxes on a decimal grid, as map files have them: many exact ties
    altitude, safety = 5.0, float(rng.choice([0.5, 2.0, 5.0, rng.uniform(0.1, 6)]))
    grid, n0, e0 = create_grid(data, altitude, safety)
    tall = [box for box in data if reaches(box, altitude, safety)]
    for i, j in np.argwhere(~grid):
        assert all(cell_to_footprint_m(n0 + i, e0 + j, box) >= safety for box in tall), (i, j)
    for i, j in np.argwhere(grid):
        # The square comes closer than the margin, so its centre is within margin + half a diagonal.
        centre_distance = min(point_to_footprint_m(n0 + i + 0.5, e0 + j + 0.5, box) for box in tall)
        assert centre_distance < safety + math.sqrt(2) / 2 + 1e-9, (i, j)


def test_the_margin_has_rounded_corners():
    # A 10 x 10 m footprint at north 0..10, east 0..10 (posts fix the map to 0..30), 5 m margin. By hand, the
    # nearest point of cell (13, 13) (square 13..14) to the corner (10, 10) is (13, 13): 4.24 m, blocked;
    # cell (14, 13): (14, 13), exactly 5 m, free; (14, 14): 5.66 m, free. A square margin blocks all three.
    data = np.array([[5, 5, 10, 5, 5, 10], [29.5, 29.5, 0.1, 0.5, 0.5, 0.1]])
    grid = create_grid(data, 5, 5)[0]
    assert grid[13, 13] and not grid[14, 13] and not grid[13, 14] and not grid[14, 14]
    assert grid[14, 9] and grid[14, 10] and not grid[15, 9]  # straight out from the north face: 5 m, no further


def test_a_diagonal_gap_a_square_margin_would_close_stays_open():
    # Two 10 m towers meeting the map's corners, north/east 0..10 and 20..30: their corners are 14.1 m apart,
    # so a 5 m margin leaves a 4.1 m lane between them. Square-grown (15 m squares) they would touch at (15, 15)
    # and cut the map in two; the only way from the north-west to the south-east is through the lane.
    data = np.array([[5, 5, 50, 5, 5, 50], [25, 25, 50, 5, 5, 50]])
    grid_map = GridMap.build(data, altitude_m=5, safety_m=5)
    plan = grid_map.plan((25.5, 2.5), (2.5, 25.5))
    for a, b in zip(plan.waypoints[:-1, :2], plan.waypoints[1:, :2]):
        for t in np.linspace(0, 1, 200):
            point = a + t * (b - a)
            assert min(point_to_footprint_m(*point, box) for box in data) >= 5 - 1e-9


def test_grid_rows_increase_northwards_and_offsets_are_the_south_west_corner():
    # One tall box north-east of a low one; offsets from the low box's south-west corner.
    data = np.array([[20.5, 10.5, 50, 0.5, 0.5, 50], [0.5, 0.5, 1, 0.5, 0.5, 1]])
    grid, north_offset, east_offset = create_grid(data, drone_altitude=5, safety_distance=0)
    assert (north_offset, east_offset) == (0, 0)
    assert grid.shape == (21, 11)
    assert np.argwhere(grid).tolist() == [[20, 10]]  # the tall box is in the top (northern) row


def test_low_obstacles_are_ignored_unless_within_safety_of_the_altitude():
    data = np.array([[0, 0, 2, 2, 2, 2]])  # 4 m tall
    assert not create_grid(data, drone_altitude=10, safety_distance=5)[0].any()
    assert create_grid(data, drone_altitude=8, safety_distance=5)[0].any()


def test_create_grid_rejects_bad_input():
    with pytest.raises(ValueError, match="N, 6"):
        create_grid(np.zeros((3, 5)), 5, 5)
    with pytest.raises(ValueError, match="safety_distance"):
        create_grid(np.ones((1, 6)), 5, -1)
    # NaN compares False with everything: unchecked, it would make every obstacle "low" and the grid all free.
    with pytest.raises(ValueError, match="finite"):
        create_grid(np.ones((1, 6)), 5, float("nan"))
    with pytest.raises(ValueError, match="NaN"):
        create_grid(np.ones((1, 6)), float("nan"), 5)
    with pytest.raises(ValueError, match="NaN"):
        create_grid(np.array([[0, 0, np.nan, 1, 1, 1]]), 5, 5)


# ---------------------------------------------------------------------------------------------------------------
# Supercover and line of sight


@pytest.mark.parametrize("seed", range(20))
def test_supercover_contains_every_cell_the_segment_touches(seed):
    rng = np.random.default_rng(seed)
    p0, p1 = rng.integers(-20, 20, size=(2, 2))
    cells = {tuple(c) for c in supercover(p0, p1).tolist()}
    # Dense samples along the segment, nudged a hair each way so points on cell edges count for both cells.
    t = np.linspace(0, 1, 20001)[:, None]
    points = (p0 + 0.5) + t * (p1 - p0)
    for nudge in ([1e-7, 1e-7], [1e-7, -1e-7], [-1e-7, 1e-7], [-1e-7, -1e-7]):
        touched = {tuple(c) for c in np.floor(points + nudge).astype(int).tolist()}
        assert touched <= cells
    # ...and nothing far from it: every cell is within half a diagonal of the line.
    d = np.array(sorted(cells)) + 0.5 - (p0 + 0.5)
    direction = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-12)
    offset = np.abs(d[:, 0] * direction[1] - d[:, 1] * direction[0])
    assert (offset <= math.sqrt(2) / 2 + 1e-9).all()


def test_supercover_is_symmetric():
    a = {tuple(c) for c in supercover((2, 3), (-7, 11)).tolist()}
    b = {tuple(c) for c in supercover((-7, 11), (2, 3)).tolist()}
    assert a == b


def test_line_of_sight_blocked_by_a_corner_the_segment_only_grazes():
    # The segment (0,0)->(2,2) passes exactly through the corner shared by (0,1) and (1,0).
    grid = np.zeros((3, 3), dtype=bool)
    grid[1, 0] = True
    assert not line_of_sight(grid, (0, 0), (2, 2))
    assert line_of_sight(grid, (0, 0), (0, 2))
    assert not line_of_sight(grid, (0, 0), (5, 0))  # off the grid
    assert not line_of_sight(grid, (0, 2), (3, 2)) and not line_of_sight(grid, (0, 1), (0, 3))  # one cell beyond
    assert not line_of_sight(grid, (0, 2), (-1, 2)) and not line_of_sight(grid, (0, 1), (0, -1))


# ---------------------------------------------------------------------------------------------------------------
# Pruning


def test_open_grid_prunes_to_start_and_goal():
    grid = np.zeros((30, 40), dtype=bool)
    path = GridPlanner(grid).plan((1, 2), (27, 35))
    assert prune_path(grid, path.cells).tolist() == [[1, 2], [27, 35]]


@pytest.mark.parametrize("seed", range(30))
def test_every_pruned_leg_is_collision_free_on_random_maps(seed):
    rng = np.random.default_rng(1000 + seed)
    grid = random_grid(rng, shape=(50, 50), density=0.35, blob=bool(seed % 2))
    free = np.argwhere(~grid)
    planner = GridPlanner(grid)
    for _ in range(5):
        start, goal = free[rng.integers(len(free))], free[rng.integers(len(free))]
        try:
            path = planner.plan(start, goal)
        except NoPathError:
            continue
        pruned = prune_path(grid, path.cells)
        assert pruned[0].tolist() == list(start) and pruned[-1].tolist() == list(goal)
        for a, b in zip(pruned[:-1], pruned[1:]):
            legs = supercover(a, b)
            assert not grid[legs[:, 0], legs[:, 1]].any()
        # Pruned cells are a subsequence of the path, and the route only gets shorter.
        assert path_length(pruned) <= path.cost + 1e-9
        assert path_length(pruned) >= np.hypot(*(goal - start)) - 1e-9


def test_prune_collinear_uses_a_tolerance_in_metres():
    points = np.array([[0.0, 0.0], [5.0, 0.3], [10.0, 0.0]])
    assert len(prune_collinear(points, tolerance_m=0.2)) == 3
    assert prune_collinear(points, tolerance_m=0.5).tolist() == [[0, 0], [10, 0]]


def test_prune_collinear_does_not_let_small_offsets_accumulate():
    # A slow arc: each point is within 0.2 m of its neighbours' chord, but not of the whole span's chord.
    x = np.linspace(0, 100, 51)
    points = np.column_stack([x, 0.002 * (x - 50) ** 2])
    pruned = prune_collinear(points, tolerance_m=0.2)
    for a, b in zip(pruned[:-1], pruned[1:]):
        inside = points[(points[:, 0] >= a[0]) & (points[:, 0] <= b[0])]
        t = (inside[:, 0] - a[0]) / (b[0] - a[0])
        chord = a[1] + t * (b[1] - a[1])
        assert (np.abs(inside[:, 1] - chord) <= 0.2 + 1e-9).all()


# ---------------------------------------------------------------------------------------------------------------
# Waypoints


def test_waypoint_headings_point_along_the_arriving_leg():
    cells = np.array([[0, 0], [10, 0], [10, 10], [0, 0]])
    waypoints = waypoints_from_cells(cells, north_offset=-5, east_offset=3, altitude_m=7)
    assert waypoints[:, :3].tolist() == [[-4.5, 3.5, 7], [5.5, 3.5, 7], [5.5, 13.5, 7], [-4.5, 3.5, 7]]
    np.testing.assert_allclose(waypoints[:, 3], [0, 0, math.pi / 2, -3 * math.pi / 4])


def test_single_point_heading_is_zero():
    assert headings_along(np.array([[1.0, 2.0]])).tolist() == [0.0]


def test_grid_map_plans_between_map_points():
    data = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    grid_map = GridMap.build(data, altitude_m=5, safety_m=2)
    plan = grid_map.plan((-20.0, 0.0), (20.0, 0.0))
    assert plan.waypoints[0, :2].tolist() == [-19.5, 0.5]
    assert plan.waypoints[-1, :2].tolist() == [20.5, 0.5]
    assert (plan.waypoints[:, 2] == 5).all()
    # The wall spans east -30..30 plus 2 m margin: the route must go round an end of it.
    assert np.abs(plan.waypoints[:, 1]).max() >= 32
    assert plan.length_m <= plan.cost_m + 1e-9
    assert plan.stats()["waypoints_after_pruning"] == len(plan.waypoints)
    # The raw route: adjacent cell centres (steps of 1 or sqrt 2 m) from the start's cell to the goal's.
    assert plan.raw_path_ne[0].tolist() == [-19.5, 0.5] and plan.raw_path_ne[-1].tolist() == [20.5, 0.5]
    steps = np.hypot(*np.diff(plan.raw_path_ne, axis=0).T)
    assert np.isin(np.round(steps, 9), [1.0, round(math.sqrt(2), 9)]).all()
    assert steps.sum() == pytest.approx(plan.cost_m)


def test_start_inside_the_margin_plans_from_the_nearest_free_cell():
    boxes = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    grid_map = GridMap.build(boxes, altitude_m=5, safety_m=2)
    start = (-2.5, 0.2)  # 1.5 m from the wall: inside the 2 m margin, outside the wall
    with pytest.raises(BlockedCellError):
        grid_map.plan(start, (20.0, 0.0))
    plan = grid_map.plan(start, (20.0, 0.0), snap_start=True)
    assert plan.raw_path_ne[0].tolist() == [-2.5, 0.5] and plan.raw_path_ne[1].tolist() == [-3.5, 0.5]
    assert plan.waypoints[0, :2].tolist() == [-2.5, 0.5]  # the centre of the start's own cell
    assert plan.waypoints[1, :2].tolist() == [-3.5, 0.5]  # the nearest free cell's centre, then on as usual


def test_start_inside_an_obstacle_is_never_snapped():
    boxes = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    with pytest.raises(BlockedCellError):
        GridMap.build(boxes, altitude_m=5, safety_m=2).plan((0.0, 0.0), (20.0, 0.0), snap_start=True)


# ---------------------------------------------------------------------------------------------------------------
# Nearest free cells, against brute force over the whole grid (mutation testing found these under-tested)


def brute_nearest_d2(free_cells: np.ndarray, cell) -> int | None:
    return None if not len(free_cells) else int(((free_cells - np.asarray(cell)) ** 2).sum(axis=1).min())


@pytest.mark.parametrize("seed", range(12))
def test_nearest_free_in_map_rasterises_only_around_the_cell_and_finds_the_true_nearest(seed):
    from skyroute.planning.cspace import grid_extent, nearest_free_in_map

    rng = np.random.default_rng(500 + seed)
    data = random_obstacles(rng, count=int(rng.integers(5, 40)), extent=float(rng.choice([20.0, 45.0])))
    data[:, 0] *= 1.7  # a map longer north-south than east-west: rows and columns must not be swapped
    safety = float(rng.choice([0.0, 1.0, 3.0]))
    grid, n0, e0 = create_grid(data, 0.0, safety)
    assert grid_extent(data)[:2] == (n0, e0)
    free = np.argwhere(~grid)
    for _ in range(6):
        cell = (int(rng.integers(-3, grid.shape[0] + 3)), int(rng.integers(-3, grid.shape[1] + 3)))
        nearest, blocked = nearest_free_in_map(data, 0.0, safety, n0, e0, grid.shape, cell)
        inside = 0 <= cell[0] < grid.shape[0] and 0 <= cell[1] < grid.shape[1]
        assert blocked == (not inside or bool(grid[cell])), cell
        expected = brute_nearest_d2(free, cell)
        if expected is None:
            assert nearest is None
            continue
        assert not grid[nearest] and ((np.array(nearest) - cell) ** 2).sum() == expected, (cell, nearest)


def test_nearest_free_in_map_of_a_map_with_no_free_cell_is_none_and_blocked():
    from skyroute.planning.cspace import nearest_free_in_map

    data = np.array([[5.0, 5.0, 5.0, 5.0, 5.0, 5.0]])  # one 10 x 10 m box covering the whole map
    assert nearest_free_in_map(data, 0.0, 1.0, 0, 0, (10, 10), (3, 4)) == (None, True)


@pytest.mark.parametrize("seed", range(12))
def test_snap_start_cell_is_the_nearest_free_cell_reachable_without_crossing_a_building(seed):
    from skyroute.planning.cspace import snap_start_cell

    rng = np.random.default_rng(700 + seed)
    shape = (int(rng.integers(15, 40)), int(rng.integers(15, 40)))  # not square
    footprint = np.zeros(shape, bool)
    for _ in range(int(rng.integers(2, 8))):
        i, j = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        footprint[i : i + rng.integers(1, 4), j : j + rng.integers(1, 12)] = True
    grid = footprint.copy()  # the margin: the footprint grown by 2 cells (a square margin is enough here)
    for di in range(-2, 3):
        for dj in range(-2, 3):
            grid |= np.roll(np.roll(footprint, di, 0), dj, 1)
    margin_cells = np.argwhere(grid & ~footprint)
    if not len(margin_cells):
        return
    for k in rng.integers(0, len(margin_cells), 5):
        cell = tuple(margin_cells[k])
        visible = [c for c in np.argwhere(~grid) if line_of_sight(footprint, cell, c)]
        found = snap_start_cell(grid, footprint, cell)
        if not visible:
            assert found is None
            continue
        assert found is not None and not grid[found] and line_of_sight(footprint, cell, found)
        assert ((np.array(found) - cell) ** 2).sum() == brute_nearest_d2(np.array(visible), cell)
    assert snap_start_cell(grid, footprint, (-1, 0)) is None and snap_start_cell(grid, footprint, (0, shape[1])) is None


def test_nearest_free_cell_finds_free_space_far_away_on_a_long_thin_grid():
    grid = np.ones((3, 200), bool)
    grid[2, 190] = False  # far beyond the first windows; rows and columns differ in size
    assert nearest_free_cell(grid, (0, 5)) == (2, 190)
    assert nearest_free_cell(grid, (-40, 400)) == (2, 190)


def test_the_grid_cell_limit_is_inclusive_and_the_message_gives_the_size(monkeypatch):
    from skyroute.planning import cspace

    # Corner boxes fixing the extent to north 0..2000, east 0..1000: 2 M cells at 1 m.
    data = np.array([[0.5, 0.5, 1, 0.5, 0.5, 1], [1999.5, 999.5, 1, 0.5, 0.5, 1]])
    monkeypatch.setattr(cspace, "MAX_GRID_CELLS", 2_000_000)
    assert cspace.grid_extent(data) == (0, 0, 2000, 1000)
    monkeypatch.setattr(cspace, "MAX_GRID_CELLS", 1_999_999)
    with pytest.raises(ValueError, match=r"^the obstacles span 2000 x 1000 m: 2 M cells at 1 m, more than the 2 M"):
        cspace.grid_extent(data)


def test_line_of_sight_pruning_cuts_a_three_cell_corner_in_the_open():
    from planning_utils import prune_line_of_sight

    open_grid = np.zeros((5, 5), dtype=bool)
    assert prune_line_of_sight(open_grid, np.array([[0, 0], [1, 1], [1, 2]])).tolist() == [[0, 0], [1, 2]]


def test_inside_obstacle_is_the_footprint_at_the_flight_altitude():
    # A 4 x 4 m box at north 20, east 10, 8 m tall; posts fix the map.
    boxes = np.array([[20, 10, 4, 2, 2, 4], [-40, -40, 0.5, 0.5, 0.5, 0.5], [40, 40, 0.5, 0.5, 0.5, 0.5]])
    grid_map = GridMap.build(boxes, altitude_m=5, safety_m=2)
    assert grid_map.inside_obstacle(21.5, 11.5) and grid_map.inside_obstacle(18.5, 8.5)
    assert not grid_map.inside_obstacle(20.0, -10.0) and not grid_map.inside_obstacle(23.0, 10.0)
    assert not GridMap.build(boxes, altitude_m=9, safety_m=2).inside_obstacle(20.0, 10.0)  # over its 8 m top
