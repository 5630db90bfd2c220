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
