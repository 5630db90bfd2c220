"""Plan a collision-free route through the city and fly it over MAVLink.

Usage (see README.md)::

    python motion_planning.py --plan-only --goal_lat 37.7955 --goal_lon -122.3937 --alt 5 --safety 5
    python motion_planning.py --sim --goal_lat 37.7955 --goal_lon -122.3937 --alt 5
    python motion_planning.py --connection tcp:127.0.0.1:5760 --goal_lat .. --goal_lon ..

``main(argv) -> int`` parses the command line and calls :func:`run` with the same names; the process exit code
is its result. Heavy modules (matplotlib, pymavlink, the graph planners) are imported only when used, so a plan
alone starts fast.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from skyroute.cli.bundled_sim import BundledSim, sim_report_summary
from skyroute.cli.exits import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, UserError
from skyroute.cli.exploring import run_exploration
from skyroute.cli.flying import fly, make_log_dir
from skyroute.cli.setting import check_endpoint, load_setting, make_plan, plan_document, print_plan, save_plot
from skyroute.cli.view_export import check_view_export, write_exports
from skyroute.frames import Geodetic, geodetic_to_ned
from skyroute.planning import PLANNERS, PLANNERS_3D
from skyroute.view import DEFAULT_VIEW_PORT

log = logging.getLogger("motion_planning")


def default_map_path() -> Path:
    """The project's ``colliders.csv`` at the root of a checkout (beside the ``skyroute`` package), else
    ``colliders.csv`` in the working directory (an installed console script has no map beside it)."""
    beside = Path(__file__).resolve().parents[2] / "colliders.csv"
    return beside if beside.exists() else Path("colliders.csv")


DEFAULT_MAP = default_map_path()


_DASHED = {"arm_timeout", "link_timeout", "target_system", "ground_amsl"}


def check_numbers(**options) -> None:
    """Refuse NaN, infinite and out-of-range numbers before they reach a planner or a vehicle.

    (NaN compares False with everything, so without this ``--safety nan`` would silently plan through buildings.)
    """
    ranges = {  # option: (lowest, highest, lowest allowed itself)
        "goal_lat": (-90.0, 90.0, True), "start_lat": (-90.0, 90.0, True),
        "goal_lon": (-180.0, 180.0, True), "start_lon": (-180.0, 180.0, True),
        "alt": (0.0, 10_000.0, False), "safety": (0.0, 1_000.0, True), "goal_alt": (0.0, 10_000.0, True),
        "speedup": (0.0, 1_000.0, False), "timeout": (0.0, 86_400.0, False),
        "arm_timeout": (0.0, 86_400.0, False), "link_timeout": (0.0, 86_400.0, False),
        "port": (1, 65_535, True), "seed": (0, 2**32 - 1, True), "samples": (2, 1_000_000, True),
        "target_system": (1, 255, True), "ground_amsl": (-500.0, 9_000.0, True),
    }
    for name, value in options.items():
        if value is None or name not in ranges:
            continue
        low, high, low_ok = ranges[name]
        if not (math.isfinite(value) and (low <= value if low_ok else low < value) and value <= high):
            bound = f"{'>=' if low_ok else '>'} {low:g} and <= {high:g}"
            flag = name.replace("_", "-") if name in _DASHED else name  # the classic flags keep underscores
            raise UserError(f"--{flag} must be {bound}, got {value}")




# ---------------------------------------------------------------------------------------------------------------
# The command line


def run(
    *,
    goal_lat: float | None = None,
    goal_lon: float | None = None,
    alt: float = 5.0,
    safety: float = 5.0,
    start_lat: float | None = None,
    start_lon: float | None = None,
    goal_alt: float | None = None,
    map_path: str | Path | None = None,
    planner: str = "grid",
    seed: int = 0,
    samples: int = 1000,
    plot: str | None = None,
    json_output: bool = False,
    plan_only: bool = False,
    connection: str | None = None,
    host: str = "127.0.0.1",
    port: int = 5760,
    sim: bool = False,
    speedup: float = 5.0,
    timeout: float = 15.0,
    arm_timeout: float = 60.0,
    link_timeout: float = 30.0,
    target_system: int | None = None,
    signing_key: str | None = None,
    ground_amsl: float | None = None,
    quiet: bool = False,
    log_dir: str | Path = "logs",
    view: int | None = None,
    export: Sequence[str] | None = None,
    no_replan: bool = False,
    no_scan_match: bool = False,
    sim_map: str | Path | None = None,
    explore: float | None = None,
    explore_time: float | None = None,
    save_map: str | None = None,
    out=None,
) -> int:
    """Plan (and, unless ``plan_only``, fly) one mission; returns the process exit code.

    Raises :class:`UserError` for problems the user can fix; :func:`main` prints those.
    """
    out = out or sys.stdout
    if explore is not None or explore_time is not None or save_map is not None:
        return run_exploration(locals())
    if goal_lat is None or goal_lon is None:
        raise UserError("give the goal as --goal_lat DEG --goal_lon DEG")
    if (start_lat is None) != (start_lon is None):
        raise UserError("give both --start_lat and --start_lon, or neither (start at the map's home)")
    check_numbers(goal_lat=goal_lat, goal_lon=goal_lon, start_lat=start_lat, start_lon=start_lon, alt=alt,
                  safety=safety, goal_alt=goal_alt, seed=seed, port=port, speedup=speedup, timeout=timeout,
                  arm_timeout=arm_timeout, link_timeout=link_timeout, samples=samples, target_system=target_system,
                  ground_amsl=ground_amsl)
    if goal_alt is not None and planner not in PLANNERS_3D:
        raise UserError(f"--goal_alt needs a 3D planner ({' or '.join(PLANNERS_3D)}), not {planner}")
    if plot and not Path(plot).resolve().parent.is_dir():
        raise UserError(f"cannot write the plot {plot}: {Path(plot).resolve().parent} is not a directory")
    check_view_export(view, export, plan_only=plan_only)
    map_given = map_path is not None
    map_path = map_path if map_given else DEFAULT_MAP
    setting = load_setting(map_path, alt, safety, map_given=map_given)
    goal_ne = geodetic_to_ned(Geodetic(goal_lat, goal_lon, 0.0), setting.home)[:2]
    if not plan_only:
        if start_lat is not None and not sim:
            raise UserError("--start_lat/--start_lon need --plan-only or --sim: a real vehicle starts where it is")
        # Refuse a bad goal before connecting, let alone arming.
        check_endpoint(setting, "goal", *goal_ne, on_map_only=goal_alt is not None)
        make_log_dir(log_dir)
        options = dict(planner=planner, goal_alt_m=goal_alt, seed=seed, heartbeat_timeout_s=timeout,
                       arm_timeout_s=arm_timeout, link_lost_timeout_s=link_timeout, target_system=target_system,
                       signing_key=signing_key, ground_amsl_m=ground_amsl, quiet=quiet, log_dir=log_dir,
                       plot=plot, view_port=view, exports=export, replan=not no_replan,
                       scan_match=not no_scan_match, out=out)
        if sim_map is not None and not sim:
            raise UserError("--sim-map needs --sim (it is the bundled simulator's city)")
        if sim_map is not None and not Path(sim_map).is_file():
            raise UserError(f"--sim-map {sim_map}: no such file")
        if not sim:
            return fly(setting, goal_ne, connection=connection or f"tcp:{host}:{port}", **options)
        import time

        stamp = time.strftime("%Y%m%d-%H%M%S")
        start = None if start_lat is None else Geodetic(start_lat, start_lon, 0.0)
        bundled = BundledSim(sim_map or map_path, speedup=speedup, start=start,
                             report_path=Path(log_dir) / f"sim-report-{stamp}.json",
                             log_path=Path(log_dir) / f"sim-{stamp}.txt")
        with bundled:
            if not quiet:
                print(f"started the bundled sim on {bundled.connection} at {speedup:g}x speed", file=out, flush=True)
            code = fly(setting, goal_ne, connection=bundled.connection, **options)
        report = bundled.report()
        if report is not None:
            print(sim_report_summary(report, goal_ne), file=out)
        return code
    start_ne = (0.0, 0.0)
    if start_lat is not None:
        start_ne = geodetic_to_ned(Geodetic(start_lat, start_lon, 0.0), setting.home)[:2]
    if goal_alt is not None:
        check_endpoint(setting, "goal", *goal_ne, on_map_only=True)
    plan = make_plan(setting, start_ne, goal_ne, planner, goal_alt_m=goal_alt, seed=seed, samples=samples)
    if json_output:
        json.dump(plan_document(setting, plan, start_ne, goal_ne), out)
        out.write("\n")
    else:
        print_plan(plan, out)
    if plot:
        save_plot(plot, setting, plan)
        if not json_output:
            print(f"plot written to {plot}", file=out)
    write_exports(export, setting, plan, out=None if json_output else out)
    return EXIT_OK


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show ``(default: ...)`` only where there is a default worth showing."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="motion_planning.py",
        description="Plan a collision-free route through the city map and fly it over MAVLink.",
        formatter_class=_HelpFormatter,
    )
    where = parser.add_argument_group("where to go")
    where.add_argument("--goal_lat", type=float, help="goal latitude in degrees (required)")
    where.add_argument("--goal_lon", type=float, help="goal longitude in degrees (required)")
    where.add_argument("--alt", type=float, default=5.0, help="flight altitude in metres above the ground")
    where.add_argument("--safety", type=float, default=5.0,
                       help="planning margin in metres: the planned route keeps it from every building; "
                       "the flown track comes up to ~1 m closer")
    where.add_argument("--start_lat", type=float,
                       help="start latitude (with --plan-only or --sim; default: the map's home)")
    where.add_argument("--start_lon", type=float,
                       help="start longitude (with --plan-only or --sim; default: the map's home)")
    where.add_argument("--goal_alt", type=float, help="goal altitude in metres, e.g. a rooftop (grid3d planner)")
    how = parser.add_argument_group("how to plan")
    how.add_argument("--map", dest="map_path", help=f"colliders.csv map file (default: {DEFAULT_MAP})")
    how.add_argument("--planner", choices=PLANNERS, default="grid", help="planning algorithm")
    how.add_argument("--seed", type=int, default=0, help="random seed for sampling planners")
    how.add_argument("--samples", type=int, default=1000, help="roadmap nodes of the prm planner")
    link = parser.add_argument_group("the vehicle")
    link.add_argument("--connection", help="pymavlink connection string, e.g. tcp:127.0.0.1:5760 or "
                      "udpin:0.0.0.0:14540 (default: tcp:HOST:PORT)")
    link.add_argument("--host", default="127.0.0.1", help="autopilot host (classic flag; see --connection)")
    link.add_argument("--port", type=int, default=5760, help="autopilot TCP port (classic flag)")
    link.add_argument("--sim", action="store_true", help="start the bundled simulator, fly against it, stop it")
    link.add_argument("--speedup", type=float, default=5.0, help="with --sim: simulated seconds per wall second")
    link.add_argument("--sim-map", dest="sim_map", metavar="FILE",
                      help="with --sim: the city the simulator flies in (the truth), when it differs from --map "
                      "(e.g. a changed city from python -m skyroute.cityedit; default: --map)")
    link.add_argument("--timeout", type=float, default=15.0, help="seconds to wait for the autopilot's heartbeat")
    link.add_argument("--arm-timeout", dest="arm_timeout", type=float, default=60.0,
                      help="seconds to keep asking to arm while the autopilot is not ready")
    link.add_argument("--link-timeout", dest="link_timeout", type=float, default=30.0,
                      help="seconds to wait for a link lost in flight to come back before giving up "
                      "(the autopilot's own failsafe then owns the vehicle)")
    link.add_argument("--target-system", dest="target_system", type=int,
                      help="fly this MAVLink system id when several vehicles heartbeat on one link "
                      "(default: the first autopilot heard)")
    link.add_argument("--signing-key", dest="signing_key", metavar="KEY",
                      help="MAVLink 2 signing: 64 hex digits are the 32-byte key, any other text is hashed with "
                      "SHA-256 (as MAVProxy's 'signing setup'); unsigned packets are then dropped")
    link.add_argument("--ground-amsl", dest="ground_amsl", type=float, metavar="M",
                      help="altitude of the map's ground above mean sea level (default: from the vehicle standing "
                      "on the surface the map shows under it)")
    link.add_argument("--log-dir", dest="log_dir", default="logs", help="where navigation logs and tlogs go")
    link.add_argument("--no-replan", dest="no_replan", action="store_true",
                      help="do not replan in flight round obstacles the autopilot's sensor shows (default: replan "
                      "whenever it streams OBSTACLE_DISTANCE or proximity DISTANCE_SENSOR data)")
    link.add_argument("--no-scan-match", dest="no_scan_match", action="store_true",
                      help="trust the autopilot's position estimate as it is (default: while replanning, match "
                      "each obstacle scan to the map's buildings and correct the estimate's drift, within the "
                      "accuracy its GPS states)")
    explore = parser.add_argument_group("exploration (no goal; see skyroute/cli/exploring.py)")
    explore.add_argument("--explore", type=float, metavar="RADIUS_M",
                         help="explore the area within RADIUS_M of the start (frontiers, targets), fly home, land")
    explore.add_argument("--explore-time", dest="explore_time", type=float, metavar="S",
                         help="exploration time budget in the autopilot's seconds from takeoff (default: 3600)")
    explore.add_argument("--save-map", dest="save_map", metavar="OUT.csv",
                         help="after exploring, write the known and the discovered obstacles as a colliders.csv")
    output = parser.add_argument_group("output")
    output.add_argument("--plan-only", dest="plan_only", action="store_true", help="plan and print; no drone")
    output.add_argument("--json", dest="json_output", action="store_true", help="print the plan as one JSON object")
    output.add_argument("--plot", metavar="FILE.png", help="draw the map, plan (and flown track) to a PNG")
    output.add_argument("--view", nargs="?", type=int, const=DEFAULT_VIEW_PORT, metavar="PORT",
                        help=f"serve a live 3D view of the flight on http://127.0.0.1:PORT/ (default port "
                        f"{DEFAULT_VIEW_PORT}; 0 picks a free one)")
    output.add_argument("--export", action="append", metavar="FILE",
                        help="write the plan (and after a flight the flown track) to FILE, format from the "
                        "extension: .plan (QGroundControl), .waypoints (MAVProxy/Mission Planner), .geojson, .kml; "
                        "repeatable")
    output.add_argument("-v", "--verbose", action="store_true", help="log everything (INFO) to stderr")
    output.add_argument("-q", "--quiet", action="store_true",
                        help="no progress lines: neither the first run's 'compiling' notice nor the flight's")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = vars(build_parser().parse_args(argv))
    announce_first_compile(not args["quiet"])
    logging.basicConfig(
        level=logging.INFO if args.pop("verbose") else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    # SIGTERM (a service manager, `kill`) is handled like Ctrl-C: land first, stop the bundled sim, then exit.
    restore = None
    if threading.current_thread() is threading.main_thread():
        restore = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return run(**args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `... --json | head`: the reader left; say nothing more
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILED
    finally:
        if restore is not None:
            signal.signal(signal.SIGTERM, restore)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def announce_first_compile(enabled: bool = True) -> None:
    """Say so on stderr, once, if this run has to compile the planner's kernels (a fresh install)."""
    from skyroute.planning import kernels

    kernels.on_first_compile(None if not enabled else lambda: print(
        "compiling the planner's kernels (first run only, a few seconds; cached on disk after that)",
        file=sys.stderr, flush=True,
    ))


def console_main() -> int:
    """The process entry point (``motion_planning.py``, the ``motion-planning`` script): :func:`main`, then skip
    the garbage collector's last pass at exit (``gc.freeze``). With numba loaded that pass takes about 0.1 s, a
    fifth of a plan-only run, and frees nothing the operating system would not; files and logs are flushed and
    closed as usual (by their owners and ``atexit``)."""
    code = main()
    import gc

    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(console_main())
