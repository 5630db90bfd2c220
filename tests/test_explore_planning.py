"""Frontiers, the nearest reachable one, coverage, the camera's search cells and the map writer (issue 12)."""

import math

import numpy as np
import pytest

from skyroute.cli.exploring import observed_height_m, save_map
from skyroute.maps import read_colliders
from skyroute.planning.cspace import create_grid
from skyroute.planning.explore import ExploreArea, Explorer, frontier_mask, merged_boxes, nearest_frontier


def test_frontier_is_known_free_next_to_unknown_outside_margins():
    # 6 x 6: the west half known; an occupied known cell at (2, 2); the grid blocks (4, 2)
    known = np.zeros((6, 6), bool)
    known[:, :3] = True
    occupied = np.zeros_like(known)
    occupied[2, 2] = True
    grid = np.zeros_like(known)
    grid[4, 2] = True
    got = frontier_mask(known, occupied, grid, np.ones_like(known))
    expected = np.zeros_like(known)
    expected[[0, 1, 3, 5], 2] = True  # column 2 touches the unknown column 3; (2, 2) occupied, (4, 2) blocked
    assert (got == expected).all()


def test_unknown_outside_the_area_makes_no_frontier():
    known = np.zeros((4, 4), bool)
    known[:, :2] = True
    area = np.zeros_like(known)
    area[:, :2] = True  # the unknown half lies outside the area
    assert not frontier_mask(known, np.zeros_like(known), np.zeros_like(known), area).any()


def test_nearest_frontier_goes_round_a_wall_and_skips_unreachable_ones():
    grid = np.zeros((7, 7), bool)
    grid[:, 3] = True  # a full wall: the east half cannot be reached
    grid[0:5, 1] = True  # a spur west of the start's column... start at (0, 0)
    frontiers = np.zeros_like(grid)
    frontiers[0, 2] = True  # 2 cells east but behind the spur: round it, 6 south-east and back
    frontiers[3, 5] = True  # beyond the wall: never
    cell, cost = nearest_frontier(grid, frontiers, (0, 0))
    # (0,0) -> down column 0 to (4,0) [4], diagonal to (5,1) [sqrt 2], diagonal up to (4,2) [sqrt 2], up to (0,2) [4]
    assert cell == (0, 2) and cost == pytest.approx(8 + 2 * math.sqrt(2))
    frontiers[0, 2] = False
    assert nearest_frontier(grid, frontiers, (0, 0)) is None


@pytest.mark.parametrize("seed", range(5))
def test_merged_boxes_cover_exactly_the_occupied_cells(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((30, 40)) < 0.3
    boxes = merged_boxes(occ, -7, 12, height_m=6.0)
    assert len(boxes) < occ.sum()  # runs were merged
    cover = np.zeros(occ.shape, int)
    for n, e, a, dn, de, da in boxes:
        assert a == da == 3.0
        i0, i1 = int(round(n - dn)) + 7, int(round(n + dn)) + 7
        j0, j1 = int(round(e - de)) - 12, int(round(e + de)) - 12
        cover[i0:i1, j0:j1] += 1
    assert (cover == occ).all()  # every occupied cell once, nothing else


def test_saved_map_reads_back_and_plans_as_the_observed_cells(tmp_path):
    occ = np.zeros((20, 20), bool)
    occ[5:15, 8] = True  # a wall 10 m long
    occ[3, 3:6] = True
    boxes = merged_boxes(occ, 100, -50, observed_height_m(5.0))
    known = np.array([[0.0, 0.0, 20.0, 2.0, 2.0, 20.0]])
    path = tmp_path / "explored.csv"
    assert save_map(path, 37.79, -122.39, known, boxes) == 1 + len(boxes)
    back = read_colliders(path)
    assert (back.lat0_deg, back.lon0_deg) == (37.79, -122.39)
    assert np.allclose(back.obstacles, np.vstack([known, boxes]))
    grid, north0, east0 = create_grid(back.obstacles[1:], 5.0, 0.0)  # the observed boxes alone, no margin
    cells = {(i + north0, j + east0) for i, j in np.argwhere(grid)}
    assert cells == {(i + 100, j - 50) for i, j in np.argwhere(occ)}


def test_an_empty_exploration_writes_a_map_the_reader_accepts_as_empty(tmp_path):
    path = tmp_path / "explored.csv"
    save_map(path, 37.79, -122.39, np.empty((0, 6)), np.empty((0, 6)))
    assert read_colliders(path, allow_empty=True).obstacles.shape == (0, 6)


def _scan_of_a_wall(area: ExploreArea, position, wall_east_m: float):
    """A 72-sector scan from ``position`` of an infinite wall along north at ``wall_east_m`` (computed here)."""
    bearings = np.radians(np.arange(0.0, 360.0, 5.0))
    half = math.radians(2.5)
    d = np.full(72, np.inf)
    gap = wall_east_m - position[1]
    for k, b in enumerate(bearings):
        lo, hi = b - half, b + half
        if math.sin(lo) > 0 or math.sin(hi) > 0:  # the wedge looks east somewhere
            best = max(math.sin(lo), math.sin(hi), 1.0 if lo <= math.pi / 2 <= hi else -1.0)
            dist = gap / best
            d[k] = dist if dist <= 30.0 else np.inf
    area.live.add_scan(position[0], position[1], bearings, half, d, 30.0)


def test_scans_of_a_wall_make_it_known_and_no_frontier_behind_it():
    area = ExploreArea(np.empty((0, 6)), (0.0, 0.0), 25.0, 5.0, 2.0, confirm_hits=1)
    for north in np.arange(-20.0, 21.0, 2.0):
        _scan_of_a_wall(area, (north, 0.0), 12.0)
    wall = area.live.hits[:, area.cell_of(0.0, 12.0)[1]]
    assert wall[area.cell_of(-10.0, 0)[0]:area.cell_of(10.0, 0)[0]].all()
    # nothing east of the wall is known, so no frontier may sit there, nor within the margin of the wall
    frontier = area.frontiers()
    cols = np.argwhere(frontier)[:, 1] + area.east_offset + 0.5
    assert (cols < 12.0 - 2.0).all()
    # the disk (r 25) east of the wall (a circular segment at 12 m) is 20.7 % of it: that much stays unknown
    segment = 25.0**2 * math.acos(12.0 / 25.0) - 12.0 * math.sqrt(25.0**2 - 12.0**2)
    assert area.coverage() == pytest.approx(1.0 - segment / (math.pi * 25.0**2), abs=0.03)


def test_camera_search_cells_are_cleared_by_viewing():
    area = ExploreArea(np.empty((0, 6)), (0.0, 0.0), 10.0, 5.0, 2.0, camera_radius_m=4.0)
    area.live.known[:] = True  # pretend the sensor has seen everything free
    assert area.search_cells().sum() > 0 and not area.frontiers().any()
    for north in (-6.0, 0.0, 6.0):
        for east in (-6.0, 0.0, 6.0):
            area.view(north, east)
    left = np.argwhere(area.search_cells()) + (area.north_offset + 0.5, area.east_offset + 0.5)
    # a 3 x 3 lattice 6 m apart with 4 m footprints leaves only what is farther than 4 m from every view point
    views = np.array([(n, e) for n in (-6, 0, 6) for e in (-6, 0, 6)], float)
    assert all(np.hypot(*(views - p).T).min() > 4.0 for p in left)


def test_explorer_routes_round_an_observed_wall():
    area = ExploreArea(np.empty((0, 6)), (0.0, 0.0), 40.0, 5.0, 2.0, confirm_hits=1)
    for north in np.arange(-30.0, 31.0, 1.0):
        area.live.hits[area.cell_of(north, 10.0)] = True
    area.live._reinflate(np.argwhere(area.live.hits))
    route = Explorer(area).route_to((0.0, 0.0), (0.0, 20.0))
    assert math.dist(route[-1][:2], (0.0, 20.0)) < 0.8
    # sampled every 0.1 m, the route keeps the 2 m margin from the wall cells (east 10..11, north -30..31)
    for a, b in zip(route[:-1, :2], route[1:, :2]):
        for t in np.linspace(0.0, 1.0, int(math.dist(a, b) / 0.1) + 2):
            n, e = a + t * (b - a)
            dn, de = max(-30.0 - n, 0.0, n - 31.0), max(10.0 - e, 0.0, e - 11.0)
            assert math.hypot(dn, de) >= 2.0 - 1e-6


def test_why_nothing_is_reachable_counts_the_goals_left_and_names_a_start_inside_a_margin():
    area = ExploreArea(np.empty((0, 6)), (0.0, 0.0), 20.0, 5.0, 2.0, confirm_hits=1, camera_radius_m=4.0)
    explorer = Explorer(area)
    assert explorer.why_unreachable((0.0, 0.0)) == ""  # nothing known yet: no goal at all
    ring = [(n, e) for n in np.arange(-6.0, 7.0) for e in np.arange(-6.0, 7.0) if max(abs(n), abs(e)) == 6.0]
    for n, e in ring:  # a closed ring of observed cells 6 m round the vehicle: every goal outside it
        area.live.hits[area.cell_of(n, e)] = True
    area.live._reinflate(np.argwhere(area.live.hits))
    area.live.known[area.cell_of(-4.0, -4.0)[0]:area.cell_of(4.0, 4.0)[0] + 1,
                    area.cell_of(-4.0, -4.0)[1]:area.cell_of(4.0, 4.0)[1] + 1] = True
    for n in (-3.0, 0.0, 3.0):
        for e in (-3.0, 0.0, 3.0):
            area.view(n, e)  # the camera has looked at everything inside the ring
    area.live.known[area.cell_of(12.0, -2.0)[0]:area.cell_of(14.0, 2.0)[0] + 1,
                    area.cell_of(12.0, -2.0)[1]:area.cell_of(14.0, 2.0)[1] + 1] = True  # seen free beyond it
    assert explorer.next_frontier((0.0, 0.0)) is None
    why = explorer.why_unreachable((0.0, 0.0))
    assert why.startswith(f"{int(area.goals().sum())} frontier and search cells, none reachable from (0.0 N, 0.0 E)")
    assert int(area.goals().sum()) > 0 and "margin" not in why
    assert explorer.why_unreachable((5.0, 0.0)).endswith("; that cell is inside an obstacle margin")


def test_a_vehicle_deep_inside_a_margin_still_finds_the_frontier_beyond_it():
    # a wall seen late: the vehicle stands 1 m from it, two cells deep in its 3 m margin, where every neighbour is
    # blocked too; the frontier is searched from where the vehicle joins the free space, that leg in its cost
    area = ExploreArea(np.empty((0, 6)), (0.0, 0.0), 25.0, 5.0, 3.0, confirm_hits=1)
    for north in np.arange(-20.0, 21.0, 1.0):
        area.live.hits[area.cell_of(north, 10.0)] = True
    area.live._reinflate(np.argwhere(area.live.hits))
    area.live.known[area.cell_of(-5.0, 0.0)[0]:area.cell_of(5.0, 0.0)[0] + 1,
                    area.cell_of(0.0, -5.0)[1]:area.cell_of(0.0, 9.0)[1] + 1] = True
    here = (0.5, 8.5)
    i, j = area.cell_of(*here)
    assert area.live.grid[i - 1:i + 2, j - 1:j + 2].all()  # boxed in by its own margin
    found = Explorer(area).next_frontier(here)
    assert found is not None
    assert found.point_ne[1] <= 10.0 - 3.0  # on the vehicle's side of the wall, outside the margin
    assert found.cost_m >= math.dist(here, (here[0], 10.0 - 3.0)) - 1.0
