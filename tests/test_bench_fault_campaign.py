"""The fault campaign's own parts: the missions it picks and the faults it gives the sim (no flights here)."""

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

import fault_campaign  # noqa: E402

from tests.sitl_support import distance_to_boxes_m, read_boxes  # noqa: E402


def test_picked_missions_start_and_end_in_streets_150_to_800_m_apart():
    missions = fault_campaign.pick_missions(ROOT / "colliders.csv", 3, seed=4)
    _, _, boxes = read_boxes(ROOT / "colliders.csv")
    assert len(missions) == 3
    for mission in missions:
        assert 150.0 <= math.dist(mission["start_ne"], mission["goal_ne"]) <= 800.0
        ends = np.array([[*mission["start_ne"], 0.0], [*mission["goal_ne"], 0.0]])
        assert (distance_to_boxes_m(ends, boxes) >= 5.0).all()  # descend and stand clear of every building
        assert mission["planned_m"] >= math.dist(mission["start_ne"], mission["goal_ne"])


def test_a_changed_city_for_a_mission_closes_the_maps_route_and_keeps_the_goal_reachable(tmp_path):
    """``--walls``: the sim flies in a copy of the map with walls across the route the map gives the mission (the
    client keeps the map); a mission with too little straight street for the walls is skipped (None)."""
    from skyroute.maps import read_colliders
    from skyroute.planning.grid import GridMap

    mission = fault_campaign.pick_missions(ROOT / "colliders.csv", 1, seed=4)[0]
    truth = fault_campaign.changed_city(ROOT / "colliders.csv", mission, 2, 4, tmp_path / "city.csv")
    assert truth == tmp_path / "city.csv"
    before, after = read_colliders(ROOT / "colliders.csv").obstacles, read_colliders(truth).obstacles
    assert len(after) == len(before) + 2
    start, goal = mission["start_ne"], mission["goal_ne"]
    stale_route = GridMap.build(before, 5.0, 5.0).plan(start, goal, snap_start=True)
    true_map = GridMap.build(after, 5.0, 5.0)
    assert true_map.plan(start, goal, snap_start=True).length_m > stale_route.length_m  # a detour, not a dead end
    assert fault_campaign.changed_city(ROOT / "colliders.csv", mission, 60, 4, tmp_path / "none.csv") is None
    assert not (tmp_path / "none.csv").exists()
