"""graph_planning: the planner registry, the shared collision check, the 2D roadmaps and any-angle search.

Maps are drawn by hand in metres; the two low posts at the corners fix the grid's extent, so grid cell (i, j)
is the 1 m square north [i, i + 1), east [j, j + 1) and its centre is (i + 0.5, j + 0.5). Routes are judged by
the tests' own collision check (tests/clearance.py: point-to-box distances on densely sampled legs), not by the
planners' ``colliding_legs``, which has its own tests here.
"""

from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from scipy import ndimage

import planning_utils as pu
from skyroute.planning import any_angle
from skyroute.planning import graphs as gp
from skyroute.planning import grid3d as grid3d_planning
from skyroute.planning import sampling as sampling_planning
from tests import clearance

POSTS_40 = [[0.25, 0.25, 0.1, 0.25, 0.25, 0.1], [39.75, 39.75, 0.1, 0.25, 0.25, 0.1]]  # grid 40 x 40, low
PLANNERS_2D = [name for name in gp.PLANNERS if name not in gp.PLANNERS_3D]


def boxes(*rows) -> np.ndarray:
    return np.array([*POSTS_40, *rows], dtype=np.float64)


def centre(i: int, j: int) -> tuple[float, float]:
    return i + 0.5, j + 0.5


# A wall 2 m thick along north 19..21, from the west edge to east 30, 20 m tall: flights at 5 m go round its
# east end (east 30 + margin).
WALL = boxes([20.0, 15.0, 10.0, 1.0, 15.0, 10.0])


# --------------------------------------------------------------------------------------------------------------
# Registry and errors


def test_planner_names_are_the_six_the_cli_offers():
    assert gp.PLANNERS == ("grid", "medial-axis", "voronoi", "prm", "grid3d", "any-angle")


@pytest.mark.parametrize("module", [gp, any_angle, grid3d_planning, sampling_planning], ids=lambda m: m.__name__)
def test_docstring_examples_hold(module):
    assert doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE).failed == 0


def test_unknown_planner_is_a_value_error_naming_the_choices():
    with pytest.raises(ValueError, match="medial-axis"):
        gp.plan("astar", WALL, centre(5, 5), centre(35, 5), 5, 1)


@pytest.mark.parametrize("name", PLANNERS_2D)
def test_2d_planners_reject_a_goal_altitude_they_cannot_fly(name):
    with pytest.raises(ValueError, match="goal_alt_m"):
        gp.plan(name, WALL, centre(5, 5), centre(35, 5), 5, 1, goal_alt_m=20)


def test_grid_planner_is_the_grid_maps_plan_plus_build_time():
    via_api = gp.plan("grid", WALL, centre(5, 5), centre(35, 5), 5, 1)
    direct = pu.GridMap.build(WALL, 5, 1).plan(centre(5, 5), centre(35, 5))
    np.testing.assert_array_equal(via_api.waypoints, direct.waypoints)
    assert "build_ms" in via_api.extra


def test_structure_is_built_once_per_map_altitude_and_safety():
    gp.clear_cache()
    first, _ = gp.structure_for("voronoi", WALL, 5, 1)
    again, _ = gp.structure_for("voronoi", WALL.copy(), 5, 1)
    other, _ = gp.structure_for("voronoi", WALL, 5, 2)
    assert again is first
    assert other is not first


@pytest.mark.parametrize("name", gp.PLANNERS)
def test_every_planner_reports_a_start_off_the_map(name):
    with pytest.raises(pu.OutsideGridError):
        gp.plan(name, WALL, (-5.0, 5.0), centre(35, 5), 5, 1)


@pytest.mark.parametrize("name", gp.PLANNERS)
def test_every_planner_reports_a_goal_in_the_wall_with_the_nearest_free_cell(name):
    # Goal cell (20, 10) is inside the wall; with a 1 m margin rows 18..21 are blocked, so the nearest free
    # cell is straight south at row 17 or north at row 22; row 17 is 3 cells away, row 22 only 2.
    with pytest.raises(pu.BlockedCellError) as caught:
        gp.plan(name, WALL, centre(5, 5), centre(20, 10), 5, 1)
    assert caught.value.nearest_free == (22, 10)


# A closed square yard around cell (25, 25), walls 20 m tall: no way in at 5 m.
YARD = boxes(
    [30, 25, 10, 0.5, 6, 10], [20, 25, 10, 0.5, 6, 10], [25, 20, 10, 6, 0.5, 10], [25, 30, 10, 6, 0.5, 10]
)


@pytest.mark.parametrize("name", PLANNERS_2D)
def test_every_2d_planner_reports_no_path_into_a_walled_yard(name):
    with pytest.raises(pu.NoPathError):
        gp.plan(name, YARD, centre(5, 5), centre(25, 25), 5, 0.5)


@pytest.mark.parametrize("name", gp.PLANNERS_3D)
def test_3d_planners_climb_over_the_yard_wall(name):
    result = gp.plan(name, YARD, centre(5, 5), centre(25, 25), 5, 0.5)
    assert result.waypoints[:, 2].max() >= 20.5  # wall top 20 m + 0.5 m margin
    assert clearance.legs_too_close(result.waypoints, YARD, 0.5) == []


@pytest.mark.parametrize("name", gp.PLANNERS)
def test_a_start_on_the_goal_is_one_waypoint(name):
    result = gp.plan(name, WALL, centre(5, 5), centre(5, 5), 5, 1)
    assert result.waypoints.tolist() == [[5.5, 5.5, 5.0, 0.0]]
    assert result.length_m == 0.0


# --------------------------------------------------------------------------------------------------------------
# The shared collision check


def flat_plan(name: str, points_ne, altitude_m: float = 5.0) -> pu.Plan:
    points = np.asarray(points_ne, dtype=np.float64)
    waypoints = np.column_stack([points, np.full(len(points), altitude_m), pu.headings_along(points)])
    return pu.Plan(name, waypoints, points, pu.path_length(points), 0.0, 0.0, 0)


def test_checker_flags_the_leg_that_crosses_the_wall_and_passes_the_leg_around_it():
    through = flat_plan("voronoi", [centre(5, 10), centre(35, 10)])
    around = flat_plan("voronoi", [centre(5, 10), centre(17, 32), centre(22, 32), centre(35, 10)])
    assert gp.colliding_legs(through, WALL, 1) == [0]
    assert gp.colliding_legs(around, WALL, 1) == []
    # With a 3 m margin the wall grows to north 16..24 and east 33: cells (17, 32) and (22, 32) are blocked.
    assert gp.colliding_legs(around, WALL, 3) == [0, 1, 2]


def test_checker_rejects_a_2d_waypoint_off_a_cell_centre():
    off_centre = flat_plan("any-angle", [centre(5, 10), (5.9, 20.5)])
    assert gp.colliding_legs(off_centre, WALL, 1) == [0]


def test_the_tests_own_check_flags_the_leg_through_the_wall_and_passes_the_legs_around_it():
    through = flat_plan("voronoi", [centre(5, 10), centre(35, 10)]).waypoints
    around = flat_plan("voronoi", [centre(5, 10), centre(17, 32), centre(22, 32), centre(35, 10)]).waypoints
    assert clearance.legs_too_close(through, WALL, 1) == [0] and clearance.legs_through_footprints(through, WALL) == [0]
    assert clearance.legs_too_close(around, WALL, 1) == []
    # By hand: the middle leg runs 2.5 m east of the wall's east face (east 30); the legs to and from it pass the
    # wall's corners (19, 30) and (21, 30) at 2.52 m and 2.56 m. So a 3 m margin flags all three, 2.5 m none.
    assert clearance.legs_too_close(around, WALL, 3) == [0, 1, 2]
    assert clearance.legs_too_close(around, WALL, 2.5) == []  # exactly 2.5 m away: touching is allowed
    # Above the lid: 20 m wall + 1 m margin; a leg at 21 m passes, at 20.5 m it does not.
    over = np.array([[5.5, 10.5, 21.0], [35.5, 10.5, 21.0]])
    assert clearance.legs_too_close(over, WALL, 1) == []
    assert clearance.legs_too_close(over - [0, 0, 0.5], WALL, 1) == [0]


def test_the_tests_own_check_has_rounded_corners():
    # A leg passing the wall's north-east corner (21, 30) at 1.2 m, at right angles to the diagonal: its nearest
    # point is 0.85 m north and 0.85 m east of the corner, inside a square-grown 1 m margin, outside the round one.
    offset = 1.2 / math.sqrt(2)
    corner = np.array([21.0 + offset, 30.0 + offset])
    direction = np.array([1.0, -1.0]) / math.sqrt(2)
    leg = np.column_stack([np.array([corner - 5 * direction, corner + 5 * direction]), [5.0, 5.0]])
    assert clearance.legs_too_close(leg, WALL, 1.0) == []
    assert clearance.legs_too_close(leg, WALL, 1.3) == [0]


def test_checker_uses_the_grown_boxes_for_3d_planners():
    # Over the 20 m wall: 20 + margin 1 = 21, so a leg at 21 m touches the grown box and is allowed; 20.5 m is not.
    over = np.array([[5.5, 10.5, 21.0, 0.0], [35.5, 10.5, 21.0, 0.0]])
    low = over.copy()
    low[:, 2] = 20.5
    assert gp.colliding_legs(pu.Plan("grid3d", over, over[:, :2], 30.0, 30.0, 0.0, 0), WALL, 1) == []
    assert gp.colliding_legs(pu.Plan("prm", low, low[:, :2], 30.0, 30.0, 0.0, 0), WALL, 1) == [0]


def test_snapped_start_plans_from_the_margin_and_its_lead_in_leg_is_exempt():
    # (18.5, 10.5) is in the 1 m margin south of the wall (rows 18..21 blocked) but not in the wall itself.
    for name in gp.PLANNERS:
        result = gp.plan(name, WALL, (18.5, 10.5), centre(35, 5), 5, 1, snap_start=True)
        np.testing.assert_allclose(result.waypoints[0, :2], (18.5, 10.5))
        assert clearance.legs_too_close(result.waypoints, WALL, 1, first_leg=1) == [], name
        assert clearance.legs_through_footprints(result.waypoints[:2], WALL) == [], name


# --------------------------------------------------------------------------------------------------------------
# Medial axis and Voronoi keep to the middle of the street


# A straight east-west street between two walls: the free rows at 5 m with a 1 m margin are 12..20 (north
# 12..21 m), 9 rows, so the middle row is 16.
STREET = boxes([5.5, 20, 10, 5.5, 20, 10], [30.5, 20, 10, 8.5, 20, 10])
# Two walls 20 m tall: one from the west edge to east 24 at north 11..13, one from east 16 to the east edge at
# north 25..27.
CHICANE = boxes([12, 12, 10, 1, 12, 10], [26, 28, 10, 1, 12, 10])


@pytest.mark.parametrize("name", ["medial-axis", "voronoi"])
def test_roadmap_runs_along_the_middle_of_a_street(name):
    roadmap, _ = gp.structure_for(name, STREET, 5, 1)
    edges = roadmap.structure()["edges"]  # (E, 2, 2) map metres
    away_from_the_map_edges = (edges[:, :, 1] > 5).all(axis=1) & (edges[:, :, 1] < 35).all(axis=1)
    assert away_from_the_map_edges.sum() >= 25
    assert set(np.floor(edges[away_from_the_map_edges, :, 0]).astype(int).ravel().tolist()) == {16}


@pytest.mark.parametrize("name", ["medial-axis", "voronoi"])
def test_roadmap_route_through_a_chicane_is_collision_free_and_uses_the_graph(name):
    result = gp.plan(name, CHICANE, centre(3, 3), centre(37, 37), 5, 1)
    assert len(result.raw_path_ne) > 2
    assert result.extra["start_links"] >= 1 and result.extra["goal_links"] >= 1
    assert clearance.legs_too_close(result.waypoints, CHICANE, 1) == []


def test_start_links_to_the_nearest_node_it_can_see_not_the_nearest_node():
    # A wall at column 10 (rows 0..29); node 0 at (21, 11) is 2.2 m from the start but behind the wall;
    # node 1 at (20, 3) is 7 m away and visible. Node 0 and the goal are linked by node 2 at (35, 10).
    grid = np.zeros((40, 40), bool)
    grid[0:30, 10] = True
    gmap = pu.GridMap(np.empty((0, 6)), grid, 0, 0, 5.0, 1.0, pu.GridPlanner(grid))
    nodes = np.array([[21, 11], [20, 3], [35, 10]])
    roadmap = gp.Roadmap2D.from_edges("voronoi", gmap, nodes, np.array([[1, 2], [2, 0]]), {})
    result = roadmap.plan(centre(20, 10 - 1), centre(20, 20))
    assert result.extra["start_links"] == 1
    assert [21, 11] not in (result.raw_path_ne[:2] - 0.5).astype(int).tolist()
    np.testing.assert_allclose(result.raw_path_ne[1], centre(20, 3))


# --------------------------------------------------------------------------------------------------------------
# Any-angle


def visibility_reference(grid: np.ndarray, start, goal) -> float:
    """The shortest cell-centre polyline whose legs are all supercover-free: Dijkstra over the visibility graph of
    every free cell (line of sight as in planning_utils.line_of_sight, batched), so any route the planners could
    return is at least this long."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    free = np.argwhere(~grid)
    a, b = np.triu_indices(len(free), k=1)
    seen = any_angle.segments_visible(grid, free[a], free[b])
    a, b = a[seen], b[seen]
    length = np.hypot(*(free[a] - free[b]).T)
    graph = csr_matrix((length, (a, b)), shape=(len(free), len(free)))
    index = {tuple(c): k for k, c in enumerate(free.tolist())}
    return float(dijkstra(graph, directed=False, indices=index[tuple(start)])[index[tuple(goal)]])


def test_any_angle_flies_straight_across_open_ground():
    result = gp.plan("any-angle", WALL, centre(30, 2), centre(37, 38), 5, 1)
    assert result.waypoints[:, :2].tolist() == [list(centre(30, 2)), list(centre(37, 38))]
    assert result.length_m == pytest.approx(math.hypot(7, 36))


def test_any_angle_beats_the_pruned_grid_path_and_matches_the_visibility_reference():
    # Through the chicane from the south-east to the north-west: the 8-connected route's 45-degree steps leave
    # the pruned path bending at the wrong cell; any-angle turns where the visibility reference does.
    start, goal = (5, 35), (35, 5)
    grid_plan = gp.plan("grid", CHICANE, centre(*start), centre(*goal), 5, 1)
    any_plan = gp.plan("any-angle", CHICANE, centre(*start), centre(*goal), 5, 1)
    reference = visibility_reference(pu.GridMap.build(CHICANE, 5, 1).grid, start, goal)
    assert any_plan.length_m < grid_plan.length_m - 0.5
    assert reference - 1e-9 <= any_plan.length_m <= 1.02 * reference


# --------------------------------------------------------------------------------------------------------------
# Every planner on random maps


def random_rows(draw_float, draw_height, count: int) -> list[list[float]]:
    rows = []
    for _ in range(count):
        half_n, half_e = draw_float(0.5, 6), draw_float(0.5, 6)
        north, east = draw_float(half_n, 40 - half_n), draw_float(half_e, 40 - half_e)
        height = draw_height()
        rows.append([north, east, height / 2, half_n, half_e, height / 2])
    return rows


@st.composite
def city(draw):
    """A 40 x 40 m map of up to 14 random boxes, a margin, and free start and goal cells at 5 m."""
    rows = random_rows(lambda lo, hi: draw(st.floats(lo, hi)), lambda: draw(st.sampled_from([3.0, 8.0, 30.0])),
                       draw(st.integers(0, 14)))
    obstacles = boxes(*rows)
    safety = draw(st.sampled_from([0.0, 1.0, 2.0]))
    grid, north_offset, east_offset = pu.create_grid(obstacles, 5.0, safety)
    assert (north_offset, east_offset, *grid.shape) == (0, 0, 40, 40)
    free = [tuple(cell) for cell in np.argwhere(~grid).tolist()]
    assume(free)  # a map with no free cell at 5 m has nothing to plan (hypothesis reports if that is common)
    return obstacles, safety, grid, draw(st.sampled_from(free)), draw(st.sampled_from(free))


def grid_connects(grid: np.ndarray, start, goal) -> bool:
    """Whether start and goal are in one 4-connected component of the free cells (scipy's flood fill). The grid
    planner's 8-connected moves never cut a blocked corner, so this is exactly the pairs it can join."""
    labels, _ = ndimage.label(~grid)
    return labels[tuple(start)] == labels[tuple(goal)]


#: The skeleton roadmaps, which may miss a route the grid has (the bound is tested below); every other planner
#: is complete: grid and any-angle on the grid, grid3d and prm (which falls back to grid3d) over every altitude.
ROADMAPS = ("medial-axis", "voronoi")


@pytest.mark.parametrize("name", gp.PLANNERS)
@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(example=city())
def test_every_planner_flies_collision_free_legs_on_random_maps(name, example):
    obstacles, safety, grid, start, goal = example
    connected = grid_connects(grid, start, goal)
    try:
        result = gp.plan(name, obstacles, centre(*start), centre(*goal), 5.0, safety, seed=1)
    except pu.NoPathError:
        if name in ROADMAPS and connected:
            event("roadmap miss")
            return
        # Only a 2D planner may find no path, and only where the grid does not join start and goal (grid3d and
        # prm can always climb over).
        assert name not in gp.PLANNERS_3D and not connected, f"{name} found no path where one exists"
        event("no path")
        return
    event("planned")
    if name not in gp.PLANNERS_3D:
        assert connected, f"{name} flew at 5 m between cells the free space does not join"
    assert clearance.legs_too_close(result.waypoints, obstacles, safety) == []
    np.testing.assert_allclose(result.waypoints[0, :3], [*centre(*start), 5.0])
    np.testing.assert_allclose(result.waypoints[-1, :3], [*centre(*goal), 5.0])
    assert result.length_m >= math.dist(start, goal) - 1e-9
    assert (np.diff(result.waypoints[:, :3], axis=0) != 0).any(axis=1).all()  # no repeated waypoint
    assert result.length_m <= result.cost_m + 1e-9  # pruning never lengthens a route; climbing costs >= 1 per m


#: The skeleton roadmaps' accepted miss rate on grid-connected pairs of random maps (measured on the pairs below:
#: medial-axis 0 and Voronoi 1 of 294; a roadmap that failed far more often, or always, fails here). The
#: grid planners are complete: they miss none.
MISS_BOUND = {"medial-axis": 0.03, "voronoi": 0.03, "grid": 0.0, "any-angle": 0.0}


@pytest.mark.parametrize("name", PLANNERS_2D)
def test_2d_planners_find_what_the_grid_connects_within_their_bound_and_nothing_else(name):
    rng = np.random.default_rng(7)
    connected = disconnected = missed = 0
    for _ in range(100):
        rows = random_rows(lambda lo, hi: float(rng.uniform(lo, hi)), lambda: float(rng.choice([3.0, 8.0, 30.0])),
                           int(rng.integers(0, 15)))
        obstacles, safety = boxes(*rows), float(rng.choice([0.0, 1.0, 2.0]))
        grid = pu.create_grid(obstacles, 5.0, safety)[0]
        free = np.argwhere(~grid)
        for _ in range(3 if len(free) else 0):
            start, goal = (tuple(free[k]) for k in rng.integers(0, len(free), 2))
            if not grid_connects(grid, start, goal):
                disconnected += 1
                with pytest.raises(pu.NoPathError):
                    gp.plan(name, obstacles, centre(*start), centre(*goal), 5.0, safety)
                continue
            connected += 1
            try:
                result = gp.plan(name, obstacles, centre(*start), centre(*goal), 5.0, safety)
            except pu.NoPathError:
                missed += 1
                continue
            assert clearance.legs_too_close(result.waypoints, obstacles, safety) == []
    assert connected >= 200 and disconnected >= 5  # both kinds of pair were tried
    assert missed <= MISS_BOUND[name] * connected, f"{name} missed {missed} of {connected} grid-connected pairs"


ALLEY = np.array([
    # Two 20 m tall walls, 2 m thick, with a 4 m alley between them (east 1..5); posts mark the map's corners.
    [50.0, 0.0, 10.0, 50.0, 1.0, 10.0],
    [50.0, 6.0, 10.0, 50.0, 1.0, 10.0],
    [-10.0, -30.0, 0.5, 0.5, 0.5, 0.5],
    [110.0, 40.0, 0.5, 0.5, 0.5, 0.5],
])


@pytest.mark.parametrize("name", gp.PLANNERS)
def test_a_snapped_start_never_leads_out_through_a_building(name):
    # A start in the alley is inside the 5 m margin of both walls. The nearest free cells by distance lie
    # beyond a wall; the way out must go along the alley instead, and no leg may touch a wall's footprint.
    plan = gp.plan(name, ALLEY, (40.3, 3.3), (30.3, 30.3), 5.0, 5.0, snap_start=True)
    assert clearance.legs_through_footprints(plan.waypoints, ALLEY) == [], "a leg passes through a wall"
    assert clearance.legs_too_close(plan.waypoints, ALLEY, 5.0, first_leg=1) == []
