"""Plan a collision-free route through the city and fly it over MAVLink: the classic entry point.

Usage (see README.md)::

    python motion_planning.py --plan-only --goal_lat 37.7955 --goal_lon -122.3937 --alt 5 --safety 5
    python motion_planning.py --sim --goal_lat 37.7955 --goal_lon -122.3937 --alt 5
    python motion_planning.py --connection tcp:127.0.0.1:5760 --goal_lat .. --goal_lon ..

The command line lives in :mod:`skyroute.cli`; this file only runs it.
"""

from __future__ import annotations

import sys

from skyroute.cli.exits import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_NO_PATH, EXIT_OK, UserError
from skyroute.cli.main import DEFAULT_MAP, build_parser, console_main, main, run
from skyroute.planning import PLANNERS

__all__ = [
    "DEFAULT_MAP", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERRUPTED", "EXIT_NO_PATH", "EXIT_OK", "PLANNERS",
    "UserError", "build_parser", "main", "run",
]

if __name__ == "__main__":
    sys.exit(console_main())
