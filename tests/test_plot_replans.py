"""--plot's picture of a flight that sensed obstacles: discovered cells and replans are drawn."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyroute.planning.grid import GridMap

BOXES = np.array([[0.0, 30.0, 10.0, 40.0, 10.0, 10.0], [-45.0, -45.0, 0.5, 0.5, 0.5, 0.5],
                  [45.0, 45.0, 0.5, 0.5, 0.5, 0.5]])


@dataclass
class Record:
    north_m: float
    east_m: float
    waypoints: np.ndarray | None


def _red_pixels(path) -> int:
    import matplotlib.image

    img = matplotlib.image.imread(path)[..., :3]
    red = np.array([0.839, 0.153, 0.157])  # tab:red
    return int((np.abs(img - red).max(axis=2) < 0.08).sum())


def test_discovered_obstacles_and_replans_add_red_to_the_picture(tmp_path):
    from skyroute.view.plotting import save_plan_figure

    gm = GridMap.build(BOXES, 5.0, 3.0)
    plan = gm.plan((-40.0, 0.0), (40.0, 0.0))
    grid = (gm.grid, gm.north_offset, gm.east_offset)
    plain = save_plan_figure(tmp_path / "plain.png", BOXES, plan, altitude_m=5.0, safety_m=3.0, grid=grid)
    hits = np.array([[0.5, e + 0.5] for e in range(-10, 10)])
    replan = Record(-12.0, 0.0, np.array([[-12.0, 0.0, 5, 0], [-12.0, -20.0, 5, 0], [40.0, 0.0, 5, 0]]))
    sensed = save_plan_figure(tmp_path / "sensed.png", BOXES, plan, altitude_m=5.0, safety_m=3.0, grid=grid,
                              discovered_ne=hits, replans=[replan], truth_added=np.array([[0.5, 0, 10, 1, 10, 10]]),
                              track_ne=np.array([[-40.0, 0.0], [-12.0, 0.0], [-12.0, -20.0]]))
    assert _red_pixels(sensed) > _red_pixels(plain) + 50
