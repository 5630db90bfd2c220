"""The exploring half of the command line (``--explore RADIUS_M``): no goal; explore, collect, map, come home.

``python motion_planning.py --explore 120 [--map KNOWN.csv] [--explore-time S] [--save-map OUT.csv]
[--plot FILE.png]``: the map may be empty (only the home line and the header) or partial. The vehicle takes off
where it stands, explores the disk of RADIUS_M round it at ``--alt`` with ``--safety``
(:mod:`skyroute.flight.exploration` on :mod:`skyroute.planning.explore`), visits every ground target it is told
of (LANDING_TARGET), flies home, lands, disarms, and prints coverage, targets found and visited, distance and time.

``--save-map`` writes what it knows in the ``colliders.csv`` format (:func:`save_map`), the input of a normal
mission: the known map's boxes, then the observed obstacle cells merged into boxes. The sensor sees walls at the
flight altitude only, not their tops: observed boxes stand on the ground and are ``2 x --alt`` tall (at least
``--alt + 1`` m), so any mission at ``--alt`` or below treats them as solid.
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import numpy as np

from skyroute.cli.exits import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, UserError
from skyroute.cli.flying import interrupted_outcome, open_logs
from skyroute.frames import Geodetic
from skyroute.maps import MapFormatError, read_colliders

log = logging.getLogger("motion_planning")

#: Default time budget of --explore-time (autopilot seconds from takeoff).
DEFAULT_EXPLORE_TIME_S = 3600.0


def camera_footprint_m(altitude_m: float) -> float:
    """Radius (m) of the ground a downward camera with a 30 degree half angle sees from ``altitude_m``, plus 2 m
    (the issue's footprint): the explorer sweeps the streets with it to find the targets.

    >>> round(camera_footprint_m(5.0), 2)
    4.89
    """
    return altitude_m * math.tan(math.radians(30.0)) + 2.0


def observed_height_m(altitude_m: float) -> float:
    """Height written for observed boxes: twice the flight altitude, at least ``altitude_m + 1``."""
    return max(2.0 * altitude_m, altitude_m + 1.0)


def save_map(path: str | Path, lat0_deg: float, lon0_deg: float, known: np.ndarray, observed: np.ndarray) -> int:
    """Write ``known`` then ``observed`` boxes (``(N, 6)`` each) as a colliders file; the number of rows."""
    from skyroute.citygen import write_colliders

    rows = np.vstack([np.asarray(known, float).reshape(-1, 6), np.asarray(observed, float).reshape(-1, 6)])
    try:
        write_colliders(path, rows, lat0_deg, lon0_deg)
    except OSError as exc:
        raise UserError(f"cannot write the map {path}: {exc.strerror or exc}") from None
    return len(rows)


def check_explore_options(radius_m: float, explore_time_s: float, save_map_path: str | None) -> None:
    """Refuse what cannot be explored before connecting."""
    if not (math.isfinite(radius_m) and 1.0 <= radius_m <= 2000.0):
        raise UserError(f"--explore must be >= 1 and <= 2000 m, got {radius_m}")
    if not (math.isfinite(explore_time_s) and 0.0 < explore_time_s <= 86_400.0):
        raise UserError(f"--explore-time must be > 0 and <= 86400 s, got {explore_time_s}")
    if save_map_path and not Path(save_map_path).resolve().parent.is_dir():
        raise UserError(f"cannot write the map {save_map_path}: {Path(save_map_path).resolve().parent} is not a "
                        "directory")


def load_known_map(map_path: str | Path):
    """The known map (may hold no boxes); map problems become :class:`UserError`."""
    try:
        return read_colliders(map_path, allow_empty=True)
    except MapFormatError as exc:
        raise UserError(f"bad map file {exc}") from None
    except OSError as exc:
        raise UserError(f"cannot read map file {map_path}: {exc.strerror or exc}") from None


def explore(
    map_path: str | Path, *, radius_m: float, explore_time_s: float, altitude_m: float, safety_m: float,
    connection: str, heartbeat_timeout_s: float, arm_timeout_s: float, link_lost_timeout_s: float = 30.0,
    target_system: int | None = None, signing_key: str | None = None, ground_amsl_m: float | None = None,
    quiet: bool = False, log_dir: str | Path, plot: str | None = None, save_map_path: str | None = None,
    out=None,
) -> int:
    """Connect, explore, come home; the exit code (problems before takeoff raise :class:`UserError`)."""
    from skyroute import vehicle as vehicle_mod
    from skyroute.flight import exploration
    from skyroute.flight import mission as mission_mod
    from skyroute.planning.clearance import Clearance
    from skyroute.planning.errors import PlanningError
    from skyroute.planning.explore import ExploreArea, Explorer

    out = out or sys.stdout
    check_explore_options(radius_m, explore_time_s, save_map_path)

    def say(line: str) -> None:
        if not quiet:
            print(line, file=out, flush=True)

    city = load_known_map(map_path)
    home = Geodetic(city.lat0_deg, city.lon0_deg, 0.0)
    key = None
    if signing_key is not None:
        try:
            key = vehicle_mod.signing_key(signing_key)
        except ValueError as exc:
            raise UserError(f"--signing-key: {exc}") from None
    geometry = Clearance(city.obstacles, safety_m)
    explorers: list[Explorer] = []

    def make_explorer(north_m: float, east_m: float) -> Explorer:
        area = ExploreArea(city.obstacles, (north_m, east_m), radius_m, altitude_m, safety_m,
                           camera_radius_m=camera_footprint_m(altitude_m))
        explorers.append(Explorer(area))
        say(f"exploring {radius_m:g} m round ({north_m:.1f} N, {east_m:.1f} E) for up to {explore_time_s:g} s")
        return explorers[-1]

    def clearance(north_m, east_m, alt_m, dn, de, max_m) -> float:
        clear = geometry.ray_m(north_m, east_m, alt_m, dn, de, max_m)
        if explorers:
            clear = min(clear, explorers[-1].clearance_m(north_m, east_m, dn, de, max_m))
        return clear

    nav_path, tlog_path, handler = open_logs(log_dir)
    root = logging.getLogger()
    saved_levels = [(root, root.level)] + [(h, h.level) for h in root.handlers]
    root.addHandler(handler)
    if root.level > logging.INFO or root.level == logging.NOTSET:
        root.setLevel(logging.INFO)
        for other in root.handlers:
            if other is not handler and other.level == logging.NOTSET:
                other.setLevel(logging.WARNING)
    try:
        say(f"connecting to {connection} ...")
        try:
            drone = vehicle_mod.MavlinkVehicle(connection, heartbeat_timeout_s=heartbeat_timeout_s,
                                               tlog_path=tlog_path, target_system=target_system, signing_key=key)
        except (vehicle_mod.BadConnection, vehicle_mod.SigningRequired) as exc:
            raise UserError(str(exc)) from None
        except vehicle_mod.VehicleError as exc:
            raise UserError(f"no autopilot answered on {connection}: {exc}") from None
        mission = None
        code = EXIT_OK
        try:
            say(f"connected (system {drone.target[0]}); logs in {nav_path} and {tlog_path}")
            mission = exploration.ExplorationMission(
                drone, make_explorer, explore_time_s=explore_time_s, altitude_m=altitude_m, map_origin=home,
                no_path_errors=(PlanningError,), vehicle_errors=(vehicle_mod.VehicleError,),
                surface_fn=geometry.surface_m, ground_amsl_m=ground_amsl_m, clearance_fn=clearance, progress=say,
                arm_timeout_s=arm_timeout_s, link_lost_timeout_s=link_lost_timeout_s, reach_m=radius_m,
            )
            try:
                result = mission.run()
                print(f"exploration complete: {mission.stats.summary()}; flown {result.flown_length_m:.1f} m, "
                      f"airborne {result.airborne_s:.1f} s, landed {result.landing_error_m:.2f} m from home",
                      file=out)
            except (mission_mod.NotReady, mission_mod.ArmingFailed, mission_mod.NoPathFound,
                    mission_mod.PlanningFailed) as exc:
                raise UserError(str(exc)) from None
            except mission_mod.MissionError as exc:
                if not any(new is mission_mod.MissionState.TAKEOFF for _, _, new in mission.result.history):
                    raise UserError(str(exc)) from None
                print(f"error: exploration failed: {exc}", file=sys.stderr)
                print(f"explored: {mission.stats.summary()}", file=out)
                result, code = exc.result, EXIT_FAILED
            except KeyboardInterrupt:
                print(f"interrupted: {interrupted_outcome(mission)}", file=sys.stderr)
                result, code = mission.result, EXIT_INTERRUPTED
        finally:
            drone.close()
        if explorers:
            area = explorers[-1].area
            if save_map_path:
                observed = area.occupied_boxes(observed_height_m(altitude_m))
                rows = save_map(save_map_path, city.lat0_deg, city.lon0_deg, city.obstacles, observed)
                print(f"map written to {save_map_path}: {rows} boxes ({len(observed)} observed)", file=out)
            if plot:
                save_exploration_plot(plot, area, mission, None if result is None else result.track)
                print(f"plot written to {plot}", file=out)
        return code
    finally:
        root.removeHandler(handler)
        handler.close()
        for logger_or_handler, level in saved_levels:
            logger_or_handler.setLevel(level)


def save_exploration_plot(path, area, mission, track) -> None:
    """The explored area, what was seen, the frontiers left, the targets and the track."""
    from skyroute.view import plotting

    targets = np.array([[t.north_m, t.east_m, float(t.collected)] for t in mission.stats.targets]).reshape(-1, 3)
    plotting.save_exploration_figure(
        path, known=area.known, hits=area.live.hits, frontiers=area.frontiers(), disk=area.disk,
        north_offset=area.north_offset, east_offset=area.east_offset, targets=targets,
        track_ne=None if track is None or len(track) == 0 else np.asarray(track)[:, 1:3],
        start_ne=area.start_ne, radius_m=area.radius_m)


def run_exploration(options: dict) -> int:
    """``main.run``'s exploration branch: its keyword arguments in, the exit code out."""
    o = options
    if o["explore"] is None:
        raise UserError("--explore-time and --save-map need --explore RADIUS_M")
    if o["goal_lat"] is not None or o["goal_lon"] is not None:
        raise UserError("--explore takes no goal: give either --explore RADIUS_M or --goal_lat/--goal_lon")
    if o["plan_only"] or o["json_output"] or o["export"] or o["view"] is not None:
        raise UserError("--explore flies: not with --plan-only, --json, --export or --view")
    if o["start_lat"] is not None or o["start_lon"] is not None:
        raise UserError("--explore starts where the vehicle stands: no --start_lat/--start_lon")
    if o["no_replan"]:
        raise UserError("--explore flies by what the vehicle senses: not with --no-replan")
    if o["sim_map"] is not None and not o["sim"]:
        raise UserError("--sim-map needs --sim (it is the bundled simulator's city)")
    if o["sim_map"] is not None and not Path(o["sim_map"]).is_file():
        raise UserError(f"--sim-map {o['sim_map']}: no such file")
    for name, low in (("alt", 0.0), ("safety", 0.0), ("timeout", 0.0), ("arm_timeout", 0.0),
                      ("link_timeout", 0.0), ("speedup", 0.0)):
        value = o[name]
        if not (math.isfinite(value) and value >= low and (value > 0 or name == "safety")):
            raise UserError(f"--{name.replace('_', '-')} must be a finite number > 0, got {value}")
    explore_time = DEFAULT_EXPLORE_TIME_S if o["explore_time"] is None else o["explore_time"]
    check_explore_options(o["explore"], explore_time, o["save_map"])
    if o["plot"] and not Path(o["plot"]).resolve().parent.is_dir():
        raise UserError(f"cannot write the plot {o['plot']}: {Path(o['plot']).resolve().parent} is not a directory")
    from skyroute.cli.flying import make_log_dir
    from skyroute.cli.main import DEFAULT_MAP

    map_path = o["map_path"] if o["map_path"] is not None else DEFAULT_MAP
    load_known_map(map_path)  # refuse a bad map before connecting
    make_log_dir(o["log_dir"])
    kwargs = dict(radius_m=o["explore"], explore_time_s=explore_time, altitude_m=o["alt"], safety_m=o["safety"],
                  heartbeat_timeout_s=o["timeout"], arm_timeout_s=o["arm_timeout"],
                  link_lost_timeout_s=o["link_timeout"], target_system=o["target_system"],
                  signing_key=o["signing_key"], ground_amsl_m=o["ground_amsl"], quiet=o["quiet"],
                  log_dir=o["log_dir"], plot=o["plot"], save_map_path=o["save_map"], out=o["out"])
    if not o["sim"]:
        connection = o["connection"] or f"tcp:{o['host']}:{o['port']}"
        return explore(map_path, connection=connection, **kwargs)
    import time

    from skyroute.cli.bundled_sim import BundledSim, sim_report_summary

    stamp = time.strftime("%Y%m%d-%H%M%S")
    bundled = BundledSim(o["sim_map"] or map_path, speedup=o["speedup"], start=None,
                         report_path=Path(o["log_dir"]) / f"sim-report-{stamp}.json",
                         log_path=Path(o["log_dir"]) / f"sim-{stamp}.txt")
    with bundled:
        if not o["quiet"]:
            print(f"started the bundled sim on {bundled.connection} at {o['speedup']:g}x speed (it flies in the "
                  f"{'--sim-map' if o['sim_map'] else '--map'} given)", file=o["out"], flush=True)
        code = explore(map_path, connection=bundled.connection, **kwargs)
    report = bundled.report()
    if report is not None:
        print(sim_report_summary(report, (0.0, 0.0)), file=o["out"])
    return code
