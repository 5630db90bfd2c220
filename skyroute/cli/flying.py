"""The flying half of the command line: logs, connect, run the mission, turn its outcome into an exit code."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skyroute.cli.exits import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_NO_PATH, EXIT_OK, UserError
from skyroute.cli.setting import Setting, make_plan, plan_summary, save_plot
from skyroute.cli.view_export import open_view, write_exports
from skyroute.planning.errors import PlanningError
from skyroute.planning.plan import Plan

log = logging.getLogger("motion_planning")

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
    run = 1
    while nav_path.exists() or tlog_path.exists():  # a second run in the same second keeps the first one's logs
        run += 1
        nav_path, tlog_path = log_dir / f"navlog-{stamp}-{run}.txt", log_dir / f"flight-{stamp}-{run}.tlog"
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
    target_system: int | None = None,
    signing_key: str | None = None,
    ground_amsl_m: float | None = None,
    quiet: bool = False,
    log_dir: str | Path,
    plot: str | None,
    view_port: int | None = None,
    exports: Sequence[str] | None = None,
    replan: bool = True,
    scan_match: bool = True,
    out,
) -> int:
    """Connect, wait for the vehicle, plan from where it is, arm, take off, fly, land at the goal, disarm.

    Returns the exit code; problems before takeoff raise :class:`UserError`. Whatever happens after takeoff,
    the mission lands (or holds, or leaves a vehicle whose link stayed lost to its failsafe) before this returns,
    and says so. Progress lines go to ``out`` unless ``quiet``. With ``replan`` (the default) and an autopilot that
    streams obstacle data, the path is checked against what the sensor shows and replanned round it
    (:func:`obstacle_map`); with ``scan_match`` too (the default), the scans also measure how far the GPS estimate
    is off from where the map's buildings show (:func:`position_fix`), and the mission flies with that correction.
    """
    from skyroute import vehicle as vehicle_mod
    from skyroute.flight import mission as mission_mod
    from skyroute.planning.clearance import Clearance

    def say(line: str) -> None:
        if not quiet:
            print(line, file=out, flush=True)

    key = None
    if signing_key is not None:
        try:
            key = vehicle_mod.signing_key(signing_key)
        except ValueError as exc:
            raise UserError(f"--signing-key: {exc}") from None
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
    view = None

    obstacles = obstacle_map(setting, goal_ne, planner) if replan else None
    fix = position_fix(setting) if replan and scan_match else None

    def plan_from(start_north_m: float, start_east_m: float) -> np.ndarray:
        if obstacles is not None and obstacles.live.hits.any():  # from the air, after an outage: the live grid
            return obstacles.replan((start_north_m, start_east_m)).waypoints
        try:
            plan = make_plan(
                setting, (start_north_m, start_east_m), goal_ne, planner,
                goal_alt_m=goal_alt_m, seed=seed, snap_start=True,
            )
        except UserError as exc:
            raise PlanRefused(exc) from None
        log.info(plan_summary(plan))
        plans.append(plan)
        if obstacles is not None:  # the map's route: where the map, once wrong, is likeliest to be wrong again
            obstacles.suspect_route(plan.waypoints)
        return plan.waypoints

    geometry = Clearance(setting.city.obstacles, setting.safety_m)

    def clearance(north_m, east_m, altitude_m, direction_north, direction_east, max_m) -> float:
        """The map's clearance, and the observed obstacles' when sensing."""
        reach = geometry.ray_m(north_m, east_m, altitude_m, direction_north, direction_east, max_m)
        if obstacles is None or not obstacles.live.hits.any():
            return reach
        return min(reach, obstacles.clearance_m(north_m, east_m, direction_north, direction_east, reach))

    observed: dict = {}  # the observed obstacles' boxes, made once per version of the layer (1.5 ms each on SF)

    def room(points_ne: np.ndarray, altitude_m: float) -> np.ndarray:
        """How far each point stands from the map's buildings, and from the observed obstacles when sensing."""
        distance = geometry.distance_m(points_ne, altitude_m)
        if obstacles is None or not obstacles.live.hits.any():
            return distance
        key = (obstacles.version, altitude_m)
        if observed.get("key") != key:
            observed.update(key=key, boxes=Clearance(obstacles.live.hit_boxes(altitude_m), setting.safety_m))
        return np.minimum(distance, observed["boxes"].distance_m(points_ne, altitude_m))

    try:
        view = open_view(view_port, setting, goal_ne, out)
        say(f"connecting to {connection} ...")
        try:
            drone = vehicle_mod.MavlinkVehicle(
                connection, heartbeat_timeout_s=heartbeat_timeout_s, tlog_path=tlog_path,
                target_system=target_system, signing_key=key,
            )
        except (vehicle_mod.BadConnection, vehicle_mod.SigningRequired) as exc:
            raise UserError(str(exc)) from None
        except vehicle_mod.VehicleError as exc:
            raise UserError(f"no autopilot answered on {connection}: {exc}") from None
        try:
            name = {"PX4": "a PX4", "ARDUPILOT": "an ArduPilot"}.get(drone.autopilot.name, "a generic MAVLink")
            say(f"connected to {name} autopilot (system {drone.target[0]}); logs in {nav_path} and {tlog_path}")
            mission = mission_mod.Mission(
                drone, plan_from, altitude_m=setting.altitude_m, map_origin=setting.home,
                no_path_errors=(PlanRefused,), vehicle_errors=(vehicle_mod.VehicleError,),
                goal_ne=goal_ne, surface_fn=geometry.surface_m, ground_amsl_m=ground_amsl_m,
                clearance_fn=clearance, room_fn=room, progress=say,
                arm_timeout_s=arm_timeout_s, link_lost_timeout_s=link_lost_timeout_s,
                obstacles=obstacles, position_fix=fix, replan_errors=(PlanningError,),
                replan_margin_m=setting.safety_m, return_line_fn=geometry.highest_crossed,
            )
            if view is not None:
                view.follow(mission, drone)
            try:
                result = mission.run()
            except (mission_mod.NotReady, mission_mod.ArmingFailed) as exc:
                raise UserError(str(exc)) from None
            except mission_mod.NoPathFound as exc:
                cause = exc.__cause__
                if isinstance(cause, PlanRefused):
                    raise UserError(f"{cause.error} (never armed)", cause.error.exit_code) from None
                raise UserError(str(exc), EXIT_NO_PATH) from None
            except mission_mod.MissionError as exc:
                if not any(new is mission_mod.MissionState.TAKEOFF for _, _, new in mission.result.history):
                    raise UserError(f"{exc}") from None  # it never took off: a refusal before takeoff
                print(f"error: mission failed: {exc}", file=sys.stderr)
                if exc.result is not None and plans and plot:
                    save_plot(plot, setting, plans[-1], exc.result.track[:, 1:3], **sensed(mission))
                if exc.result is not None and plans:
                    write_exports(exports, setting, plans[-1], exc.result.track, out)
                return EXIT_FAILED
            except KeyboardInterrupt:
                print(f"interrupted: {interrupted_outcome(mission)}", file=sys.stderr)
                return EXIT_INTERRUPTED
        finally:
            drone.close()
        print(f"mission complete: {result.summary()}", file=out)
        if plot and plans:
            save_plot(plot, setting, plans[-1], result.track[:, 1:3], **sensed(mission))
            print(f"plot written to {plot}", file=out)
        if plans:
            write_exports(exports, setting, plans[-1], result.track, out)
        return EXIT_OK
    finally:
        if view is not None:
            view.close()
        root.removeHandler(handler)
        handler.close()
        for logger_or_handler, level in saved_levels:
            logger_or_handler.setLevel(level)


#: How far below the flight altitude a roof still explains the sensor's readings (m).
FOOTPRINT_BELOW_M = 1.0


def obstacle_map(setting: Setting, goal_ne: Sequence[float], planner: str):
    """The live occupancy layer over the flight's planning grid and its replanner (``skyroute.planning``): the
    map's footprint explains the sensor's readings of its own buildings; a fallback point must be landable (clear
    of every building's margin at every lower altitude). Any-angle replans are pulled taut; every other planner
    (3D ones included: observed obstacles' tops are unknown) replans on the 2D grid at the flight altitude."""
    from skyroute.planning.cspace import create_grid
    from skyroute.planning.livemap import LiveMap
    from skyroute.planning.replan import Replanner

    gm = setting.grid_map
    # Roofs up to a metre below the altitude count too: the vehicle flies that much low at times, and its sensor
    # then sees them (a roof it cannot see only reads farther, which the layer never takes for an obstacle).
    footprint = create_grid(setting.city.obstacles, max(setting.altitude_m - FOOTPRINT_BELOW_M, 0.0), 0.0)[0]
    landable = ~create_grid(setting.city.obstacles, 0.0, setting.safety_m)[0]
    live = LiveMap.for_grid_map(gm, footprint)
    method = "any-angle" if planner == "any-angle" else "grid"
    return Replanner(live, goal_ne, setting.altitude_m, method=method, landable=landable)


def position_fix(setting: Setting):
    """Scan matching against the map's buildings at the flight altitude, and at their own altitude for scans from
    the climb and the descent (``skyroute.planning.scanmatch``)."""
    from skyroute.planning.scanmatch import MapSurface, PositionFix

    return PositionFix(MapSurface(setting.city.obstacles, setting.altitude_m), obstacles=setting.city.obstacles)


def sensed(mission) -> dict:
    """What ``save_plot`` draws of a sensing flight: the observed obstacle cells and the replans."""
    records = list(mission.sensing.records)
    discovered = mission.sensing.discovered_ne()
    if not records and len(discovered) == 0:
        return {}
    return {"discovered_ne": discovered, "replans": [r for r in records if r.waypoints is not None]}


def interrupted_outcome(mission) -> str:
    """What the mission did with the vehicle after Ctrl-C, from its state and history (not assumed)."""
    from skyroute.flight import mission as mission_mod

    state, history = mission.state, mission.result.history
    if state is mission_mod.MissionState.MANUAL:
        if any(new is mission_mod.MissionState.TAKEOFF for _, _, new in history):
            return "the vehicle was landed and disarmed first"
        if any(new is mission_mod.MissionState.ARMING for _, _, new in history):
            return "the vehicle is disarmed on the ground; it never took off"
        return "the vehicle was never armed"
    if state is mission_mod.MissionState.HANDED_OVER:
        return "the vehicle was handed over (to its pilot, or the autopilot's own failsafe)"
    return (f"the mission stopped in state {state.name}: the vehicle may not be on the ground and disarmed; "
            "the autopilot's failsafe owns it")
