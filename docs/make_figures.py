"""Regenerate the figures in README.md and WRITEUP.md: ``python docs/make_figures.py``.

* ``mission.png``: the demo mission flown against the bundled sim (about 15 s).
* ``planners.png``: every planner on the same corner-to-corner query of the project's map, and
  ``plan_grid3d.png``: the grid3d route over the height map, with its altitude profile.
* ``plan_sf.png``: the classic exercise's corner-to-corner query on the San Francisco map, found or fetched by
  ``skyroute.sfmap`` (a shared copy, the cache, else a checksum-verified download); skipped, with a message, when
  it cannot be had.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))

import motion_planning  # noqa: E402
from skyroute import sfmap  # noqa: E402

DEMO_GOAL = ["--goal_lat", "37.789774", "--goal_lon", "-122.393473"]
# Near the SF map's south-west and north-east corners (the exercise's corner query), moved to free cells of the
# project's map.
CORNER_QUERY = ["--start_lat", "37.790088", "--start_lon", "-122.401906", "--goal_lat", "37.797250",
                "--goal_lon", "-122.392664"]
SF_QUERY = ["--start_lat", "37.790088", "--start_lon", "-122.401634", "--goal_lat", "37.797476",
            "--goal_lon", "-122.392619"]


def planner_figures() -> None:
    """The gallery of every planner and the grid3d detail, on the project's map."""
    import numpy as np

    from skyroute.cli.setting import load_setting, make_plan, save_plot
    from skyroute.frames import Geodetic, geodetic_to_ned
    from skyroute.planning import PLANNERS
    from skyroute.view import plotting

    setting = load_setting(motion_planning.DEFAULT_MAP, 5.0, 5.0)
    values = dict(zip(CORNER_QUERY[::2], map(float, CORNER_QUERY[1::2])))
    start = geodetic_to_ned(Geodetic(values["--start_lat"], values["--start_lon"], 0.0), setting.home)[:2]
    goal = geodetic_to_ned(Geodetic(values["--goal_lat"], values["--goal_lon"], 0.0), setting.home)[:2]
    plans = [make_plan(setting, start, goal, name) for name in PLANNERS]
    grid_map = setting.grid_map
    plotting.save_planner_gallery(
        DOCS / "planners.png", setting.city.obstacles, plans, altitude_m=5.0, safety_m=5.0,
        grid=(grid_map.grid, grid_map.north_offset, grid_map.east_offset),
    )
    save_plot(DOCS / "plan_grid3d.png", setting, plans[PLANNERS.index("grid3d")])
    for plan in plans:
        print(f"{plan.planner:<12} {plan.length_m:8.1f} m  {len(plan.waypoints):3d} waypoints  "
              f"up to {np.max(plan.waypoints[:, 2]):5.1f} m")


def main() -> int:
    with tempfile.TemporaryDirectory() as logs:
        code = motion_planning.main(
            ["--sim", *DEMO_GOAL, "--speedup", "10", "--log-dir", logs, "--plot", str(DOCS / "mission.png")]
        )
    if code:
        return code
    planner_figures()
    try:
        sf_map = sfmap.sf_map()
    except sfmap.DownloadError as exc:
        print(f"plan_sf.png not made: {exc}", file=sys.stderr)
        return 1
    return motion_planning.main(["--plan-only", "--map", str(sf_map), *SF_QUERY, "--plot", str(DOCS / "plan_sf.png")])


if __name__ == "__main__":
    sys.exit(main())
