"""The changed-city tool: walls that cut the map-trusting route but leave a detour, a goal walled in, removals."""

from __future__ import annotations

import numpy as np
import pytest

from skyroute.cityedit import enclose_goal, main, remove_boxes, walls_across_route
from skyroute.maps import read_colliders
from skyroute.planning.cspace import grid_extent
from skyroute.planning.errors import NoPathError
from skyroute.planning.grid import GridMap

#: Four 60 m blocks in a 2 x 2 grid with 20 m streets between and round them (a ring of streets and a cross).
BLOCKS = np.array([[n, e, 15.0, 30.0, 30.0, 15.0] for n in (-40.0, 40.0) for e in (-40.0, 40.0)]
                  + [[-95.0, -95.0, 0.5, 0.5, 0.5, 0.5], [95.0, 95.0, 0.5, 0.5, 0.5, 0.5]])  # posts fix the extent


def _segment_hits_box(a, b, box) -> bool:
    """Whether segment a-b crosses the box's footprint (sampled every 5 cm: walls are >= 1 m thick)."""
    lo, hi = box[:2] - box[3:5], box[:2] + box[3:5]
    t = np.linspace(0.0, 1.0, max(2, int(np.hypot(*(np.subtract(b, a))) / 0.05)))
    pts = np.asarray(a)[None, :] + t[:, None] * np.subtract(b, a)[None, :]
    return bool(np.any(np.all((pts >= lo) & (pts <= hi), axis=1)))


def test_walls_cross_the_original_route_and_leave_a_detour():
    start, goal = (-85.0, 0.0), (85.0, 0.0)  # straight up the central north-south street
    change = walls_across_route(BLOCKS, start, goal, altitude_m=5, safety_m=3, count=1, seed=4)
    (wall,) = change.added
    route = change.route[:, :2]
    assert any(_segment_hits_box(a, b, wall) for a, b in zip(route[:-1], route[1:]))
    # The wall spans the street from block face to block face (east -10..10) and no further than into them.
    assert wall[1] - wall[4] <= -10.0 and wall[1] + wall[4] >= 10.0 and wall[4] <= 11.0
    detour = GridMap.build(change.obstacles, 5, 3).plan(start, goal, snap_start=True)
    assert detour.length_m > GridMap.build(BLOCKS, 5, 3).plan(start, goal).length_m + 50.0  # round a block


def test_a_wall_across_a_street_at_the_maps_edge_ends_at_the_edge():
    # The west street runs between the blocks and the map's edge; a wall across it reaches the edge and stops
    # there, so the changed map keeps the original's grid: no route round the wall's end outside the map.
    start, goal = (-85.0, -85.0), (85.0, -85.0)
    change = walls_across_route(BLOCKS, start, goal, altitude_m=5, safety_m=3, count=1, seed=0,
                                keep_reachable=False)
    (wall,) = change.added
    assert wall[1] - wall[4] == pytest.approx(-96.0)  # the map's west edge (the posts: -95.5, floored)
    assert grid_extent(change.obstacles) == grid_extent(BLOCKS)


def test_every_returned_city_keeps_the_goal_reachable():
    start, goal = (-85.0, 0.0), (85.0, 0.0)
    # Two walls on the route of this small grid can cut the goal off (one in each half of the central street
    # leaves the ring road; a draw that closes both ways is drawn again).
    for seed in range(6):
        change = walls_across_route(BLOCKS, start, goal, altitude_m=5, safety_m=3, count=2, seed=seed)
        GridMap.build(change.obstacles, 5, 3).plan(start, goal, snap_start=True)  # raises if unreachable


def test_a_city_has_as_many_walls_as_asked_for_or_none():
    """Walls stand at least 3 margins plus a wall apart (here 20 m) on the route's straight stretches, clear of its
    ends: 170 m up the central street hold 7, never 8. Asked for more than fit, a draw used to return the ones it
    could space out; now every draw must place them all, or the route is refused for too little straight street."""
    start, goal = (-85.0, 0.0), (85.0, 0.0)
    for count in (1, 3, 7):
        change = walls_across_route(BLOCKS, start, goal, altitude_m=5, safety_m=3, count=count, seed=1,
                                    keep_reachable=False)
        assert len(change.added) == count
    with pytest.raises(ValueError, match="too little straight street for 8 wall"):
        walls_across_route(BLOCKS, start, goal, altitude_m=5, safety_m=3, count=8, seed=1, keep_reachable=False)


def test_an_enclosed_goal_is_free_but_unreachable():
    goal = (85.0, 85.0)
    ring = enclose_goal(goal, ring_m=8.0, height_m=30.0)
    grid_map = GridMap.build(np.vstack([BLOCKS, ring]), 5, 3)
    assert not grid_map.grid[grid_map.cell_of(*goal)]
    with pytest.raises(NoPathError):
        grid_map.plan((-85.0, 0.0), goal)


def test_remove_boxes_removes_that_many_distinct_rows():
    kept, removed = remove_boxes(BLOCKS, 2, seed=1)
    assert len(kept) == len(BLOCKS) - 2 and len(set(removed)) == 2
    assert all(any(np.array_equal(row, k) for k in kept) for i, row in enumerate(BLOCKS) if i not in removed)


def test_cli_writes_a_readable_map_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    from skyroute.citygen import write_colliders

    src = tmp_path / "city.csv"
    write_colliders(src, BLOCKS)
    out = tmp_path / "changed.csv"
    assert main([str(src), "-o", str(out), "--start=-85,0", "--goal", "85,0", "--walls", "1", "--safety", "3"]) == 0
    assert len(read_colliders(out).obstacles) == len(BLOCKS) + 1
    assert main([str(tmp_path / "missing.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cityedit: error:")
    with pytest.raises(SystemExit) as exit_info:
        main([str(src), "-o", str(out), "--walls", "1"])  # no goal
    assert exit_info.value.code == 2
