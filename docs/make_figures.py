"""Regenerate the figures in README.md and WRITEUP.md: ``python docs/make_figures.py``.

Flies the demo mission against the bundled sim (about 15 s) and plans on the shared SF map when it is present
(``../shared/maps/udacity_sf_colliders.csv``). Writes PNGs next to this file.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))

import motion_planning  # noqa: E402

DEMO_GOAL = ["--goal_lat", "37.789774", "--goal_lon", "-122.393473"]
SF_MAP = ROOT.parent / "shared" / "maps" / "udacity_sf_colliders.csv"


def main() -> int:
    with tempfile.TemporaryDirectory() as logs:
        code = motion_planning.main(
            ["--sim", *DEMO_GOAL, "--speedup", "10", "--log-dir", logs, "--plot", str(DOCS / "mission.png")]
        )
    if code:
        return code
    if SF_MAP.exists():
        # The classic exercise's corner-to-corner query on the students' map.
        code = motion_planning.main(
            ["--plan-only", "--map", str(SF_MAP), "--goal_lat", "37.797476", "--goal_lon", "-122.392619",
             "--start_lat", "37.790088", "--start_lon", "-122.401634", "--plot", str(DOCS / "plan_sf.png")]
        )
    return code


if __name__ == "__main__":
    sys.exit(main())
