"""The live occupancy layer and the replanner, fed scans that the SIM's sensor model computes from true boxes (the
client's layer and the sim's sensor are separate code; these tests check they agree on what a wall is)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.sensors import sector_minima
from skyroute.planning.cspace import create_grid
from skyroute.planning.grid import GridMap
from skyroute.planning.livemap import LiveMap
from skyroute.planning.pruning import line_of_sight
from skyroute.planning.replan import GoalBlocked, GoalUnreachable, Replanner

ALT, SAFETY = 5.0, 3.0
#: Two long blocks with a 24 m north-south street between them (east -12..12), posts fixing a 200 m extent.
STALE = np.array([[0.0, 42.0, 15.0, 90.0, 30.0, 15.0], [0.0, -42.0, 15.0, 90.0, 30.0, 15.0],
                  [-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
#: The truth: a wall across the street at north 20..22, and a side street open at north -30..-10 east of it.
WALL = np.array([[21.0, 0.0, 15.0, 1.0, 13.0, 15.0]])


def _live(obstacles=STALE, safety_m=SAFETY, **kwargs) -> tuple[LiveMap, GridMap]:
    gm = GridMap.build(obstacles, ALT, safety_m)
    footprint = create_grid(obstacles, ALT, 0.0)[0]
    return LiveMap.for_grid_map(gm, footprint, **kwargs), gm


def _scan(truth: np.ndarray, p, sectors: int, heading_rad: float = 0.0, rng=None, noise_m=0.0, dropout=0.0):
    """What the sim's sensor reports at ``p``: (bearings, half width, distances) in the client's terms."""
    lo, hi = truth[:, :3] - truth[:, 3:], truth[:, :3] + truth[:, 3:]
    crossing = (lo[:, 2] <= ALT) & (ALT <= hi[:, 2])
    first = 0.0 if sectors == 72 else heading_rad
    d = sector_minima(lo[crossing, :2], hi[crossing, :2], p[0], p[1], sectors, first, 30.0)
    if rng is not None:
        finite = np.isfinite(d)
        d[finite] = np.clip(d[finite] + rng.normal(0.0, noise_m, finite.sum()), 0.2, 30.0)
        d[rng.random(sectors) < dropout] = np.nan
    width = 2 * math.pi / sectors
    return (first + width * np.arange(sectors)) % (2 * math.pi), width / 2, d


def _fly_north(live: LiveMap, truth: np.ndarray, sectors: int, until_north_m: float, **noise):
    for north in np.arange(-80.0, until_north_m, 1.0):
        p = (north, 0.5)
        bearings, half, d = _scan(truth, p, sectors, **noise)
        if sectors == 72:
            live.add_scan(*p, bearings, half, d, 30.0)
        else:  # ArduPilot: one message per sector
            for b, v in zip(bearings, d):
                live.add_scan(*p, np.array([b]), half, np.array([v]), 30.0)


def _distance_to_boxes(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    lo, hi = boxes[:, :2] - boxes[:, 3:5], boxes[:, :2] + boxes[:, 3:5]
    gap = np.maximum(np.maximum(lo[None] - points[:, None], points[:, None] - hi[None]), 0.0)
    return np.hypot(gap[..., 0], gap[..., 1]).min(axis=1)


@pytest.mark.parametrize("sectors", [72, 8])
def test_the_map_explains_its_own_buildings_so_an_unchanged_street_adds_no_obstacle(sectors):
    live, _ = _live()
    _fly_north(live, STALE, sectors, 60.0)
    assert live.hits.sum() == 0 and live.scans > 0
    assert live.known.sum() > 500  # the street ahead and behind was seen free


@pytest.mark.parametrize("sectors", [72, 8])
def test_a_new_wall_is_seen_on_the_wall_and_blocks_the_street(sectors):
    live, gm = _live()
    truth = np.vstack([STALE, WALL])
    _fly_north(live, truth, sectors, 0.0)  # up to 20 m short of the wall
    hits = live.hit_cells_ne()
    assert len(hits) > 5
    assert _distance_to_boxes(hits, WALL).max() <= 1.5  # every hit cell is at the wall
    # The street is cut: no path north through it on the live grid (the map's grid still has one).
    assert not line_of_sight(live.grid, live.cell_of(0.5, 0.5), live.cell_of(40.5, 0.5))
    assert line_of_sight(gm.grid, gm.cell_of(0.5, 0.5), gm.cell_of(40.5, 0.5))


def _fly_north_believing(live: LiveMap, truth: np.ndarray, sectors: int, until_north_m: float, error_ne,
                         position_error_m: float) -> None:
    """As :func:`_fly_north`, with the position estimate ``error_ne`` off the truth: the scans are measured at the
    true position and placed at the estimate (a GPS drift, slow against a scan)."""
    for north in np.arange(-80.0, until_north_m, 1.0):
        true_p = (north, 0.5)
        bearings, half, d = _scan(truth, true_p, sectors)
        p = (true_p[0] + error_ne[0], true_p[1] + error_ne[1])
        if sectors == 72:
            live.add_scan(*p, bearings, half, d, 30.0, 0.0, position_error_m)
        else:
            for b, v in zip(bearings, d):
                live.add_scan(*p, np.array([b]), half, np.array([v]), 30.0, 0.0, position_error_m)


@pytest.mark.parametrize("sectors", [72, 8])
def test_a_position_estimate_off_by_its_stated_error_reads_the_maps_buildings_as_the_maps(sectors):
    off = (1.5, 2.0)  # 2.5 m: within 3.0 m, a 1 m receiver accuracy's (a reading's arc adds up to a metre)
    drifted, _ = _live(safety_m=5.0)
    _fly_north_believing(drifted, STALE, sectors, 60.0, off, 0.0)
    assert drifted.hits.sum() > 0  # told nothing of the error: the street's own walls become new obstacles
    live, _ = _live(safety_m=5.0)
    _fly_north_believing(live, STALE, sectors, 60.0, off, 3.0)
    assert live.hits.sum() == 0 and live.known.sum() > 500
    # The new wall is still found, where the estimate puts it: 20 m short of it with 5 degree sectors; 14 m short
    # with 45 degree ones, whose wedge, placed 2 m nearer the street's east block, has the map predict that block
    # 25 m off, so the wall (21 m) takes the tolerance off that to count as new.
    walled, _ = _live(safety_m=5.0)
    _fly_north_believing(walled, np.vstack([STALE, WALL]), sectors, {72: 0.0, 8: 6.0}[sectors], off, 3.0)
    hits = walled.hit_cells_ne()
    assert len(hits) > 5 and _distance_to_boxes(hits - off, WALL).max() <= 2.0
    assert not line_of_sight(walled.grid, walled.cell_of(0.5, 0.5), walled.cell_of(40.5, 0.5))


def test_however_poor_the_stated_accuracy_a_new_obstacle_beyond_70_percent_of_the_margin_is_found():
    pole = np.array([[10.5, 7.5, 15.0, 0.5, 0.5, 15.0]])  # 4 m from the street's east block, 4.5 m off its margin
    live, _ = _live(safety_m=5.0)
    _fly_north_believing(live, np.vstack([STALE, pole]), 72, 0.0, (0.0, 0.0), 10.0)  # "10 m": taken as 3.5 m
    hits = live.hit_cells_ne()
    assert len(hits) > 0 and _distance_to_boxes(hits, pole).max() <= 1.5


def test_noise_and_dropout_still_find_the_wall_with_few_stray_hits():
    live, _ = _live()
    truth = np.vstack([STALE, WALL])
    _fly_north(live, truth, 72, 0.0, rng=np.random.default_rng(7), noise_m=0.3, dropout=0.1)
    hits = live.hit_cells_ne()
    near_wall = _distance_to_boxes(hits, WALL) <= 1.5
    assert near_wall.sum() > 5
    assert (~near_wall).sum() <= 0.05 * len(hits) + 2


def test_observed_obstacles_are_inflated_by_the_maps_euclidean_rule():
    live, _ = _live(confirm_hits=1)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    d = np.full(72, np.inf)
    d[9] = 10.0  # one sector due east: a hit 10 m east of (0.5, 0.5)... inside the street
    live.add_scan(-50.5, 0.5, bearings, math.radians(2.5), d, 30.0)
    hit_cells = np.argwhere(live.hits)
    assert len(hit_cells) >= 1
    # Brute force: a cell is blocked iff its square comes closer than the margin to some hit cell's square.
    n, m = live.shape
    ii, jj = np.mgrid[0:n, 0:m]
    expect = np.zeros((n, m), bool)
    for i, j in hit_cells:
        gap_n = np.maximum(np.maximum(i - (ii + 1), ii - (i + 1)), 0)
        gap_e = np.maximum(np.maximum(j - (jj + 1), jj - (j + 1)), 0)
        expect |= np.hypot(gap_n, gap_e) < SAFETY
        expect[i, j] = True
    assert np.array_equal(live.inflated, expect)
    assert np.array_equal(live.grid, live.base | expect)


def test_a_narrower_margin_reinflates_every_observed_obstacle_by_the_same_rule():
    live, _ = _live(confirm_hits=1)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    d = np.full(72, np.inf)
    d[[0, 9, 40]] = 10.0, 12.0, 8.0
    live.add_scan(-50.5, 0.5, bearings, math.radians(2.5), d, 30.0)
    full = live.grid.copy()
    hit_cells = np.argwhere(live.hits)
    n, m = live.shape
    ii, jj = np.mgrid[0:n, 0:m]
    assert live.set_margin(2.0)
    expect = live.hits.copy()
    for i, j in hit_cells:
        gap_n = np.maximum(np.maximum(i - (ii + 1), ii - (i + 1)), 0)
        gap_e = np.maximum(np.maximum(j - (jj + 1), jj - (j + 1)), 0)
        expect |= np.hypot(gap_n, gap_e) < 2.0
    assert np.array_equal(live.inflated, expect)
    assert np.array_equal(live.grid, live.base | expect)
    assert live.set_margin(SAFETY) and np.array_equal(live.grid, full)
    assert not live.set_margin(SAFETY)  # unchanged
    for bad in (SAFETY + 0.5, -1.0):
        with pytest.raises(ValueError, match="margin"):
            live.set_margin(bad)


#: Two blocks reaching the map's north and south edges: the street between them (east -12..12) is the only way.
CLOSED_STREET = np.array([[0.0, 56.0, 15.0, 100.0, 44.0, 15.0], [0.0, -56.0, 15.0, 100.0, 44.0, 15.0],
                          [-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])


def _wall_leaving(gap_m: float) -> np.ndarray:
    """A wall across the street at north 20..22 from its west side, ``gap_m`` short of its east side."""
    west, east = -12.0, 12.0 - gap_m
    return np.array([[21.0, (west + east) / 2, 15.0, 1.0, (east - west) / 2, 15.0]])


def test_a_gap_only_the_whole_cell_margin_closes_is_flown_at_a_narrower_margin():
    # An 11.5 m gap between the wall's end and the block: open at the full 5 m margin on the true boxes; the hit
    # cells at the wall's end (each counted whole, the arc past the end) close it at 5 m and 4.5 m, not at 4 m.
    wall = _wall_leaving(11.5)
    truth = np.vstack([CLOSED_STREET, wall])
    GridMap.build(truth, ALT, 5.0).plan((0.5, 0.5), (60.5, 0.5))  # the truth has a way at the full margin
    live, _ = _live(CLOSED_STREET, safety_m=5.0)
    _fly_north(live, truth, 72, 12.0)
    with pytest.raises(GoalUnreachable):
        Replanner(live, (60.5, 0.5), ALT, min_margin_m=5.0).replan((11.5, 0.5))  # narrowing turned off
    assert live.margin_m == 5.0
    route = Replanner(live, (60.5, 0.5), ALT).replan((11.5, 0.5))
    assert route.margin_m == 4.0 and live.margin_m == 4.0  # kept from now on
    assert tuple(route.waypoints[-1, :2]) == (60.5, 0.5)
    samples = np.vstack([a + np.linspace(0.0, 1.0, 200)[:, None] * (b - a)
                         for a, b in zip(route.waypoints[:-1, :2], route.waypoints[1:, :2])])
    assert _distance_to_boxes(samples, wall).min() >= 4.0
    assert _distance_to_boxes(samples, CLOSED_STREET[:2]).min() >= 5.0  # the map's own buildings keep it whole


def test_a_gap_closed_at_the_narrowest_margin_leaves_the_margin_as_it_was():
    truth = np.vstack([CLOSED_STREET, _wall_leaving(9.0)])
    live, _ = _live(CLOSED_STREET, safety_m=5.0)
    _fly_north(live, truth, 72, 12.0)
    grid = live.grid.copy()
    with pytest.raises(GoalUnreachable) as error:
        Replanner(live, (60.5, 0.5), ALT).replan((11.5, 0.5))
    assert live.margin_m == 5.0 and np.array_equal(live.grid, grid)
    assert error.value.fallback_ne is not None and error.value.fallback_ne[0] < 20.0  # south of the wall


def test_one_stray_reading_is_not_an_obstacle_and_hits_seen_free_again_are_dropped():
    live, _ = _live(confirm_hits=2, free_to_clear=3)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    stray = np.full(72, np.inf)
    stray[0] = 15.0
    live.add_scan(-50.5, 0.5, bearings, math.radians(2.5), stray, 30.0)
    assert live.hits.sum() == 0  # one scan: not confirmed
    live.add_scan(-50.5, 0.5, bearings, math.radians(2.5), stray, 30.0)
    assert live.hits.sum() > 0
    version = live.version
    clear = np.full(72, np.inf)
    for _ in range(6):
        live.add_scan(-50.5, 0.5, bearings, math.radians(2.5), clear, 30.0)
    assert live.hits.sum() == 0 and not live.inflated.any() and live.version > version


def test_a_walled_corridor_leaves_the_goal_unreachable_with_a_fallback_short_of_the_wall():
    corridor = np.array([[0.0, 56.0, 15.0, 100.0, 44.0, 15.0], [0.0, -56.0, 15.0, 100.0, 44.0, 15.0]])
    live, _ = _live(corridor)
    _fly_north(live, np.vstack([corridor, WALL]), 72, 0.0)
    start, goal = (0.5, 0.5), (60.5, 0.5)
    replanner = Replanner(live, goal, ALT)
    block = replanner.check(start, np.array([goal]))
    assert block is not None and block.reason == "margin" and 15.0 <= block.along_m <= 20.0
    with pytest.raises(GoalUnreachable) as info:
        replanner.replan(start)
    fallback = info.value.fallback_ne
    # The nearest reachable free point is in the street just short of the wall's margin.
    assert fallback is not None and 20.0 - SAFETY - 2.0 <= fallback[0] < 20.0 - SAFETY
    assert not live.grid[live.cell_of(*fallback)]


def test_replan_with_a_detour_returns_free_legs_and_starts_where_the_vehicle_is():
    side_street = np.array([[0.0, 42.0, 15.0, 90.0, 30.0, 15.0], [-60.0, -42.0, 15.0, 30.0, 30.0, 15.0],
                            [50.0, -42.0, 15.0, 40.0, 30.0, 15.0], [-99.5, -99.5, 0.5, 0.5, 0.5, 0.5],
                            [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])  # a gap in the west block at north -30..10
    live, _ = _live(side_street)
    _fly_north(live, np.vstack([side_street, WALL]), 72, 0.0)
    replanner = Replanner(live, (60.5, 0.5), ALT)
    route = replanner.replan((0.5, 0.5))
    assert tuple(route.waypoints[0, :2]) == (0.5, 0.5) and tuple(route.waypoints[-1, :2]) == (60.5, 0.5)
    cells = [live.cell_of(*p) for p in route.waypoints[:, :2]]
    assert all(line_of_sight(live.grid, a, b) for a, b in zip(cells[:-1], cells[1:]))
    assert route.plan_ms > 0 and np.all(route.waypoints[:, 2] == ALT)
    assert replanner.check((0.5, 0.5), route.waypoints[1:]) is None


def test_a_goal_inside_an_observed_obstacles_margin_is_blocked():
    live, _ = _live(confirm_hits=1)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    d = np.full(72, np.inf)
    d[0] = 20.0
    live.add_scan(0.5, 0.5, bearings, math.radians(2.5), d, 30.0)
    with pytest.raises(GoalBlocked):
        Replanner(live, (19.5, 0.5), ALT).replan((0.5, 0.5))


def test_a_start_inside_the_margin_leads_out_first():
    live, _ = _live(confirm_hits=1)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    d = np.full(72, np.inf)
    d[0] = 2.0  # 2 m ahead, inside the 3 m margin
    live.add_scan(-40.5, 0.5, bearings, math.radians(2.5), d, 30.0)
    route = Replanner(live, (-70.5, 0.5), ALT).replan((-40.5, 0.5))
    assert route.snapped and not live.grid[live.cell_of(*route.waypoints[1, :2])]


#: Four blocks with 20 m streets between them: corners the sensor grazes from the streets.
BLOCKS = np.array([[n, e, 15.0, 30.0, 30.0, 15.0] for n in (-40.0, 40.0) for e in (-40.0, 40.0)]
                  + [[-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])


def test_building_corners_grazed_by_a_sector_are_the_maps_not_new_obstacles():
    # Near the crossings of the east-west street between the blocks (north -10..10) with the outer streets: every
    # block corner passes through the edge of some 5 degree sector there (a reading the map's cell samples alone
    # did not explain, at (7.5 N, -73 E) for one).
    live, _ = _live(BLOCKS)
    points = [(north, east) for north in np.arange(-9.0, 9.5, 0.5)
              for east in np.concatenate([np.arange(-80.0, -60.0, 0.5), np.arange(60.5, 80.5, 0.5)])]
    for p in points:
        bearings, half, d = _scan(BLOCKS, p, 72)
        live.add_scan(*p, bearings, half, d, 30.0)
    assert live.hit_count.sum() == 0  # not one sector read as a new obstacle


def test_a_vehicle_inside_a_margin_is_not_blocked_by_it_on_the_way_out_but_is_on_the_way_back():
    live, _ = _live(confirm_hits=1)
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    d = np.full(72, np.inf)
    d[0] = 2.0  # an obstacle 2 m north, inside the 3 m margin
    live.add_scan(-40.5, 0.5, bearings, math.radians(2.5), d, 30.0)
    replanner = Replanner(live, (-70.5, 0.5), ALT)
    assert replanner.check((-40.5, 0.5), np.array([[-70.5, 0.5]])) is None  # straight out, south
    back = replanner.check((-40.5, 0.5), np.array([[-50.5, 0.5], [-50.5, 2.5], [-30.5, 2.5]]))
    assert back is not None and back.along_m > 15.0  # re-entering the margin on the way north counts


def test_a_heading_relative_sector_turned_by_the_heading_lag_still_explains_the_maps_building():
    # A 1 m post on the map at bearing 31 degrees, 23 m from the sensor. The 45 degree sector really spans
    # 29..74 degrees (it reads the post); its stated bearing, from a heading lagging a yaw by 12 degrees, spans
    # 41..86, which misses the post: without an allowance for that turn the map cannot explain the reading.
    post = np.array([[20.0, 12.5, 15.0, 0.5, 0.5, 15.0], [-99.5, -99.5, 0.5, 0.5, 0.5, 0.5],
                     [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
    p = (0.5, 0.5)
    lo, hi = post[:, :2] - post[:, 3:5], post[:, :2] + post[:, 3:5]
    true_centre = math.radians(29.0 + 22.5)
    d = sector_minima(lo, hi, p[0], p[1], 8, true_centre, 30.0)[:1]  # the sim's eight 45 degree sectors
    assert np.isfinite(d[0])  # the true sector sees the post
    stated = np.array([true_centre + math.radians(12.0)])
    live, _ = _live(post, confirm_hits=1)
    assert live.add_scan(*p, stated, math.radians(22.5), d, 30.0).unexplained == 1
    live, _ = _live(post, confirm_hits=1)
    update = live.add_scan(*p, stated, math.radians(22.5), d, 30.0, bearing_error_rad=math.radians(15.0))
    assert update.unexplained == 0 and live.hits.sum() == 0


#: One block (north -20..20, east -60..40) between a start south of it and a goal north of it: round its east end
#: is the shorter way (~150 m), round its west end ~185 m. Posts fix a 200 m extent.
ISLAND = np.array([[0.0, -10.0, 15.0, 20.0, 50.0, 15.0], [-99.5, -99.5, 0.5, 0.5, 0.5, 0.5],
                   [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])


def _seen_east_of_the_block(live: LiveMap) -> None:
    """One sector of one scan, from (25.5 N, 75.5 E) looking west: an obstacle 20 m off at east 55.5, 12 m east of
    the short way's leg; every other sector unknown (NaN), so only that wedge is seen."""
    d = np.full(72, np.nan)
    d[54] = 20.0  # bearing 270: west
    live.add_scan(25.5, 75.5, np.radians(np.arange(0.0, 360.0, 5.0)), math.radians(2.5), d, 30.0)


def test_the_stale_map_prior_steers_away_from_unseen_space_near_an_observed_obstacle():
    live, _ = _live(ISLAND, confirm_hits=1)
    _seen_east_of_the_block(live)
    start, goal = (-50.5, 0.5), (50.5, 0.5)
    replanner = Replanner(live, goal, ALT, suspect_weight=3.0, suspect_radius_m=60.0)
    fast = replanner.replan(start)
    assert fast.waypoints[:, 1].max() > 40.0  # the plain search takes the short way, past the observed obstacle
    better = replanner.refine(start, fast.waypoints)
    assert better is not None and better.waypoints[:, 1].min() < -60.0  # the prior: round the far end
    assert better.length_m > fast.length_m
    assert replanner.prior_cost(better.waypoints) < replanner.prior_cost(fast.waypoints)
    cells = [live.cell_of(*p) for p in better.waypoints[:, :2]]
    assert all(line_of_sight(live.grid, a, b) for a, b in zip(cells[:-1], cells[1:]))  # as free as a replan's
    assert tuple(better.waypoints[0, :2]) == start and tuple(better.waypoints[-1, :2]) == goal
    assert replanner.refine(start, better.waypoints) is None  # nothing better than itself


def test_the_prior_costs_unseen_cells_less_the_farther_they_are_from_an_observed_obstacle():
    live, _ = _live(ISLAND, confirm_hits=1)
    _seen_east_of_the_block(live)
    weights = Replanner(live, (50.5, 0.5), ALT, suspect_weight=3.0, suspect_radius_m=60.0).suspect_weights()
    assert live.hits[live.cell_of(25.5, 55.5)]
    # West of the hit, unseen, along its row: 3x beside it, 2x halfway out (30 m, on a 4 m coarse grid), 1x past 60 m.
    beside, halfway, past = (float(weights[live.cell_of(25.5, east)]) for east in (51.5, 25.5, -10.5))
    assert 3.0 >= beside > 2.8 and halfway == pytest.approx(2.0, abs=0.15) and past == 1.0
    row = weights[live.cell_of(25.5, 0.0)[0], live.cell_of(0.0, -4.5)[1]:live.cell_of(0.0, 51.5)[1]]
    assert np.all(np.diff(row) >= 0.0)  # never dearer farther from it


def test_the_prior_keeps_the_short_way_when_it_is_off_seen_or_there_is_nothing_observed():
    start, goal = (-50.5, 0.5), (50.5, 0.5)
    live, _ = _live(ISLAND, confirm_hits=1)
    nothing = Replanner(live, goal, ALT, suspect_weight=3.0, suspect_radius_m=30.0)
    assert nothing.suspect_weights() is None and nothing.refine(start, nothing.replan(start).waypoints) is None
    _seen_east_of_the_block(live)
    off = Replanner(live, goal, ALT, suspect_weight=1.0, suspect_radius_m=30.0)
    assert off.refine(start, off.replan(start).waypoints) is None
    on = Replanner(live, goal, ALT, suspect_weight=3.0, suspect_radius_m=60.0)
    weights = on.suspect_weights()
    hit = live.cell_of(25.5, 55.5)
    assert weights[live.cell_of(-40.5, -70.5)] == 1.0
    assert weights[live.cell_of(25.5, 65.5)] == 1.0  # seen free: no doubt there
    assert live.hits[hit]
    # Seen free all along the short way: the prior has nothing against it.
    live.known[:, live.cell_of(0.0, 38.0)[1]:live.cell_of(0.0, 50.0)[1]] = True
    assert on.refine(start, on.replan(start).waypoints) is None


#: A street north (east -6..7) between two blocks (north -40..60), open ground round them (posts fix a 200 m
#: extent); in the truth a 20 m wall stands across the street's southern approach, 25 m ahead of the start.
STREET = np.vstack([ISLAND[1:], [[10.0, -23.0, 15.0, 50.0, 17.0, 15.0], [10.0, 19.5, 15.0, 50.0, 12.5, 15.0]]])
WALL_BEFORE_THE_STREET = np.vstack([STREET, [[-50.0, 0.0, 15.0, 0.5, 10.0, 15.0]]])


def test_the_prior_keeps_a_detour_off_the_rest_of_the_maps_route_once_the_map_proved_wrong_on_it():
    start, goal = (-75.5, 0.5), (80.5, 0.5)
    live, gm = _live(STREET, confirm_hits=1)
    replanner = Replanner(live, goal, ALT, suspect_weight=1.0, route_weight=3.0, route_radius_m=20.0)
    replanner.suspect_route(gm.plan(start, goal).waypoints)  # up the street
    bearings, half, d = _scan(WALL_BEFORE_THE_STREET, start, 72)
    live.add_scan(*start, bearings, half, d, 30.0)
    assert live.hits.any()
    fast = replanner.replan(start)
    assert np.abs(fast.waypoints[:, 1]).max() < 20.0  # round the wall's end and back into the map's street
    better = replanner.refine(start, fast.waypoints)
    assert better is not None and better.waypoints[:, 1].max() > 32.0  # round the east block instead
    assert replanner.prior_cost(better.waypoints) < replanner.prior_cost(fast.waypoints)
    cells = [live.cell_of(*p) for p in better.waypoints[:, :2]]
    assert all(line_of_sight(live.grid, a, b) for a, b in zip(cells[:-1], cells[1:]))  # as free as a replan's
    # Without the map's route named, or with that half off, nothing argues against the short way.
    unnamed = Replanner(live, goal, ALT, suspect_weight=1.0, route_weight=3.0)
    off = Replanner(live, goal, ALT, suspect_weight=1.0, route_weight=1.0)
    off.suspect_route(gm.plan(start, goal).waypoints)
    for plain in (unnamed, off):
        assert plain.suspect_weights() is None and plain.refine(start, plain.replan(start).waypoints) is None


def test_the_prior_rejects_weights_below_one_and_negative_radii():
    live, _ = _live(ISLAND)
    for bad in ({"suspect_weight": 0.5}, {"suspect_radius_m": -1.0}, {"route_weight": 0.5},
                {"route_radius_m": -1.0}):
        with pytest.raises(ValueError, match="prior's weight must be >= 1 and its radius >= 0"):
            Replanner(live, (50.5, 0.5), ALT, **bad)


def test_a_wall_seen_obliquely_is_placed_on_its_face_not_in_front_of_it():
    # An east-west wall 15 m north of the sensor: its far parts are seen at up to 60 degrees from the normal, where
    # a 5 degree sector's whole arc lies up to ~2.5 m in front of the face (on the sensor's side).
    posts = np.array([[-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
    wall = np.array([[16.0, 0.5, 15.0, 1.0, 60.0, 15.0]])
    live, _ = _live(posts, confirm_hits=1)
    live.add_scan(0.5, 0.5, *_scan(np.vstack([posts, wall]), (0.5, 0.5), 72), 30.0)
    hits = live.hit_cells_ne()
    assert len(hits) > 0 and hits[:, 1].min() < -20.0 and hits[:, 1].max() > 20.0  # seen across +-60 degrees
    # every hit cell's centre within a cell's diagonal of the face (the whole arcs were up to 2.5 m off)
    assert _distance_to_boxes(hits, wall).max() <= 1.0
    # ArduPilot's 45 degree sectors keep the whole arc: which part holds the point is not known
    live8, _ = _live(posts, confirm_hits=1)
    bearings, half, d = _scan(np.vstack([posts, wall]), (0.5, 0.5), 8)
    live8.add_scan(0.5, 0.5, bearings, half, d, 30.0)
    assert _distance_to_boxes(live8.hit_cells_ne(), wall).max() > 5.0


def test_a_face_seen_at_a_grazing_angle_marks_no_cell_in_front_of_it():
    # Seen from beyond a wall's end, almost along its west face (east 7.38): each sector's nearest point is at its
    # edge towards the wall's end, on the face. A quarter arc there lay 0.58 m in front of the face at 26 m, in the
    # cell west of the face's: a one-cell passage beside that face closed (a false "no path" on the offline model).
    posts = np.array([[-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
    wall = np.array([[0.0, 8.38, 15.0, 60.5, 1.0, 15.0]])
    live, _ = _live(posts, confirm_hits=1)
    p = (66.5, 3.92)
    live.add_scan(*p, *_scan(np.vstack([posts, wall]), p, 72), 30.0)
    hits = live.hit_cells_ne()
    assert len(hits) >= 3  # the face is seen in several sectors
    # every hit cell overlaps the wall: none lies west of the face's cell (east 7..8)
    assert hits[:, 1].min() >= 7.5 and _distance_to_boxes(hits, wall).max() <= 0.71


def test_a_walls_corner_is_marked_where_its_face_runs_into_it_not_across_the_corners_sector():
    # South-east of an east-west wall's end (the corner at north 15.3, east 60.5): the corner is the nearest thing
    # in its sector and neither neighbour reads nearer, so the whole arc was marked, past the corner into the free
    # cell beyond the end (east 61..62). The south face recedes through the next two sectors; its line through
    # their edge points, carried on to the corner sector's reading, puts the corner where it is.
    posts = np.array([[-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
    wall = np.array([[16.3, 0.38, 15.0, 1.0, 60.12, 15.0]])
    for p in [(-5.5, 70.5), (-7.5, 66.5), (-2.5, 68.5)]:
        live, _ = _live(posts, confirm_hits=1)
        live.add_scan(*p, *_scan(np.vstack([posts, wall]), p, 72), 30.0)
        hits = live.hit_cells_ne()
        assert [15.5, 60.5] in hits.tolist()  # the corner's own cell
        assert _distance_to_boxes(hits, wall).max() <= 0.71  # every hit cell overlaps the wall


def test_a_cell_dropped_as_noise_takes_an_arcs_hit_only_when_no_other_cell_of_the_arc_can():
    live = LiveMap(np.zeros((40, 40), bool), None, 0, 0, safety_m=2.0, confirm_hits=1, free_to_clear=1)
    north = np.radians([0.0])
    live.add_scan(5.5, 20.5, north, np.radians(1.0), np.array([10.0]), 30.0)  # hits cell (15, 20)
    assert live.hits[15, 20]
    for _ in range(2):  # then seen free twice: dropped as noise
        live.add_scan(5.5, 20.5, north, np.radians(1.0), np.array([np.inf]), 30.0)
    assert not live.hits[15, 20] and live.once_dropped[15, 20]
    # A wider sector whose arc at 10 m spans cells (15, 20) and (15, 21): only the cell never dropped takes it.
    live.add_scan(5.5, 21.0, north, np.radians(3.0), np.array([10.0]), 30.0)
    assert live.hits[15, 21] and not live.hits[15, 20]
    # A reading only the dropped cell can explain still marks it.
    live.add_scan(5.5, 20.5, north, np.radians(1.0), np.array([10.0]), 30.0)
    assert live.hits[15, 20]


def test_a_cell_seen_free_more_often_than_hit_settles_as_free_instead_of_flickering():
    """Hit in one scan of three, seen free in the other two (an arc grazing the free cell beside a wall's end): the
    evidence is counted over the whole flight, so the cell settles as free; reset at each drop, it came back every
    few scans, and its margin closed and opened a corridor at that rate."""
    live = LiveMap(np.zeros((40, 40), bool), None, 0, 0, safety_m=2.0, confirm_hits=2, free_to_clear=3)
    north = np.radians([0.0])
    states = []
    for _ in range(20):
        for reading in (10.0, np.inf, np.inf):
            live.add_scan(5.5, 20.5, north, np.radians(1.0), np.array([reading]), 30.0)
            states.append(bool(live.hits[15, 20]))
    assert any(states[:9])  # confirmed at first, on the first hits
    assert not any(states[-30:])  # and free for good once the free readings outweigh the hits


def test_under_wide_sectors_the_viewpoint_is_the_near_edge_of_what_closes_the_way():
    corridor = np.array([[0.0, 56.0, 15.0, 100.0, 44.0, 15.0], [0.0, -56.0, 15.0, 100.0, 44.0, 15.0]])
    truth = np.vstack([corridor, WALL])
    start, goal = (0.5, 0.5), (60.5, 0.5)
    fine, _ = _live(corridor)
    _fly_north(fine, truth, 72, 0.0)
    assert Replanner(fine, goal, ALT).viewpoint(start) is None  # PX4's sectors: a closure they show is one
    wide, _ = _live(corridor)
    _fly_north(wide, truth, 8, 0.0)  # ArduPilot's 45 degree sectors
    replanner = Replanner(wide, goal, ALT)
    with pytest.raises(GoalUnreachable):
        replanner.replan(start)
    view = replanner.viewpoint(start)
    assert view is not None and not wide.grid[wide.cell_of(*view)]
    # In the street, one cell short of the margin round what was seen of the wall, north of the vehicle.
    assert view[0] > start[0] and abs(view[1]) < 12.0
    assert wide.grid[wide.cell_of(view[0] + 1.0, view[1])] or wide.grid[wide.cell_of(view[0] + 1.0, view[1] + 1.0)] \
        or wide.grid[wide.cell_of(view[0] + 1.0, view[1] - 1.0)]
    again = replanner.viewpoint(view)  # from there: the same edge (the mission needs 3 m more to go on looking)
    assert again is None or math.dist(again, view) < 3.0


def test_the_viewpoint_looks_at_the_least_certain_part_of_a_closure():
    # A line of hits across a 60 m square at north 30: the west half hit 20 times and never seen free (a wall flown
    # along), the east half hit twice and seen free once (a wide arc through free street). The way through the east
    # half is longer from the west; the viewpoint is there all the same.
    live = LiveMap(np.zeros((60, 60), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
    live.hit_count[30, :30], live.hit_count[30, 30:], live.free_count[30, 30:] = 20, 2, 1
    live.hits[30, :] = True
    live._reinflate(np.argwhere(live.hits))
    live.wide_sectors = True
    view = Replanner(live, (55.5, 10.5), ALT).viewpoint((10.5, 10.5))
    assert view is not None and view[1] >= 30.0 and 25.0 <= view[0] < 30.0
    live.free_count[30, 30:] = 0
    live.hit_count[30, 30:] = 20  # as sure as the west half: straight on
    view = Replanner(live, (55.5, 10.5), ALT).viewpoint((10.5, 10.5))
    assert view is not None and view[1] < 20.0


@pytest.mark.parametrize("heading_deg, bearing_error_deg", [(0.0, 0.0), (30.0, 0.0), (12.0, 15.0)])
def test_a_single_sector_looks_only_at_its_wedge_and_changes_the_layer_as_the_whole_square_would(
        heading_deg, bearing_error_deg, monkeypatch):
    """ArduPilot's sectors come one per message: each scan looks at its wedge's box, not the square round the
    sensor (a fifth of the cells), and leaves the layer exactly as the square would."""
    truth = np.vstack([STALE, WALL])
    wedge, _ = _live()
    square, _ = _live()
    monkeypatch.setattr(square, "_wedge_window", lambda p, centres, half, reach: square._window(p[0], p[1], reach))
    looked = []
    window = wedge._wedge_window
    monkeypatch.setattr(wedge, "_wedge_window", lambda *a: looked.append(window(*a)) or looked[-1])
    for north in np.arange(-40.0, 12.0, 1.5):
        p = (north, 0.5 + 0.3 * math.sin(north))
        bearings, half, d = _scan(truth, p, 8, heading_rad=math.radians(heading_deg))
        for b, v in zip(bearings, d):
            for live in (wedge, square):
                live.add_scan(*p, np.array([b]), half, np.array([v]), 30.0, math.radians(bearing_error_deg))
    assert wedge.hits.sum() > 5  # the wall was found
    for name in ("hits", "hit_count", "free_count", "known", "once_dropped", "grid"):
        assert np.array_equal(getattr(wedge, name), getattr(square, name)), name
    cells = np.mean([(i1 - i0) * (j1 - j0) for i0, i1, j0, j1 in looked])
    assert cells < (0.35 if bearing_error_deg else 0.3) * 63 ** 2  # the square: 2 x 30 m + 3 cells a side


#: A new wall along the street (east 3..4, north 0..60), not across it: flown beside, 4 m west of its face.
WALL_ALONG = np.array([[30.0, 3.5, 15.0, 30.0, 0.5, 15.0]])


def test_a_face_seen_across_wide_sectors_is_marked_on_the_face_not_as_arcs_across_the_street():
    """ArduPilot's 45 degree wedges beside a wall: the wedge ahead meets the face at its edge, 10.5 m on; its whole
    arc there lies across the street in front of the vehicle, and a vehicle that slows or hovers (looking again,
    a viewpoint) confirms it: round a wall's end that closed the way past it, and held-out model missions gave
    their reachable goals up. Read as one face across the wedges, only the edge point is marked (whole arcs: hit
    cells 7.5 m off the wall)."""
    live, _ = _live()
    truth = np.vstack([STALE, WALL_ALONG])
    worst = 0.0
    for north in np.arange(8.0, 38.0, 1.0):
        p = (north, -1.0)
        bearings, half, d = _scan(truth, p, 8)
        for _ in range(3):  # slow: three scans a metre
            live.add_scan(*p, bearings, half, d, 30.0)
        hits = live.hit_cells_ne()
        worst = max(worst, float(_distance_to_boxes(hits, WALL_ALONG).max()) if len(hits) else 0.0)
    assert len(live.hit_cells_ne()) > 10
    assert worst <= 3.0  # on the wall, give or take its ends' corners
