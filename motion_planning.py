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
import functools
import json
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frames import Geodetic, LocalNED, geodetic_to_ned, ned_to_geodetic
from planning_utils import (
    BlockedCellError,
    CityMap,
    GridMap,
    MapFormatError,
    NoPathError,
    OutsideGridError,
    Plan,
    PlanningError,
    create_grid,
    nearest_free_cell,
    read_colliders,
)

log = logging.getLogger("motion_planning")

def default_map_path() -> Path:
    """The project's ``colliders.csv`` beside this file (a checkout), else ``colliders.csv`` in the working
    directory (an installed console script has no map beside it)."""
    beside = Path(__file__).resolve().with_name("colliders.csv")
    return beside if beside.exists() else Path("colliders.csv")


DEFAULT_MAP = default_map_path()
PLANNERS = ("grid", "medial-axis", "voronoi", "prm", "grid3d", "any-angle")
PLANNERS_3D = ("prm", "grid3d")  # the planners that can end at another altitude (--goal_alt)

EXIT_OK = 0
EXIT_FAILED = 1  # the mission started but did not complete
EXIT_BAD_INPUT = 2  # bad map, bad start/goal, no autopilot, refused command before takeoff
EXIT_NO_PATH = 3
EXIT_INTERRUPTED = 130


class UserError(Exception):
    """A problem the user can fix; the CLI prints it on one line and exits with ``exit_code``."""

    def __init__(self, message: str, exit_code: int = EXIT_BAD_INPUT):
        super().__init__(message)
        self.exit_code = exit_code


# ---------------------------------------------------------------------------------------------------------------
# Planning


@dataclass(frozen=True)
class Setting:
    """The map and the grid for the flight altitude, with the home point the map frame is relative to."""

    city: CityMap
    home: Geodetic
    grid_map: GridMap
    altitude_m: float
    safety_m: float

    @functools.cached_property
    def landing_grid(self) -> np.ndarray:
        """Cells at least the safety margin from every obstacle, however low: where the vehicle may descend."""
        return create_grid(self.city.obstacles, 0.0, self.safety_m)[0]

    def to_geodetic(self, north_m: float, east_m: float) -> Geodetic:
        return ned_to_geodetic(LocalNED(north_m, east_m, 0.0), self.home)

    def describe(self, north_m: float, east_m: float) -> str:
        """``lat, lon (N .. m, E .. m)`` for messages."""
        p = self.to_geodetic(north_m, east_m)
        return f"{p.lat_deg:.6f}, {p.lon_deg:.6f} (N {north_m:.1f} m, E {east_m:.1f} m)"


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
        "port": (1, 65_535, True), "seed": (0, 2**32 - 1, True),
    }
    for name, value in options.items():
        if value is None or name not in ranges:
            continue
        low, high, low_ok = ranges[name]
        if not (math.isfinite(value) and (low <= value if low_ok else low < value) and value <= high):
            bound = f"{'>=' if low_ok else '>'} {low:g} and <= {high:g}"
            raise UserError(f"--{name.replace('_', '-') if name.endswith('timeout') else name} must be {bound}, "
                            f"got {value}")


def load_setting(map_path: str | Path, altitude_m: float, safety_m: float) -> Setting:
    """Read the map and build the configuration-space grid; map problems become :class:`UserError`."""
    try:
        city = read_colliders(map_path)
    except MapFormatError as exc:
        raise UserError(f"bad map file {exc}") from None
    except OSError as exc:
        hint = " (pass --map FILE)" if isinstance(exc, FileNotFoundError) else ""
        raise UserError(f"cannot read map file {map_path}: {exc.strerror or exc}{hint}") from None
    home = Geodetic(city.lat0_deg, city.lon0_deg, 0.0)
    return Setting(city, home, GridMap.build(city.obstacles, altitude_m, safety_m), altitude_m, safety_m)


def check_endpoint(
    setting: Setting, which: str, north_m: float, east_m: float, *, allow_margin: bool = False,
    on_map_only: bool = False,
) -> None:
    """Raise :class:`UserError` if a start or goal point is off the map or inside an obstacle or its margin.

    With ``allow_margin`` a point inside the safety margin (but outside every obstacle) passes: the planner then
    starts from the nearest free cell. ``on_map_only`` checks only that the point is on the map (a 3D goal, which
    the 3D planner checks at its own altitude). A goal must also keep the margin from buildings lower than the
    flight altitude, since the vehicle descends there.
    """
    grid_map = setting.grid_map
    n, m = grid_map.grid.shape
    i, j = grid_map.cell_of(north_m, east_m)
    where = setting.describe(north_m, east_m)
    if not (0 <= i < n and 0 <= j < m):
        raise UserError(
            f"{which} {where} is off the map, which spans N {grid_map.north_offset}..{grid_map.north_offset + n} m, "
            f"E {grid_map.east_offset}..{grid_map.east_offset + m} m from home"
        )
    if on_map_only:
        return
    if not grid_map.grid[i, j]:
        if which == "goal" and setting.landing_grid[i, j]:
            nearest = nearest_free_cell(setting.landing_grid, (i, j))
            hint = "no free point on the map"
            if nearest is not None:
                hint = "nearest free landing point: " + setting.describe(*grid_map.centre_of(nearest))
            raise UserError(
                f"{which} {where} is within the {setting.safety_m:g} m safety margin of a building lower than the "
                f"flight altitude, which the descent would pass; {hint}"
            )
        return
    inside = grid_map.inside_obstacle(north_m, east_m)
    if allow_margin and not inside:
        return
    try:
        grid_map.planner.check_cell(which, (i, j))
    except BlockedCellError as exc:
        what = "inside a building" if inside else f"within the {setting.safety_m:g} m safety margin of a building"
        hint = "no free point on the map"
        if exc.nearest_free is not None:
            hint = "nearest free point: " + setting.describe(*grid_map.centre_of(exc.nearest_free))
        raise UserError(f"{which} {where} is {what} at {setting.altitude_m:g} m altitude; {hint}") from None


def make_plan(
    setting: Setting,
    start_ne: Sequence[float],
    goal_ne: Sequence[float],
    planner: str = "grid",
    *,
    goal_alt_m: float | None = None,
    seed: int = 0,
    snap_start: bool = False,
) -> Plan:
    """Plan with the named planner; bad endpoints and "no path" become :class:`UserError` (exit 2 or 3)."""
    check_endpoint(setting, "start", *start_ne, allow_margin=snap_start)
    if goal_alt_m is None:
        check_endpoint(setting, "goal", *goal_ne)
    try:
        if planner == "grid":
            return setting.grid_map.plan(start_ne, goal_ne, snap_start=snap_start)
        import graph_planning  # the other planners pull in networkx, scipy and scikit-image

        return graph_planning.plan(
            planner, setting.city.obstacles, start_ne, goal_ne, setting.altitude_m, setting.safety_m,
            goal_alt_m=goal_alt_m, seed=seed, snap_start=snap_start,
        )
    except NoPathError as exc:
        raise UserError(
            f"no path from {setting.describe(*start_ne)} to {setting.describe(*goal_ne)} at "
            f"{setting.altitude_m:g} m with a {setting.safety_m:g} m safety margin ({exc})",
            EXIT_NO_PATH,
        ) from None
    except BlockedCellError as exc:  # e.g. a 3D goal whose altitude is inside a building's margin
        where = setting.describe(*(start_ne if exc.which == "start" else goal_ne))
        hint = ""
        if exc.nearest_free is not None:
            hint = "; nearest free point: " + setting.describe(*setting.grid_map.centre_of(exc.nearest_free))
        raise UserError(f"cannot plan with {planner}: the {exc.which} {where} is blocked{hint}") from None
    except (OutsideGridError, PlanningError) as exc:
        raise UserError(f"cannot plan with {planner}: {exc}") from None


def plan_summary(plan: Plan) -> str:
    s = plan.stats()
    return (
        f"{plan.planner} plan: cost {s['cost_m']:.1f} m, length {s['length_m']:.1f} m, "
        f"{s['expanded']} nodes expanded, search {s['search_ms']:.1f} ms, "
        f"waypoints {s['waypoints_before_pruning']} -> {s['waypoints_after_pruning']} after pruning"
    )


def plan_document(setting: Setting, plan: Plan, start_ne, goal_ne) -> dict:
    """The ``--json`` output: waypoints, stats, and where things are."""

    def point(north_m, east_m):
        p = setting.to_geodetic(north_m, east_m)
        return {"north_m": float(north_m), "east_m": float(east_m), "lat_deg": p.lat_deg, "lon_deg": p.lon_deg}

    return {
        "waypoints": np.round(plan.waypoints, 4).tolist(),
        "waypoint_fields": ["north_m", "east_m", "altitude_m", "heading_rad"],
        "stats": plan.stats(),
        "home": {"lat_deg": setting.home.lat_deg, "lon_deg": setting.home.lon_deg},
        "start": point(*start_ne),
        "goal": point(*goal_ne),
        "map": setting.city.path,
        "altitude_m": setting.altitude_m,
        "safety_m": setting.safety_m,
    }


def print_plan(plan: Plan, out=sys.stdout) -> None:
    print("waypoints: north_m east_m altitude_m heading_rad", file=out)
    for k, (north, east, alt, heading) in enumerate(plan.waypoints):
        print(f"{k:4d} {north:9.2f} {east:9.2f} {alt:7.2f} {heading:8.4f}", file=out)
    print(plan_summary(plan), file=out)


def save_plot(path, setting: Setting, plan: Plan, track_ne=None) -> None:
    import plotting  # matplotlib only when a picture is asked for

    plotting.save_plan_figure(
        path, setting.city.obstacles, plan, altitude_m=setting.altitude_m, safety_m=setting.safety_m,
        track_ne=track_ne,
        grid=(setting.grid_map.grid, setting.grid_map.north_offset, setting.grid_map.east_offset),
    )


# ---------------------------------------------------------------------------------------------------------------
# Flying


class PlanRefused(Exception):
    """Raised inside the mission's planning step; carries the :class:`UserError` for the CLI."""

    def __init__(self, error: UserError):
        super().__init__(str(error))
        self.error = error


def make_log_dir(log_dir: str | Path) -> Path:
    """Create the log directory, or raise :class:`UserError` saying why not."""
    try:
        Path(log_dir).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot use {log_dir} as the log directory: {exc.strerror or exc}") from None
    return Path(log_dir)


def open_logs(log_dir: str | Path) -> tuple[Path, Path, logging.Handler]:
    """Create ``log_dir`` and a navigation log handler (flushed after every record) plus a tlog path."""
    import time

    log_dir = make_log_dir(log_dir)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    nav_path, tlog_path = log_dir / f"navlog-{stamp}.txt", log_dir / f"flight-{stamp}.tlog"
    handler = logging.FileHandler(nav_path, encoding="utf-8")  # StreamHandler flushes after each record
    handler.setLevel(logging.INFO)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    return nav_path, tlog_path, handler


def fly(
    setting: Setting,
    goal_ne: Sequence[float],
    *,
    connection: str,
    planner: str,
    goal_alt_m: float | None,
    seed: int,
    heartbeat_timeout_s: float,
    arm_timeout_s: float,
    link_lost_timeout_s: float = 30.0,
    log_dir: str | Path,
    plot: str | None,
    out,
) -> int:
    """Connect, arm, plan from where the vehicle is, take off, fly, land at the goal, disarm.

    Returns the exit code; problems before takeoff raise :class:`UserError`. Whatever happens after takeoff,
    the mission lands (or holds) before this returns, and says so.
    """
    import mission as mission_mod
    import vehicle as vehicle_mod

    nav_path, tlog_path, handler = open_logs(log_dir)
    root = logging.getLogger()
    saved_levels = [(root, root.level)] + [(h, h.level) for h in root.handlers]  # restored on the way out
    root.addHandler(handler)
    if root.level > logging.INFO or root.level == logging.NOTSET:
        root.setLevel(logging.INFO)
        for other in root.handlers:  # keep the console as quiet as the user asked
            if other is not handler and other.level == logging.NOTSET:
                other.setLevel(logging.WARNING)
    plans: list[Plan] = []

    def plan_from(start_north_m: float, start_east_m: float) -> np.ndarray:
        try:
            plan = make_plan(
                setting, (start_north_m, start_east_m), goal_ne, planner,
                goal_alt_m=goal_alt_m, seed=seed, snap_start=True,
            )
        except UserError as exc:
            raise PlanRefused(exc) from None
        log.info(plan_summary(plan))
        plans.append(plan)
        return plan.waypoints

    try:
        print(f"connecting to {connection} ...", file=out, flush=True)
        try:
            drone = vehicle_mod.MavlinkVehicle(
                connection, heartbeat_timeout_s=heartbeat_timeout_s, tlog_path=tlog_path
            )
        except vehicle_mod.VehicleError as exc:
            raise UserError(f"no autopilot answered on {connection}: {exc}") from None
        try:
            print(f"connected to a {drone.autopilot.name} autopilot; logs in {nav_path} and {tlog_path}",
                  file=out, flush=True)
            mission = mission_mod.Mission(
                drone, plan_from, altitude_m=setting.altitude_m, map_origin=setting.home,
                no_path_errors=(PlanRefused,), vehicle_errors=(vehicle_mod.VehicleError,),
                arm_timeout_s=arm_timeout_s, link_lost_timeout_s=link_lost_timeout_s,
            )
            try:
                result = mission.run()
            except vehicle_mod.VehicleError as exc:  # before arming: e.g. no position to plan from
                raise UserError(f"the vehicle did not get ready: {exc}") from None
            except mission_mod.ArmingFailed as exc:
                raise UserError(str(exc)) from None
            except mission_mod.NoPathFound as exc:
                cause = exc.__cause__
                if isinstance(cause, PlanRefused):
                    raise UserError(f"{cause.error} (disarmed, never took off)", cause.error.exit_code) from None
                raise UserError(str(exc), EXIT_NO_PATH) from None
            except mission_mod.MissionError as exc:
                print(f"error: mission failed: {exc}", file=sys.stderr)
                if exc.result is not None and plans and plot:
                    save_plot(plot, setting, plans[-1], exc.result.track[:, 1:3])
                return EXIT_FAILED
            except KeyboardInterrupt:
                print(f"interrupted: {interrupted_outcome(mission)}", file=sys.stderr)
                return EXIT_INTERRUPTED
        finally:
            drone.close()
        print(f"mission complete: {result.summary()}", file=out)
        if plot and plans:
            save_plot(plot, setting, plans[-1], result.track[:, 1:3])
            print(f"plot written to {plot}", file=out)
        return EXIT_OK
    finally:
        root.removeHandler(handler)
        handler.close()
        for logger_or_handler, level in saved_levels:
            logger_or_handler.setLevel(level)


def interrupted_outcome(mission) -> str:
    """What the mission did with the vehicle after Ctrl-C, from its state and history (not assumed)."""
    import mission as mission_mod

    state, history = mission.state, mission.result.history
    if state is mission_mod.MissionState.MANUAL:
        if any(new is mission_mod.MissionState.TAKEOFF for _, _, new in history):
            return "the vehicle was landed and disarmed first"
        return "the vehicle is disarmed on the ground; it never took off" if history else "the vehicle was never armed"
    return (f"the mission stopped in state {state.name}: the vehicle may not be on the ground and disarmed; "
            "the autopilot's failsafe owns it")


class BundledSim:
    """The project's simulator (``python -m sim``) as a child process on a free loopback port.

    Used as a context manager: starts the sim, waits until it accepts connections, and on exit stops it with
    SIGINT (it writes its report) and kills it if it does not stop. The sim's status lines go to ``log_path``.
    """

    def __init__(self, map_path: str | Path, *, speedup: float, start: Geodetic | None, report_path: Path,
                 log_path: Path, startup_timeout_s: float = 30.0):
        self.map_path = Path(map_path).resolve()
        self.speedup, self.start, self.report_path = speedup, start, Path(report_path).resolve()
        self.log_path, self.startup_timeout_s = Path(log_path), startup_timeout_s
        self.port = 0
        self._proc = None

    def __enter__(self) -> BundledSim:
        import socket
        import subprocess
        import time

        with socket.socket() as probe:  # a free port; the sim binds it a moment later
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        cmd = [sys.executable, "-m", "sim", "--map", str(self.map_path), "--port", str(self.port),
               "--speedup", f"{self.speedup:g}", "--strict", "--origin", "boot", "--report", str(self.report_path)]
        if self.start is not None:
            cmd += ["--start", f"{self.start.lat_deg:.8f},{self.start.lon_deg:.8f}"]
        log.info("starting the sim: %s", " ".join(cmd))
        self._log = open(self.log_path, "w", encoding="utf-8")  # noqa: SIM115 (closed in __exit__)
        # A session of its own: a terminal's Ctrl-C goes to the whole foreground process group, and the sim must
        # keep flying while we land; __exit__ stops it once we are done.
        self._proc = subprocess.Popen(cmd, cwd=Path(__file__).resolve().parent, stdout=self._log,
                                      stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + self.startup_timeout_s
        while time.monotonic() < deadline:
            if self._proc.poll() is not None:
                self.__exit__(None, None, None)
                raise UserError(f"the bundled sim exited at start (code {self._proc.returncode}); see {self.log_path}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return self
            except OSError:
                time.sleep(0.1)
        self.__exit__(None, None, None)
        raise UserError(f"the bundled sim did not start within {self.startup_timeout_s:g} s; see {self.log_path}")

    def __exit__(self, *exc_info) -> None:
        import signal
        import subprocess

        if self._proc is not None and self._proc.poll() is None:
            self._proc.send_signal(signal.SIGINT)
            try:
                self._proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._log.close()

    @property
    def connection(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def report(self) -> dict | None:
        try:
            return json.loads(self.report_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None


def sim_report_summary(report: dict, goal_ne: Sequence[float]) -> str:
    """One line from the sim's truth: where it landed, collisions, clearance, distance, airborne time."""
    landed = report.get("landed")
    where = "not landed"
    if landed:
        error_m = math.hypot(landed["north_m"] - goal_ne[0], landed["east_m"] - goal_ne[1])
        where = f"landed at N {landed['north_m']:.1f} m, E {landed['east_m']:.1f} m ({error_m:.2f} m from the goal)"
    clearance = report.get("min_clearance_m")
    clearance_text = "n/a" if clearance is None else f"{clearance:.1f} m"
    return (
        f"sim report: {where}, {len(report.get('collisions', []))} collisions, "
        f"min clearance {clearance_text}, flown {report.get('distance_flown_m', 0):.1f} m, "
        f"airborne {report.get('airborne_time_s', 0):.1f} s (sim time)"
    )


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
    map_path: str | Path = DEFAULT_MAP,
    planner: str = "grid",
    seed: int = 0,
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
    log_dir: str | Path = "logs",
    out=None,
) -> int:
    """Plan (and, unless ``plan_only``, fly) one mission; returns the process exit code.

    Raises :class:`UserError` for problems the user can fix; :func:`main` prints those.
    """
    out = out or sys.stdout
    if goal_lat is None or goal_lon is None:
        raise UserError("give the goal as --goal_lat DEG --goal_lon DEG")
    if (start_lat is None) != (start_lon is None):
        raise UserError("give both --start_lat and --start_lon, or neither (start at the map's home)")
    check_numbers(goal_lat=goal_lat, goal_lon=goal_lon, start_lat=start_lat, start_lon=start_lon, alt=alt,
                  safety=safety, goal_alt=goal_alt, seed=seed, port=port, speedup=speedup, timeout=timeout,
                  arm_timeout=arm_timeout, link_timeout=link_timeout)
    if goal_alt is not None and planner not in PLANNERS_3D:
        raise UserError(f"--goal_alt needs a 3D planner ({' or '.join(PLANNERS_3D)}), not {planner}")
    if plot and not Path(plot).resolve().parent.is_dir():
        raise UserError(f"cannot write the plot {plot}: {Path(plot).resolve().parent} is not a directory")
    setting = load_setting(map_path, alt, safety)
    goal_ne = geodetic_to_ned(Geodetic(goal_lat, goal_lon, 0.0), setting.home)[:2]
    if not plan_only:
        if start_lat is not None and not sim:
            raise UserError("--start_lat/--start_lon need --plan-only or --sim: a real vehicle starts where it is")
        # Refuse a bad goal before connecting, let alone arming.
        check_endpoint(setting, "goal", *goal_ne, on_map_only=goal_alt is not None)
        make_log_dir(log_dir)
        options = dict(planner=planner, goal_alt_m=goal_alt, seed=seed, heartbeat_timeout_s=timeout,
                       arm_timeout_s=arm_timeout, link_lost_timeout_s=link_timeout, log_dir=log_dir, plot=plot,
                       out=out)
        if not sim:
            return fly(setting, goal_ne, connection=connection or f"tcp:{host}:{port}", **options)
        import time

        stamp = time.strftime("%Y%m%d-%H%M%S")
        start = None if start_lat is None else Geodetic(start_lat, start_lon, 0.0)
        bundled = BundledSim(map_path, speedup=speedup, start=start,
                             report_path=Path(log_dir) / f"sim-report-{stamp}.json",
                             log_path=Path(log_dir) / f"sim-{stamp}.txt")
        with bundled:
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
    plan = make_plan(setting, start_ne, goal_ne, planner, goal_alt_m=goal_alt, seed=seed)
    if json_output:
        json.dump(plan_document(setting, plan, start_ne, goal_ne), out)
        out.write("\n")
    else:
        print_plan(plan, out)
    if plot:
        save_plot(plot, setting, plan)
        if not json_output:
            print(f"plot written to {plot}", file=out)
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
    where.add_argument("--safety", type=float, default=5.0, help="minimum distance to buildings in metres")
    where.add_argument("--start_lat", type=float,
                       help="start latitude (with --plan-only or --sim; default: the map's home)")
    where.add_argument("--start_lon", type=float,
                       help="start longitude (with --plan-only or --sim; default: the map's home)")
    where.add_argument("--goal_alt", type=float, help="goal altitude in metres, e.g. a rooftop (grid3d planner)")
    how = parser.add_argument_group("how to plan")
    how.add_argument("--map", dest="map_path", default=str(DEFAULT_MAP), help="colliders.csv map file")
    how.add_argument("--planner", choices=PLANNERS, default="grid", help="planning algorithm")
    how.add_argument("--seed", type=int, default=0, help="random seed for sampling planners")
    link = parser.add_argument_group("the vehicle")
    link.add_argument("--connection", help="pymavlink connection string, e.g. tcp:127.0.0.1:5760 or "
                      "udpin:0.0.0.0:14540 (default: tcp:HOST:PORT)")
    link.add_argument("--host", default="127.0.0.1", help="autopilot host (classic flag; see --connection)")
    link.add_argument("--port", type=int, default=5760, help="autopilot TCP port (classic flag)")
    link.add_argument("--sim", action="store_true", help="start the bundled simulator, fly against it, stop it")
    link.add_argument("--speedup", type=float, default=5.0, help="with --sim: simulated seconds per wall second")
    link.add_argument("--timeout", type=float, default=15.0, help="seconds to wait for the autopilot's heartbeat")
    link.add_argument("--arm-timeout", dest="arm_timeout", type=float, default=60.0,
                      help="seconds to keep asking to arm while the autopilot is not ready")
    link.add_argument("--link-timeout", dest="link_timeout", type=float, default=30.0,
                      help="seconds to wait for a link lost in flight to come back before giving up "
                      "(the autopilot's own failsafe then owns the vehicle)")
    link.add_argument("--log-dir", dest="log_dir", default="logs", help="where navigation logs and tlogs go")
    output = parser.add_argument_group("output")
    output.add_argument("--plan-only", dest="plan_only", action="store_true", help="plan and print; no drone")
    output.add_argument("--json", dest="json_output", action="store_true", help="print the plan as one JSON object")
    output.add_argument("--plot", metavar="FILE.png", help="draw the map, plan (and flown track) to a PNG")
    output.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = vars(build_parser().parse_args(argv))
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


if __name__ == "__main__":
    sys.exit(main())
