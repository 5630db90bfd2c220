"""The exploration judge (``tests/explore_oracle.py``) on hand-made cities: what it requires of a saved map."""

from __future__ import annotations

import numpy as np

from tests import explore_oracle as oracle

ALT_M, SAFETY_M, RADIUS_M = 5.0, 5.0, 30.0


def _box(north, east, half, top):
    return [north, east, top / 2, half, half, top / 2]


def test_a_wall_seen_from_the_streets_is_required_and_found_when_saved():
    wall = np.array([_box(15.0, 0.0, 2.0, 20.0)])
    missing = oracle.score_map(wall, np.empty((0, 6)), (0.0, 0.0), RADIUS_M, ALT_M, SAFETY_M)
    saved = oracle.score_map(wall, wall, (0.0, 0.0), RADIUS_M, ALT_M, SAFETY_M)
    assert missing["visible_wall_cells"] > 0 and missing["recall"] == 0.0
    assert saved["recall"] == 1.0 and saved["precision"] == 1.0


def test_a_pole_barely_above_the_sensor_plane_is_not_required_but_not_wrong_when_saved():
    pole = np.array([_box(15.0, 0.0, 1.3, ALT_M + 0.2)])
    missing = oracle.score_map(pole, np.empty((0, 6)), (0.0, 0.0), RADIUS_M, ALT_M, SAFETY_M)
    saved = oracle.score_map(pole, pole, (0.0, 0.0), RADIUS_M, ALT_M, SAFETY_M)
    assert missing["visible_wall_cells"] == 0
    assert saved["precision"] == 1.0
    taller = oracle.score_map(np.array([_box(15.0, 0.0, 1.3, ALT_M + 1.0)]), np.empty((0, 6)), (0.0, 0.0),
                              RADIUS_M, ALT_M, SAFETY_M)
    assert taller["visible_wall_cells"] > 0
