"""grid3d_planning (height map, 3D leg checks, the grid3d planner) and sampling_planning (the PRM).

Maps are 40 x 40 m, fixed by two low posts at the corners, so cell (i, j) has its centre at (i + 0.5, j + 0.5).
Routes are judged by the tests' own collision check (tests/clearance.py), not the planners' ``colliding_legs``.
"""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import planning_utils as pu
from skyroute.planning import graphs as gp
from skyroute.planning import grid3d as g3
from skyroute.planning import sampling as sp
from tests import clearance

POSTS_40 = [[0.25, 0.25, 0.1, 0.25, 0.25, 0.1], [39.75, 39.75, 0.1, 0.25, 0.25, 0.1]]


def boxes(*rows) -> np.ndarray:
    return np.array([*POSTS_40, *rows], dtype=np.float64)


def centre(i: int, j: int) -> tuple[float, float]:
    return i + 0.5, j + 0.5


@st.composite
def random_boxes(draw, max_count=10, size=40):
    rows = []
    for _ in range(draw(st.integers(1, max_count))):
        half_n, half_e = draw(st.floats(0.5, 5)), draw(st.floats(0.5, 5))
        north, east = draw(st.floats(half_n, size - half_n)), draw(st.floats(half_e, size - half_e))
        height = draw(st.floats(1, 30))
        rows.append([north, east, height / 2, half_n, half_e, height / 2])
    posts = [[0.25, 0.25, 0.1, 0.25, 0.25, 0.1], [size - 0.25, size - 0.25, 0.1, 0.25, 0.25, 0.1]]
    return np.array([*posts, *rows])


# --------------------------------------------------------------------------------------------------------------
# Height map and leg checks


@settings(max_examples=30, deadline=None, derandomize=True)
@given(obstacles=random_boxes(), safety_m=st.sampled_from([0.0, 1.0, 2.5]))
def test_height_map_blocks_exactly_the_cells_create_grid_blocks_at_every_altitude(obstacles, safety_m):
    floor, north_offset, east_offset = g3.floor_map(obstacles, safety_m)
    for altitude in (0.0, 3.0, 5.0, 10.5, 20.0, 40.0):
        grid, grid_north, grid_east = pu.create_grid(obstacles, altitude, safety_m)
        assert (grid_north, grid_east) == (north_offset, east_offset)
        np.testing.assert_array_equal(floor > altitude, grid)


def test_a_leg_touching_the_rounded_margin_is_clear_and_one_cutting_its_corner_is_not():
    # A 2 x 2 m box, 10 m tall, with a 5 m margin: its grown prism is the footprint plus 5 m, corners rounded,
    # up to 15 m. The legs run in direction (16, 12) north/east past its south-east corner (north -1, east 1).
    box = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 5.0]])
    along_the_face = np.array([[-10.0, 6.0, 5.0], [10.0, 6.0, 5.0]])  # 5 m east of the east face
    # Nearest the corner at its middle, (-4, 5): offsets (3, 4) from the corner, exactly 5 m.
    tangent_to_the_corner = np.array([[-12.0, -1.0, 5.0], [4.0, 11.0, 5.0]])
    # Nearest the corner at (-3.16, 3.88): 3.6 m from it.
    across_the_corner = np.array([[-11.0, -2.0, 5.0], [5.0, 10.0, 5.0]])
    # Through (-4.6, 5.8), 6 m from the corner: inside the square grown box (|n|, |e| <= 6), outside the rounded one.
    round_the_corner = np.array([[-12.6, -0.2, 5.0], [3.4, 11.8, 5.0]])
    over_the_top = np.array([[-10.0, 0.0, 15.0], [10.0, 0.0, 15.0]])
    just_under_the_lid = np.array([[-10.0, 0.0, 14.9], [10.0, 0.0, 14.9]])
    assert g3.legs_clear_of_boxes(along_the_face, box, 5.0).tolist() == [True]
    assert g3.legs_clear_of_boxes(tangent_to_the_corner, box, 5.0).tolist() == [True]
    assert g3.legs_clear_of_boxes(across_the_corner, box, 5.0).tolist() == [False]
    assert g3.legs_clear_of_boxes(round_the_corner, box, 5.0).tolist() == [True]
    assert g3.legs_clear_of_boxes(over_the_top, box, 5.0).tolist() == [True]
    assert g3.legs_clear_of_boxes(just_under_the_lid, box, 5.0).tolist() == [False]


def test_with_no_margin_only_the_box_interior_collides():
    box = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 5.0]])
    along_the_face = np.array([[-5.0, 1.0, 5.0], [5.0, 1.0, 5.0]])
    through = np.array([[-5.0, 0.5, 5.0], [5.0, 0.5, 5.0]])
    on_the_roof = np.array([[-5.0, 0.0, 10.0], [5.0, 0.0, 10.0]])
    assert g3.legs_clear_of_boxes(np.vstack([along_the_face]), box, 0.0).tolist() == [True]
    assert g3.legs_clear_of_boxes(through, box, 0.0).tolist() == [False]
    assert g3.legs_clear_of_boxes(on_the_roof, box, 0.0).tolist() == [True]


def exact_distance_to_box(point_ne: np.ndarray, box: np.ndarray) -> float:
    """Horizontal distance from a point to a box's footprint, written out: zero inside."""
    gap_n = max(box[0] - box[3] - point_ne[0], point_ne[0] - box[0] - box[3], 0.0)
    gap_e = max(box[1] - box[4] - point_ne[1], point_ne[1] - box[1] - box[4], 0.0)
    return math.hypot(gap_n, gap_e)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(obstacles=random_boxes(max_count=4), safety_m=st.sampled_from([0.5, 2.0, 5.0]),
       ends=st.lists(st.tuples(st.floats(-5, 45), st.floats(-5, 45), st.floats(0, 35)), min_size=2, max_size=2))
def test_the_3d_rule_agrees_with_dense_samples_of_the_leg(obstacles, safety_m, ends):
    # Sample the leg every 1 cm: a sample below a lid and closer than the margin to that box's footprint is a
    # collision. The exact check must flag every such leg, and pass every leg whose samples all keep 2 cm more.
    a, b = (np.array(e) for e in ends)
    t = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b - a) / 0.01)))
    samples = a + t[:, None] * (b - a)
    slack = []
    for box in obstacles:
        below = samples[:, 2] < box[2] + box[5] + safety_m
        for p in samples[below]:
            slack.append(exact_distance_to_box(p[:2], box) - safety_m)
    clear = g3.legs_clear_of_boxes(np.array([a, b]), obstacles, safety_m)[0]
    if slack and min(slack) < -0.02:
        assert not clear
    if not slack or min(slack) > 0.02:
        assert clear


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    obstacles=random_boxes(),
    safety_m=st.sampled_from([0.0, 1.0, 2.5]),
    ends=st.lists(st.tuples(st.integers(0, 39), st.integers(0, 39), st.floats(0, 35)), min_size=2, max_size=2),
)
def test_a_leg_the_height_map_accepts_clears_every_grown_box(obstacles, safety_m, ends):
    floor, north_offset, east_offset = g3.floor_map(obstacles, safety_m)
    a, b = (np.array(e, dtype=np.float64) for e in ends)
    if g3.legs_free(floor, a[None, :], b[None, :])[0]:
        points = np.array([a, b]) + (north_offset + 0.5, east_offset + 0.5, 0.0)
        assert g3.legs_clear_of_boxes(points, obstacles, safety_m).tolist() == [True]


def test_a_climbing_leg_may_pass_a_block_it_has_risen_above_by_then():
    # A 10 m block at north 19..21, east 4..6; with a 1 m margin its cells (rows 18..21, columns 3..6) are free
    # from 11 m. A leg up column 5 from the centre of row 0 (north 0.5) enters row 18 at north 18, i.e. 17.5 / 20
    # of the way to row 20's centre: at 5 + 7 * 0.875 = 11.125 m when climbing to 12 m (clear), at
    # 5 + 6.5 * 0.875 = 10.69 m when climbing to 11.5 m (inside the grown box).
    block = boxes([20.0, 5.0, 5.0, 1.0, 1.0, 5.0])
    floor, north_offset, east_offset = g3.floor_map(block, 1.0)
    for top, expected in ((12.0, True), (11.5, False)):
        a, b = np.array([[0.0, 5.0, 5.0]]), np.array([[20.0, 5.0, top]])
        assert g3.legs_free(floor, a, b).tolist() == [expected]
        points = np.vstack([a, b]) + (north_offset + 0.5, east_offset + 0.5, 0.0)
        assert g3.legs_clear_of_boxes(points, block, 1.0).tolist() == [expected]


def test_vertical_legs_keep_the_heading_of_the_horizontal_leg():
    points = np.array([[0, 0, 5], [0, 0, 15], [0, 10, 15], [0, 10, 5]], dtype=np.float64)
    np.testing.assert_allclose(g3.headings_3d(points), [math.pi / 2] * 4)


# --------------------------------------------------------------------------------------------------------------
# grid3d


# A wall 10 m tall across north 19..21, from the west edge to east 34; with a 1 m margin it blocks rows 18..21,
# columns 0..34 below 11 m, leaving a gap in columns 35..39.
LOW_WALL = boxes([20.0, 17.0, 5.0, 1.0, 17.0, 5.0])


def test_grid3d_climbs_over_a_low_wall_when_that_is_cheaper_than_going_round():
    # Straight north 30 m at column 5, climbing two 5 m levels (5 -> 15 m, above the wall's 11 m) at 1.5 per
    # metre and descending them at 1 per metre: 30 + 15 + 10 = 55. Round the wall's east end is over 60 m.
    flat = gp.plan("grid", LOW_WALL, centre(5, 5), centre(35, 5), 5, 1)
    over = gp.plan("grid3d", LOW_WALL, centre(5, 5), centre(35, 5), 5, 1)
    assert flat.length_m > 60
    assert over.cost_m == pytest.approx(55.0)
    assert over.waypoints[:, 2].max() == 15.0
    assert over.length_m < flat.length_m
    assert clearance.legs_too_close(over.waypoints, LOW_WALL, 1) == []


def test_grid3d_goes_round_a_tall_wall_at_the_grid_planners_optimal_cost():
    tall = boxes([20.0, 17.0, 50.0, 1.0, 17.0, 50.0])  # climbing to 101 m would cost 240; round the end ~65
    grid_cost = pu.GridMap.build(tall, 5, 1).planner.plan((5, 5), (35, 5)).cost
    around = gp.plan("grid3d", tall, centre(5, 5), centre(35, 5), 5, 1)
    assert around.cost_m == pytest.approx(grid_cost)
    assert set(around.waypoints[:, 2].tolist()) == {5.0}


def test_grid3d_lands_a_goal_on_a_rooftop_above_roof_plus_margin():
    # Roof of a 10 x 10 m block, 20 m tall, centred on (25, 25); with a 1 m margin its cells are free from 21 m.
    # Levels 5 -> 21 m in ceil(16 / 5) = 4 steps of 4 m.
    block = boxes([25.0, 25.0, 10.0, 5.0, 5.0, 10.0])
    result = gp.plan("grid3d", block, centre(5, 5), centre(25, 25), 5, 1, goal_alt_m=21)
    np.testing.assert_allclose(result.waypoints[-1, :3], [25.5, 25.5, 21.0])
    assert result.extra["level_step_m"] == 4.0
    assert clearance.legs_too_close(result.waypoints, block, 1) == []
    with pytest.raises(pu.BlockedCellError):
        gp.plan("grid3d", block, centre(5, 5), centre(25, 25), 5, 1, goal_alt_m=20)


def reference_cost_3d(floor, levels, start, goal, climb, descent) -> float:
    """Dijkstra (networkx) over the voxel graph, built here from the documented move rules."""
    n, m = floor.shape
    graph = nx.DiGraph()
    for k, z in enumerate(levels):
        for i in range(n):
            for j in range(m):
                if floor[i, j] > z:
                    continue
                for di in (-1, 0, 1):
                    for dj in (-1, 0, 1):
                        wi, wj = i + di, j + dj
                        if (di, dj) == (0, 0) or not (0 <= wi < n and 0 <= wj < m) or floor[wi, wj] > z:
                            continue
                        if di and dj and (floor[wi, j] > z or floor[i, wj] > z):
                            continue
                        graph.add_edge((i, j, k), (wi, wj, k), weight=math.hypot(di, dj))
                if k + 1 < len(levels) and floor[i, j] <= levels[k + 1]:
                    graph.add_edge((i, j, k), (i, j, k + 1), weight=(levels[k + 1] - z) * climb)
                    graph.add_edge((i, j, k + 1), (i, j, k), weight=(levels[k + 1] - z) * descent)
    return nx.dijkstra_path_length(graph, start, goal)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(obstacles=random_boxes(max_count=6, size=16), goal_alt=st.sampled_from([5.0, 12.0]), data=st.data())
def test_grid3d_cost_is_optimal_against_a_dijkstra_reference(obstacles, goal_alt, data):
    planner = g3.Grid3DPlanner.build(obstacles, 5.0, 1.0)
    free_low, free_goal = np.argwhere(planner.floor <= 5.0), np.argwhere(planner.floor <= goal_alt)
    if not len(free_low) or not len(free_goal):
        return
    start = tuple(free_low[data.draw(st.integers(0, len(free_low) - 1))])
    goal = tuple(free_goal[data.draw(st.integers(0, len(free_goal) - 1))])
    result = planner.plan(centre(*start), centre(*goal), goal_alt_m=goal_alt)
    levels = planner.levels_for(goal_alt)
    k_goal = int(np.argmin(np.abs(levels - goal_alt)))
    expected = reference_cost_3d(planner.floor, levels, (*start, 0), (*goal, k_goal), 1.5, 1.0)
    assert result.cost_m == pytest.approx(expected, abs=1e-9)


# --------------------------------------------------------------------------------------------------------------
# PRM


CHICANE = boxes([12, 12, 10, 1, 12, 10], [26, 28, 10, 1, 12, 10])


def test_prm_is_reproducible_for_a_seed_and_differs_across_seeds():
    a = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=3, n_samples=200)
    b = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=3, n_samples=200)
    c = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=4, n_samples=200)
    np.testing.assert_array_equal(a.nodes, b.nodes)
    assert not np.array_equal(a.nodes, c.nodes)
    np.testing.assert_array_equal(
        a.plan(centre(3, 3), centre(37, 37)).waypoints, b.plan(centre(3, 3), centre(37, 37)).waypoints
    )


def test_prm_nodes_are_free_at_their_altitude_within_the_band_and_every_edge_is_clear():
    roadmap = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=0, n_samples=300, altitude_span_m=20)
    nodes = roadmap.nodes
    assert len(nodes) == 300
    assert (nodes[:, 2] >= 5).all() and (nodes[:, 2] <= 25).all()
    assert (roadmap.floor[nodes[:, 0].astype(int), nodes[:, 1].astype(int)] <= nodes[:, 2]).all()
    edges = roadmap.edges
    assert len(edges) > 300
    offset = (roadmap.north_offset + 0.5, roadmap.east_offset + 0.5, 0.0)
    for u, v in edges[:: max(1, len(edges) // 100)]:
        assert clearance.legs_too_close(np.array([nodes[u], nodes[v]]) + offset, CHICANE, 1) == []


def test_prm_reaches_a_rooftop_above_its_sampled_band_by_a_vertical_and_a_level_leg():
    block = boxes([25.0, 25.0, 10.0, 5.0, 5.0, 10.0])  # roof at 20 m, free from 21 m with a 1 m margin
    roadmap = sp.ProbabilisticRoadmap.build(block, 5, 1, seed=0, n_samples=300, altitude_span_m=0)
    assert set(roadmap.nodes[:, 2].tolist()) == {5.0}
    result = roadmap.plan(centre(5, 5), centre(25, 25), goal_alt_m=21)
    np.testing.assert_allclose(result.waypoints[-1, :3], [25.5, 25.5, 21.0])
    assert clearance.legs_too_close(result.waypoints, block, 1.0) == []


def test_prm_with_too_few_samples_misses_the_route_and_says_what_to_try():
    roadmap = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=0, n_samples=2, altitude_span_m=0)
    queries = [(centre(3, 3), centre(37, 37))]
    assert sp.connection_rate(roadmap, queries) == 0.0
    with pytest.raises(sp.RoadmapNoPathError, match="try another seed or more samples"):
        roadmap.plan(*queries[0], fallback=False)


def test_prm_falls_back_to_the_complete_search_when_its_roadmap_misses():
    roadmap = sp.ProbabilisticRoadmap.build(CHICANE, 5, 1, seed=0, n_samples=2, altitude_span_m=0)
    result = roadmap.plan(centre(3, 3), centre(37, 37))
    assert result.planner == "prm" and result.extra["fallback"] == "grid3d"
    np.testing.assert_allclose(result.waypoints[[0, -1], :3], [[3.5, 3.5, 5.0], [37.5, 37.5, 5.0]])
    assert clearance.legs_too_close(result.waypoints, CHICANE, 1) == []
    direct = gp.plan("grid3d", CHICANE, centre(3, 3), centre(37, 37), 5, 1)
    assert result.cost_m == pytest.approx(direct.cost_m)
