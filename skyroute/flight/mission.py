"""The mission: wait for the vehicle, plan, arm, take off, fly the waypoints, land at the goal, disarm.

The state machine is data (:mod:`.states`); :class:`Mission` only talks to an injected vehicle (anything with
the methods of :class:`~.protocol.Vehicle`, e.g. ``vehicle.MavlinkVehicle`` or a test fake) and never imports
pymavlink or the planners.

Order (what real autopilots need): wait until the vehicle is ready (position estimates, home, pre-arm checks;
one progress line every few seconds with the autopilot's own reasons), tie its altitudes to the map's ground
(:mod:`.preflight`), read its limits, plan from where it is, select the flight mode, arm, take off at once (an
idle armed vehicle disarms itself after ~10 s). An arm refusal the autopilot calls permanent while it says it is
ready fails at once with its reason; others are retried until ``arm_timeout_s``.

Frames: waypoints are in the MAP frame (NED at the map's lat0/lon0, altitude 0 at the map's ground) as
``[north_m, east_m, altitude_m, heading_rad]``; the vehicle is commanded in the autopilot's local frame,
``map = local + offset``.

Safety: any failure after the takeoff command lands the vehicle (or holds it, if landing cannot be commanded)
before the error propagates; Ctrl-C in flight lands first and re-raises KeyboardInterrupt, and so does a bug. In
the air, a lost link is ridden out: the autopilot's failsafe owns the vehicle meanwhile; when the link comes back
within ``link_lost_timeout_s`` the mission reads the real state, takes control back and flies on from where the
vehicle is (replanning if it is off the path). A mode we did not ask for is taken back at once (bounded), unless
it is not ours to take: a failsafe the autopilot names as its own (battery, geofence, ...), a return or landing
nothing on our side explains, a pilot's mode (manual, position, altitude) no failsafe explains; those are handed
over. A vehicle found landed and disarmed is never taken off again. One that disarms between takeoff and
touchdown is not commanded any more. A route that leaves the autopilot's geofence is refused before arming.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from skyroute.frames import Geodetic, LocalNED

from . import follower, keepoff, preflight
from .drag import DragEstimate
from .errors import (
    ArmingFailed,
    ControlTakenOver,
    FlightAborted,
    GoalUnreachableInFlight,
    LandedMeanwhile,
    LinkLostInFlight,
    MissionError,
    NoPathFound,
    NotReady,
    OutsideGeofence,
    PlanningFailed,
    VehicleDisarmedInFlight,
)
from .landing import LandingMixin
from .path import RoomFn, SmoothPath, leg_headings, path_length_m, smooth_path
from .protocol import ClearanceFn, Limits, PlanFn, ProgressFn, ReturnLineFn, SurfaceFn, Vehicle
from .recovery import RecoveryMixin, _Abort, _Resumed
from .replanning import ObstacleMap, PositionFix, ReplanningMixin, Sensing, _Blocked, _Rerouted
from .states import AIRBORNE_STATES, TRANSITIONS, IllegalTransition, MissionEvent, MissionState, next_state
from .tilt import TiltBudget, TiltPlan

__all__ = [  # the mission's vocabulary, importable from here
    "TRANSITIONS", "ArmingFailed", "ControlTakenOver", "FlightAborted", "GoalUnreachableInFlight",
    "IllegalTransition", "LandedMeanwhile",
    "LinkLostInFlight", "Mission", "MissionError", "MissionEvent", "MissionResult", "MissionState", "NoPathFound",
    "NotReady", "OutsideGeofence", "PlanningFailed", "Vehicle", "VehicleDisarmedInFlight", "next_state",
]
log = logging.getLogger(__name__)
E, S = MissionEvent, MissionState

#: How many times the GPS's stated horizontal accuracy (GPS_RAW_INT h_acc) the vehicle may be off its estimate,
#: the allowance the sensing makes too (``skyroute.vehicle.sensors.POSITION_ERROR_PER_ACCURACY``).
ACCURACY_SIGMAS = 3.0
#: The share of the margin that error may take before the mission warns (the live layer's cap on its own
#: allowance, ``skyroute.planning.livemap.MAX_TOLERANCE_PER_MARGIN``).
MARGIN_SHARE = 0.7


@dataclass
class MissionResult:
    """What a mission did. Lengths in m, times in s, positions in the map frame.

    ``planned_length_m`` counts the climb from the start to the first waypoint, the waypoint polyline and the
    descent from the last waypoint to the ground; ``flown_length_m`` is the 3D length of ``track`` (rows
    ``[time_s, north_m, east_m, altitude_m]`` from the takeoff command to touchdown). ``landing_error_m`` is the
    horizontal distance from the touchdown point to the goal itself (not the planner's cell). ``airborne_s`` runs
    from liftoff (0.1 m above the start) to touchdown and ``flight_time_s`` from the takeoff command to
    touchdown, both in the autopilot's clock when it reports one (simulated time against a sped-up simulator),
    like the simulator's ``airborne_time_s``; ``track`` times are our own monotonic clock.
    """

    final_state: MissionState
    completed: bool = False
    waypoints: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    planned_length_m: float = math.nan
    flown_length_m: float = math.nan
    flight_time_s: float = math.nan
    airborne_s: float = math.nan
    landing_error_m: float = math.nan
    recoveries: int = 0
    replans: list = field(default_factory=list)
    track: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    history: list[tuple[MissionState, MissionEvent, MissionState]] = field(default_factory=list)

    def summary(self) -> str:
        """One line: planned length, flown length, airborne time, landing error (to the goal)."""
        text = (f"planned {self.planned_length_m:.1f} m, flown {self.flown_length_m:.1f} m, airborne "
                f"{self.airborne_s:.1f} s, landing error {self.landing_error_m:.2f} m from the goal")
        text += f", {self.recoveries} recoveries" if self.recoveries else ""
        return text + (f", {len(self.replans)} replans" if self.replans else "")


class Mission(RecoveryMixin, LandingMixin, ReplanningMixin):
    """Fly ``plan_fn``'s waypoints with ``vehicle``; see the module docstring for the flow and the failures.

    Parameters
    ----------
    vehicle : Vehicle
        Connected vehicle; the mission never closes it.
    plan_fn : PlanFn
        ``(start_north_m, start_east_m) -> ndarray (K, 4)`` map-frame waypoints, called before arming (and again
        from the air to replan after an outage). Altitude NaN means ``altitude_m``; headings are recomputed.
    altitude_m : float
        Flight altitude above the map's ground (m), for waypoints without one.
    map_origin : Geodetic
        The map's lat0/lon0.
    vehicle_errors : tuple of exception types
        What vehicle calls raise on refusal/timeout (e.g. ``vehicle.VehicleError``): arming is retried on these
        and a flight that raises them lands. Required: anything else (a bug) propagates as itself.
    no_path_errors : tuple of exception types
        What ``plan_fn`` raises when there is no path.
    goal_ne : (float, float), optional
        The goal itself (map north, east m), for the landing error; default the last waypoint.
    surface_fn, ground_amsl_m, clearance_fn : optional
        The map's surface height (for the altitude datum, see :mod:`.preflight`), or the map ground's AMSL
        altitude given outright; the clearance along a straight line (bounds the last command, see
        :mod:`.follower`).
    return_line_fn : optional
        The highest building on a straight line home (:data:`~.protocol.ReturnLineFn`): before arming, a route
        from which the autopilot's own return (straight home at its RTL altitude) would meet a building taller than
        that altitude is flown with a warning that says so.
    progress : ProgressFn, optional
        Receives one short line at each step, and every ``progress_every_s`` while waiting or flying.
    arm_timeout_s : float
        How long to wait for the vehicle to get ready and to keep asking it to arm.
    link_lost_timeout_s : float
        How long to wait for a link lost in flight to come back before leaving the vehicle to its failsafe.
    handover_watch_s : float
        How long to follow a vehicle handed over to the autopilot's own return or landing until it is down.
    pilot_grace_s : float
        How long a pilot's mode nothing explains is watched for a return to ours (PX4 leaves its offboard-loss
        fallback by itself once setpoints arrive) before it is handed over.
    reach_m : float
        How far (m) from home the mission may go besides its first route (an exploration's radius): the
        autopilot's geofence must hold that too.
    corner_cut_m, cruise_mps, accel_mps2, lateral_accel_mps2, vertical_mps : float
        The flight path (:func:`~.path.smooth_path`), fitted within the autopilot's own limits before flight.
    room_fn : RoomFn, optional
        What stands round the path (the map's buildings and the observed obstacles, :data:`~.path.RoomFn`): each
        corner's arc is widened within it, keeping the whole margin (``replan_margin_m``) from every obstacle, and
        while the sensor may still find more, never more than half the margin off its legs; the corners are rounded
        again whenever the observed obstacles change. None: every arc keeps within ``corner_cut_m`` of its legs.
    handover_m : float
        The height (m) above the map's surface at the landing point down to which the vehicle descends under our
        setpoints, holding that point, before the autopilot's own landing takes over (:meth:`_come_down`); 0 hands
        over at the flight altitude.
    lead_s, velocity_lag_s : float
        Steering (:func:`~.follower.steer`): the autopilot's response time on top of the link's round trip;
        how far ahead the feed-forward velocity is taken.
    obstacles : ObstacleMap, optional
        The live occupancy layer and its replanner (``skyroute.planning.replan.Replanner``): when given and the
        vehicle streams obstacle data (``vehicle.sensing``), the rest of the path is checked at the sensor rate and
        replanned round what the map does not show (:mod:`.replanning`). None: no replanning.
    position_fix : PositionFix, optional
        Scan matching against the map (``skyroute.planning.scanmatch.PositionFix``): the scans measure how far the
        autopilot's position estimate is off, and the mission places readings and flies with that correction.
    replan_errors : tuple of exception types
        What ``obstacles.replan`` raises when the goal is blocked or cut off (with a ``fallback_ne`` attribute).
    replan_margin_m, max_replans : float, int
        The planning margin (for the braking rule); the most replans in one flight before landing where it is.
    look_again_s : float
        Before giving the goal up as out of reach, hold this long (autopilot seconds) while the sensor looks again,
        then replan once more: a hit seen free again is dropped (a passing reading, a position estimate that
        drifted), and only what is still there ends the mission short of the goal.
    clock, sleep : callables
        Injected for tests (monotonic seconds; sleep seconds).
    """

    def __init__(self, vehicle: Vehicle, plan_fn: PlanFn, *, altitude_m: float, map_origin: Geodetic,
                 vehicle_errors: tuple[type[BaseException], ...],
                 no_path_errors: tuple[type[BaseException], ...] = (NoPathFound,),
                 goal_ne: Sequence[float] | None = None, surface_fn: SurfaceFn | None = None,
                 ground_amsl_m: float | None = None, clearance_fn: ClearanceFn | None = None,
                 room_fn: RoomFn | None = None, progress: ProgressFn | None = None, progress_every_s: float = 5.0,
                 arm_timeout_s: float = 60.0, arm_retry_s: float = 1.0,
                 takeoff_timeout_s: float = 60.0, leg_timeout_s: float = 60.0, min_speed_mps: float = 1.0,
                 landing_timeout_s: float = 120.0, disarm_timeout_s: float = 15.0,
                 link_lost_timeout_s: float = 30.0, handover_watch_s: float = 300.0, pilot_grace_s: float = 2.0,
                 reach_m: float = 0.0,
                 control_retries: int = 3, max_recoveries: int = 10,
                 resume_off_path_m: float = 2.0,
                 goal_tolerance_m: float = 0.3, stop_speed_mps: float = 0.3, settle_s: float = 3.0,
                 trim_gain: float = 0.4, max_trim_m: float = 1.5, stuck_mps: float = 1.0, stuck_s: float = 3.0,
                 altitude_tolerance_m: float = 1.0, handover_m: float = 1.5,
                 corner_cut_m: float = 0.5, cruise_mps: float = 10.0, accel_mps2: float = 3.0,
                 lateral_accel_mps2: float = 3.0, vertical_mps: float = 1.5, lead_s: float = 0.2,
                 velocity_lag_s: float = 0.15, poll_s: float = 0.02, track_interval_s: float = 0.2,
                 obstacles: ObstacleMap | None = None, position_fix: PositionFix | None = None,
                 replan_errors: tuple[type[BaseException], ...] = (),
                 replan_margin_m: float = 5.0, max_replans: int = 200, look_again_s: float = 3.0,
                 return_line_fn: ReturnLineFn | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        if not altitude_m > 0:
            raise ValueError(f"altitude_m must be > 0, got {altitude_m}")
        self.vehicle, self.plan_fn = vehicle, plan_fn
        self.altitude_m, self.map_origin = float(altitude_m), map_origin
        self.no_path_errors = tuple(no_path_errors) + (NoPathFound,)
        self.vehicle_errors = tuple(vehicle_errors)
        self.goal_ne = None if goal_ne is None else (float(goal_ne[0]), float(goal_ne[1]))
        self.surface_fn, self.ground_amsl_m, self.clearance_fn = surface_fn, ground_amsl_m, clearance_fn
        self.room_fn = room_fn
        self.return_line_fn = return_line_fn
        self.progress = progress or (lambda line: None)
        self.progress_every_s = progress_every_s
        self.arm_timeout_s, self.arm_retry_s = arm_timeout_s, arm_retry_s
        self.takeoff_timeout_s, self.leg_timeout_s, self.min_speed_mps = takeoff_timeout_s, leg_timeout_s, min_speed_mps
        self.landing_timeout_s, self.disarm_timeout_s = landing_timeout_s, disarm_timeout_s
        self.link_lost_timeout_s, self.control_retries = link_lost_timeout_s, control_retries
        self.handover_watch_s, self.pilot_grace_s, self.reach_m = handover_watch_s, pilot_grace_s, float(reach_m)
        self.max_recoveries, self.resume_off_path_m = max_recoveries, resume_off_path_m
        self.goal_tolerance_m, self.stop_speed_mps, self.settle_s = goal_tolerance_m, stop_speed_mps, settle_s
        self._near_goal_since = math.nan
        self.trim_gain, self.max_trim_m = trim_gain, max_trim_m
        self.stuck_mps, self.stuck_s, self._stuck_since = stuck_mps, stuck_s, math.nan
        self._trim_m = np.zeros(2)
        self.altitude_tolerance_m, self.corner_cut_m = altitude_tolerance_m, corner_cut_m
        self.handover_m, self._heading_rad, self._coming_down = handover_m, math.nan, False
        self._descent_point: tuple[float, float] | None = None  # the descent over the goal control was lost on
        self.speeds = preflight.Speeds(cruise_mps, accel_mps2, lateral_accel_mps2, vertical_mps)
        self.lead_s, self.velocity_lag_s, self.brake_lag_s = lead_s, velocity_lag_s, 0.0
        self.drag, self._drag_at, self._drag_told = DragEstimate(), math.nan, False
        # what the tilt limit leaves once the wind's drag is held (.tilt): the schedule within it
        self.tilt, self._tilt_plan, self._tilt_binds = TiltBudget(math.inf), None, False
        self._calm_speeds = self.speeds
        self.poll_s, self.track_interval_s = poll_s, track_interval_s
        self.clock, self.sleep = clock, sleep
        # what the sensor reads closer than 80 % of the margin is kept off by shifting the route (.keepoff): a
        # route through the map keeps >= 86 % (its corners' arcs use some of the margin's room)
        self.keep_off = None if obstacles is None else keepoff.KeepOff(0.8 * replan_margin_m,
                                                                        max_shift_m=replan_margin_m)
        self._keep_off_said = False
        self.sensing = Sensing(vehicle, obstacles, clock, position_fix, keep_off=self.keep_off)
        self.replan_errors, self.replan_margin_m, self.max_replans = tuple(replan_errors), replan_margin_m, max_replans
        self.look_again_s = float(look_again_s)
        self.state = MissionState.MANUAL
        self.result = MissionResult(final_state=self.state)
        self.limits: Limits | None = None
        self._offset = LocalNED(0.0, 0.0, 0.0)
        self._ground_amsl_m = 0.0
        self.frame_jump_m, self._frame_jumps, self._frame_checked_s = 3.0, 0, -math.inf
        self._track: list[tuple[float, float, float, float]] = []
        self._takeoff_s = self._takeoff_autopilot_s = self._liftoff_autopilot_s = math.nan
        self._start_altitude_m = 0.0
        self._land_commanded = False
        self._progress_s = 0.0  # arc length reached on the current path
        self._last_line_s = -math.inf

    # ------------------------------------------------------------------------------------------ plumbing
    def _fire(self, event: MissionEvent) -> MissionState:
        new = next_state(self.state, event)
        log.info("%s --%s--> %s", self.state.name, event.name, new.name)
        self.result.history.append((self.state, event, new))
        self.state = self.result.final_state = new
        return new

    def _say(self, line: str, *, every: bool = False) -> None:
        """A progress line (``every``: at most one per ``progress_every_s``)."""
        now = self.clock()
        if every and now - self._last_line_s < self.progress_every_s:
            return
        self._last_line_s = now
        log.info("progress: %s", line)
        self.progress(line)

    def _map_position(self) -> LocalNED:
        """Vehicle position in the map frame (down = -altitude above the map's ground)."""
        t = self.vehicle.telemetry
        cn, ce = self.sensing.correction_ne
        return LocalNED(t.north_m + self._offset.north_m + cn, t.east_m + self._offset.east_m + ce,
                        t.down_m + self._offset.down_m)

    def _flown_position(self) -> LocalNED:
        """The map position less the keep-off shift and lift (:mod:`.keepoff`): where the vehicle is relative to
        the route it follows, which is the route moved by that much."""
        return self._unshifted(self._map_position())

    def _unshifted(self, p: LocalNED) -> LocalNED:
        k = self.keep_off
        if k is None or not (k.shift_ne.any() or k.lift_m):
            return p
        return LocalNED(p.north_m - float(k.shift_ne[0]), p.east_m - float(k.shift_ne[1]), p.down_m + k.lift_m)

    def _keep_off_update(self, path: SmoothPath, q: LocalNED, t, now: float, rate: float, dt_s: float) -> None:
        """Shift the route away from what the sensor reads closer than ``keep_off.keep_m`` (see :mod:`.keepoff`);
        ``q`` is the vehicle relative to the route shifted as it is."""
        if self.keep_off is None or self.keep_off.idle:
            return
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        at = self._progress_s + np.concatenate([[0.0], keepoff.ahead_distances_m(speed)])
        points = np.array([path.point_at(s_m)[0] for s_m in at])
        before = float(np.hypot(*self.keep_off.shift_ne))
        u = self.keep_off.update((t.north_m, t.east_m), points[:, :2] - (q.north_m, q.east_m), now_s=now,
                                 rate=rate, dt_s=dt_s)
        lifted = self.keep_off.lift_m
        lift = self.keep_off.update_lift(q.altitude_m - points[0, 2], now_s=now, rate=rate, dt_s=dt_s)
        if lift >= 1.0 > lifted:
            self._say(f"the rangefinder reads something less than {self.keep_off.keep_m:.1f} m below: the route "
                      f"lifted {lift:.1f} m over it")
        after = float(np.hypot(*u))
        if int(after) > int(before):
            near = self.keep_off.nearest()
            log.info("keep-off: route shifted (%+.1f N, %+.1f E) m at map (%.1f N, %.1f E), %.1f m/s; nearest "
                     "reading %.1f m at %.0f deg", u[0], u[1], q.north_m + u[0], q.east_m + u[1], speed, *near)
        if after >= 1.0 and not self._keep_off_said:
            self._keep_off_said = True
            self._say(f"the sensor reads something closer than {self.keep_off.keep_m:.1f} m where the map "
                      f"and the position estimate have room: keeping off it, the route shifted {after:.1f} m")
        elif after < 0.5 <= before and self._keep_off_said:
            self._keep_off_said = False
            log.info("keep-off: the route is back within 0.5 m of where it was planned")

    def _to_local(self, north_m: float, east_m: float, altitude_m: float) -> LocalNED:
        """The autopilot's local position for a map point: what it must be told to put the vehicle there (with
        scan matching's correction of its estimate, see :attr:`Sensing.correction_ne`)."""
        cn, ce = self.sensing.correction_ne
        return LocalNED(north_m - self._offset.north_m - cn, east_m - self._offset.east_m - ce,
                        -altitude_m - self._offset.down_m)

    def _autopilot_time_s(self) -> float:
        """The autopilot's time since boot (s), NaN if it does not say (flight times are in its clock)."""
        return float(getattr(self.vehicle.telemetry, "local_time_s", math.nan))

    def _hold(self, north_m: float, east_m: float, altitude_m: float, heading_rad: float, seconds: float, *,
              each: Callable[[], None] | None = None, max_ours_s: float = math.inf) -> None:
        """Hold over the map point at ``altitude_m`` for ``seconds`` of the autopilot's time (ours if it gives
        none), streaming the setpoint every poll and calling ``each`` after it; never longer than ``max_ours_s`` of
        our time."""
        target = self._to_local(north_m, east_m, altitude_m)
        start, start_ours = self._autopilot_time_s(), self.clock()
        while True:
            now = self._autopilot_time_s()
            held = now - start if math.isfinite(now) and math.isfinite(start) else self.clock() - start_ours
            if held >= seconds or self.clock() - start_ours > max_ours_s:
                return
            self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading_rad)
            self._tick()
            if each is not None:
                each()

    def _sample(self, force: bool = False) -> None:
        now = self.clock()
        p = self._map_position()
        if math.isnan(self._liftoff_autopilot_s) and self.state is S.TAKEOFF \
                and p.altitude_m > self._start_altitude_m + 0.1:
            self._liftoff_autopilot_s = self._autopilot_time_s()
        if force or not self._track or now - self._track[-1][0] >= self.track_interval_s:
            self._track.append((now, p.north_m, p.east_m, p.altitude_m))

    def _tick(self, wake_on_sensor: bool = False) -> None:
        """One poll: wait (``wake_on_sensor``: until a sensor reading arrives, at most a poll), notice a lost link
        or a lost mode, record the track, notice a disarm in flight."""
        waiter = getattr(self.vehicle, "wait_sensor", None)
        if wake_on_sensor and waiter is not None and self.sensing.active:
            waiter(self.poll_s)
        else:
            self.sleep(self.poll_s)
        if not self.vehicle.link_ok:
            self._link_lost()
        self._sample()
        self._check_armed()
        self._check_local_frame()
        if self.state in (S.TAKEOFF, S.WAYPOINT, S.REPLANNING) and not self.vehicle.in_control \
                and not self._landing_over_goal():
            self._recover(f"the autopilot left our flight mode for {self.vehicle.telemetry.mode or '?'}",
                          link_lost=False)

    def _check_local_frame(self) -> None:
        """Notice the autopilot's local frame jumping under us (an EKF reset, an origin moved to where it armed):
        the offset from the latest positions differs by ``frame_jump_m`` or more twice ``check_s`` apart. Then
        the map is re-tied and the streamed setpoint moved with the frame, so it still means the same place."""
        now = self.clock()
        if now - self._frame_checked_s < 0.25 or not hasattr(self.vehicle, "map_offset_now"):
            return
        self._frame_checked_s = now
        instant = self.vehicle.map_offset_now(self.map_origin, self._ground_amsl_m)
        if instant is None:
            return
        delta = np.subtract(instant, self._offset)
        if float(np.linalg.norm(delta)) < self.frame_jump_m:
            self._frame_jumps = 0
            return
        self._frame_jumps += 1
        if self._frame_jumps < 2:  # once may be a glitch of one sample
            return
        self._frame_jumps = 0
        self._retie(instant)

    def _retie(self, offset: LocalNED) -> None:
        """Take ``offset`` as the map offset if it moved by ``frame_jump_m`` or more, and move the streamed
        setpoint with the frame."""
        delta = np.subtract(offset, self._offset)
        if float(np.linalg.norm(delta)) < self.frame_jump_m:
            return
        log.warning("the autopilot's local frame moved by (%.1f, %.1f, %.1f) m: re-tied to the map", *delta)
        self._say(f"the autopilot's local frame moved by {float(np.linalg.norm(delta)):.1f} m (an estimator reset "
                  "or a new origin): re-tied to the map")
        self._offset = LocalNED(*(float(v) for v in offset))
        if self.keep_off is not None:
            self.keep_off.forget()
        shift = getattr(self.vehicle, "shift_setpoint", None)
        if shift is not None:
            shift(*(-float(v) for v in delta))

    def _check_armed(self, context: str = "") -> None:
        """Raise :class:`VehicleDisarmedInFlight` if the vehicle disarmed between takeoff and touchdown (in
        LANDING a disarm on the ground is the autopilot's auto-disarm after touchdown)."""
        if self.state not in AIRBORNE_STATES:
            return
        t = self.vehicle.telemetry
        if t.armed:
            return
        on_ground = bool(t.on_ground)
        if on_ground and self.state is S.LANDING:
            return
        state, position = self.state, self._map_position()
        self._sample(force=True)
        log.error("the vehicle disarmed %s in state %s at map (%.1f N, %.1f E, %.1f m)",
                  "on the ground" if on_ground else "in the air", state.name, position.north_m, position.east_m,
                  position.altitude_m)
        self._fire(E.DISARMED_IN_FLIGHT)
        self._release()
        raise VehicleDisarmedInFlight(state, position, on_ground, context)

    def _release(self) -> None:
        try:
            self.vehicle.release_control()
        except self.vehicle_errors as exc:
            log.warning("could not release control: %s", exc)

    def _finish(self, error: MissionError | None = None) -> MissionResult:
        r = self.result
        r.replans = list(self.sensing.records)
        self.sensing.log_summary()
        if self.keep_off is not None and (self.keep_off.largest_m > 0 or self.keep_off.highest_m > 0):
            log.info("keep-off: the route was shifted at most %.1f m away from readings closer than %.1f m and "
                     "lifted at most %.1f m", self.keep_off.largest_m, self.keep_off.keep_m, self.keep_off.highest_m)
        r.track = np.array(self._track, float).reshape(-1, 4)
        if len(r.track):
            r.flown_length_m = path_length_m(r.track[:, 1:])
        if error is not None:
            error.result = r
        return r

    # ------------------------------------------------------------------------------------------------ run
    def run(self) -> MissionResult:
        """Fly the mission.

        Returns
        -------
        MissionResult
            ``completed`` True, ``final_state`` MANUAL: landed at the goal, disarmed, control released.

        Raises
        ------
        NotReady, ArmingFailed, NoPathFound, PlanningFailed, OutsideGeofence
            Before takeoff; the vehicle was never armed (or was disarmed).
        FlightAborted
            Something failed after takeoff; the vehicle landed (or holds, if landing could not be commanded).
        VehicleDisarmedInFlight
            A FlightAborted: the vehicle disarmed after takeoff and before touchdown; nothing more was commanded.
        LandedMeanwhile, ControlTakenOver
            After an outage the vehicle had landed and disarmed; a pilot, an operator or the autopilot's own
            failsafe took it over.
        LinkLostInFlight
            The link stayed lost; the autopilot's failsafe owns the vehicle.
        KeyboardInterrupt, or any exception that is not a MissionError nor in ``vehicle_errors`` (a bug)
            Re-raised after landing (in flight) or disarming (on the ground), unless making the vehicle safe
            raised a MissionError, which then replaces it.

        Every MissionError carries ``.result`` (the partial :class:`MissionResult`).
        """
        try:
            self._fire(E.START)
            self._preflight()
            waypoints = self._plan()
            self._arm()
            try:
                self._fly(waypoints)
            finally:
                self._stop_refining()
        except MissionError as exc:
            self._finish(exc)
            raise
        except KeyboardInterrupt:
            log.warning("interrupted in state %s", self.state.name)
            self._abandon("interrupted (Ctrl-C)")
            raise
        except self.vehicle_errors as exc:  # the vehicle failed a request the steps above do not retry
            raise self._vehicle_failed(exc) from exc
        except Exception as exc:  # a bug, not a refusal: make the vehicle safe, then re-raise it unchanged
            log.exception("unexpected error in state %s", self.state.name)
            self._abandon(f"unexpected error {exc!r}")
            raise
        return self._finish()

    def _vehicle_failed(self, exc: Exception) -> MissionError:
        """A vehicle error no step handled (a timeout reading the frame at arming, a link gone mid-request): make
        the vehicle safe, and say what failed where as a MissionError (NotReady on the ground, FlightAborted once
        armed), so the CLI reports one line instead of a traceback."""
        state = self.state.name
        on_the_ground = self.state in (S.MANUAL, S.PREFLIGHT, S.PLANNING, S.ARMING)
        try:
            outcome = self._make_safe(f"the vehicle failed in state {state}")
        except MissionError as unsafe:
            self._finish(unsafe)
            return unsafe
        cls = NotReady if on_the_ground else FlightAborted
        error = cls(f"the vehicle failed in state {state}: {exc}; {outcome}")
        self._finish(error)
        return error

    def _abandon(self, why: str) -> None:
        """Make the vehicle safe after Ctrl-C or a bug; a MissionError from that replaces the original."""
        try:
            outcome = self._make_safe(why)
        except MissionError as exc:
            self._finish(exc)
            raise
        log.warning("%s: %s", why, outcome)
        self._finish()

    # ------------------------------------------------------------------------------------------ on the ground
    def _preflight(self) -> None:
        deadline = self.clock() + self.arm_timeout_s
        self._arm_deadline_s = deadline
        missing = preflight.wait_until_ready(self.vehicle, deadline_s=deadline, clock=self.clock,
                                             sleep=self.sleep, progress=self._say, every_s=self.progress_every_s)
        if missing == "the link was lost":
            self._fire(E.LINK_LOST)
            raise LinkLostInFlight("the link was lost before takeoff; the vehicle is on the ground, never armed")
        if missing is not None:
            self._fire(E.NOT_READY)
            raise NotReady(f"the vehicle did not get ready within {self.arm_timeout_s:g} s: {missing}")
        while True:  # a booting estimator's vertical speed can wander: give "on the ground" until the deadline
            t = self.vehicle.telemetry
            if not t.armed and t.on_ground:
                break
            if self.clock() >= deadline:
                self._fire(E.NOT_READY)
                raise NotReady("the vehicle is " + ("armed" if t.armed else "in the air")
                               + ": a mission starts from a vehicle disarmed on the ground")
            self._say("waiting for the vehicle to stand disarmed on the ground", every=True)
            self.sleep(0.2)
        if self.ground_amsl_m is None:
            ground, surface = preflight.ground_amsl(self.vehicle, self.map_origin, self.surface_fn)
        else:
            ground, surface = float(self.ground_amsl_m), math.nan
        self._offset = self.vehicle.map_offset(self.map_origin, ground)
        self._ground_amsl_m = ground
        self._say(preflight.describe_offset(self._offset, ground, surface if math.isfinite(surface) else 0.0))
        self.limits = self.vehicle.flight_limits()
        self.speeds = self._calm_speeds = preflight.fit_speeds(self.speeds, self.limits)
        self.tilt = TiltBudget(math.radians(float(getattr(self.limits, "max_tilt_deg", math.inf))))
        response_s = float(getattr(self.limits, "response_s", math.nan))
        if math.isfinite(response_s):  # brake as early as the autopilot is slow to slow down
            self.brake_lag_s = max(self.brake_lag_s, response_s)
        if self.limits.leaves_flying:
            self._say(f"warning: {self.limits.link_loss}")
        self._fire(E.READY)

    def _plan(self, start: LocalNED | None = None) -> np.ndarray:
        start = self._map_position() if start is None else start
        self._say(f"planning from map ({start.north_m:.1f} N, {start.east_m:.1f} E) ...")
        try:
            waypoints = np.array(self.plan_fn(start.north_m, start.east_m), dtype=float).reshape(-1, 4)
        except self.no_path_errors as exc:
            self._fire(E.NO_PATH)
            raise NoPathFound(f"no path: {exc}; never armed") from exc
        except Exception as exc:
            self._fire(E.ABORT)
            raise PlanningFailed(f"planning failed: {exc!r}; never armed") from exc
        if len(waypoints) == 0:
            self._fire(E.NO_PATH)
            raise NoPathFound("the planner returned no waypoints; never armed")
        waypoints[np.isnan(waypoints[:, 2]), 2] = self.altitude_m
        waypoints[:, 3] = leg_headings(waypoints)
        r = self.result
        r.waypoints = waypoints
        r.planned_length_m = (math.dist((start.north_m, start.east_m, start.altitude_m), waypoints[0, :3])
                              + path_length_m(waypoints) + waypoints[-1, 2])
        log.info("planned %d waypoints, %.1f m: %s", len(waypoints), r.planned_length_m,
                 " ".join(f"({n:.1f} N, {e:.1f} E, {a:.1f} m)" for n, e, a in waypoints[:, :3]))
        self._check_fence(start, waypoints)
        self._check_return(start, waypoints)
        self._check_accuracy()
        self._fire(E.PLANNED)
        return waypoints

    def _check_return(self, home: LocalNED, waypoints: np.ndarray, step_m: float = 10.0) -> None:
        """Warn, before arming, when the autopilot's own return from somewhere on the route (straight home at its
        RTL altitude above ``home``, or the flight altitude if higher) would meet a building taller than that: a
        failsafe (a lost link, a low battery) would fly the vehicle into it, and only the autopilot's parameter can
        change that (an ArduCopter at RTL_ALT 15 m set down on a 15 m roof on its way home in the sim)."""
        altitude = float(getattr(self.limits, "return_altitude_m", math.nan))
        if self.return_line_fn is None or not math.isfinite(altitude) or len(waypoints) == 0:
            return
        legs = [waypoints[:1, :2]]
        for a, b in zip(waypoints[:-1, :2], waypoints[1:, :2]):
            n = max(int(math.ceil(math.dist(a, b) / step_m)), 1)
            legs.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
        top, (north, east) = self.return_line_fn(np.vstack(legs), (home.north_m, home.east_m))
        flies_at = home.altitude_m + altitude
        if top < max(flies_at, float(waypoints[:, 2].max())):
            return
        self._say(f"warning: the autopilot's own return flies straight home at {altitude:g} m above home "
                  f"({self.limits.return_described}); from parts of this route that line meets a building "
                  f"{top:.0f} m tall at map ({north:.0f} N, {east:.0f} E): a failsafe return from there would fly "
                  "into it unless the return altitude is raised")

    def _check_accuracy(self) -> None:
        """Warn, before arming, when the GPS's stated horizontal accuracy eats most of the margin: the autopilot flies
        its position estimate along the route, so the vehicle itself is off the route by the estimate's error
        (``ACCURACY_SIGMAS`` times the stated accuracy, the allowance the sensing also makes) and keeps that much
        less than the margin from the buildings. Beyond ``MARGIN_SHARE`` of the margin it says so, with the margin
        that would keep the rest."""
        accuracy = float(getattr(self.vehicle.telemetry, "horizontal_accuracy_m", math.nan))
        if not accuracy > 0:  # unknown (NaN) or not stated
            return
        error = ACCURACY_SIGMAS * accuracy
        if error <= MARGIN_SHARE * self.replan_margin_m:
            return
        self._say(f"warning: the GPS states a horizontal accuracy of {accuracy:.1f} m: the {self.replan_margin_m:g} m "
                  f"margin is kept round the position estimate, and the vehicle itself may be {error:.1f} m off it; "
                  f"a --safety of {error / MARGIN_SHARE:.1f} m or more would keep {1 - MARGIN_SHARE:.0%} of the "
                  "margin")

    def _check_fence(self, home: LocalNED, waypoints: np.ndarray) -> None:
        """Refuse, before arming, a route that leaves the autopilot's geofence round ``home`` (where it arms): at
        the breach it would return or land, not fly the mission (ArduCopter SITL did, 150 m out)."""
        fence = getattr(self.limits, "fence", None)
        if fence is None:
            return
        out_m = max(float(np.hypot(waypoints[:, 0] - home.north_m, waypoints[:, 1] - home.east_m).max()),
                    self.reach_m)
        up_m = float((waypoints[:, 2] - home.altitude_m).max())
        if out_m <= fence.radius_m and up_m <= fence.height_m:
            return
        self._fire(E.ABORT)
        what = (f"{out_m:.0f} m from home, the fence allows {fence.radius_m:.0f} m" if out_m > fence.radius_m
                else f"{up_m:.0f} m above home, the fence allows {fence.height_m:.0f} m")
        raise OutsideGeofence(f"the route leaves the autopilot's geofence: it goes {what} ({fence.described}); "
                              "never armed")

    def _arm(self) -> None:
        """Select the flight mode and arm; retry what waiting can change until the readiness deadline."""
        attempts = 0
        while True:
            attempts += 1
            try:
                action = "take the flight mode we arm in"
                self.vehicle.prepare_flight()
                action = "arm"
                self.vehicle.arm()
                break
            except self.vehicle_errors as exc:
                if not self.vehicle.link_ok:
                    self._fire(E.LINK_LOST)
                    raise LinkLostInFlight("the link was lost while arming; the vehicle is on the ground") from exc
                ready = self.vehicle.readiness().ready
                if getattr(exc, "permanent", False) and ready:
                    self._arm_failed()
                    raise ArmingFailed("and says it is ready, so waiting will not help", attempts, str(exc),
                                       action) from exc
                if self.clock() >= self._arm_deadline_s:
                    self._arm_failed()
                    raise ArmingFailed(f"for {self.arm_timeout_s:g} s", attempts, str(exc), action) from exc
                self._say(f"{'arming' if action == 'arm' else 'the flight mode'} refused ({exc}); retrying",
                          every=True)
                self.sleep(min(self.arm_retry_s, max(self._arm_deadline_s - self.clock(), 0.0)))
        self._fire(E.ARMED)
        if hasattr(self.vehicle, "map_offset_now"):  # a frame that moved at arming (a new origin) before takeoff
            self._retie(self.vehicle.map_offset(self.map_origin, self._ground_amsl_m))

    def _arm_failed(self) -> None:
        self._release()
        if self.vehicle.telemetry.armed:
            self._fire(E.ABORT)
            self._disarm()
            self._fire(E.DISARMED)
        else:
            self._fire(E.ARM_FAILED)

    def _disarm(self) -> None:
        deadline = self.clock() + self.disarm_timeout_s
        while self.vehicle.telemetry.armed:
            try:
                self.vehicle.disarm()
            except self.vehicle_errors as exc:
                if self.clock() >= deadline:
                    self._fire(E.DISARM_FAILED)
                    raise MissionError(f"could not disarm within {self.disarm_timeout_s:g} s: {exc}") from exc
                log.info("disarm refused (%s); retrying", exc)
                self.sleep(0.5)

    # ------------------------------------------------------------------------------------------- flight
    def _fly(self, waypoints: np.ndarray) -> None:
        try:
            path = waypoints
            try:
                self._takeoff(float(waypoints[0, 2]))
            except _Resumed:
                path = self._resume_path(waypoints)
            blockage = None
            while True:
                try:
                    if blockage is not None:  # inside the try: control lost while braking for it is resumed too
                        path, blockage = self._replan_in_flight(blockage), None
                    if self._descent_point is not None:
                        self._finish_descent()
                    else:
                        self._follow(path)
                    break
                except _Resumed:
                    blockage = None  # flown on from where the vehicle is; the sensing finds the blockage again
                    if not self._descent_resumable():
                        path = self._resume_path(path)
                except _Blocked as blocked:
                    blockage = blocked.blockage
                except _Rerouted as better:
                    blockage, path = None, better.waypoints
            self._land()
            self._check_reached_goal()
        except MissionError:
            raise
        except (_Abort, *self.vehicle_errors) as exc:
            log.error("flight failed in state %s: %s", self.state.name, exc)
            outcome = self._make_safe(str(exc))
            raise FlightAborted(f"{exc}; {outcome}") from exc
        self.result.completed = True

    def _takeoff(self, altitude_m: float) -> None:
        if self.keep_off is not None:
            self.keep_off.reset()
        here = self._map_position()
        self._start_altitude_m = here.altitude_m
        self._takeoff_s, self._takeoff_autopilot_s = self.clock(), self._autopilot_time_s()
        self._sample(force=True)
        self._command_takeoff(altitude_m - here.altitude_m)
        self._say(f"taking off to {altitude_m:.1f} m")
        deadline = self.clock() + self.takeoff_timeout_s
        while self._map_position().altitude_m < altitude_m - self.altitude_tolerance_m:
            if self.clock() > deadline:
                raise _Abort(f"takeoff did not reach {altitude_m:.1f} m within {self.takeoff_timeout_s:g} s")
            self._tick()
        log.info("takeoff done at %.1f m", self._map_position().altitude_m)
        self._fire(E.TAKEOFF_DONE)

    def _command_takeoff(self, climb_m: float, retries: int = 2) -> None:
        """Command the climb (m), and make sense of a refusal from what the vehicle then does.

        * It climbs: the first command was carried out and its acknowledgement lost, and the repeat was refused
          (ArduCopter answers NAV_TAKEOFF FAILED when already flying): the takeoff goes on. An ArduPilot mission
          of the fault campaign with 10 % loss landed 237 m short, exit 1, that way.
        * It stands disarmed on the ground: the autopilot disarmed itself since it armed (ArduCopter's
          DISARM_DELAY, PX4's COM_DISARM_PRFLT: 10 s armed without a takeoff, reached when a lossy link held up the
          commands between): arm again and repeat it, ``retries`` times at most.
        * Otherwise (armed on the ground, or the link lost) the refusal stands."""
        for attempt in range(retries + 1):
            try:
                self.vehicle.takeoff(climb_m)
                return
            except self.vehicle_errors as exc:
                after = self._after_refusal() if self.vehicle.link_ok else None
                if after == "climbing":
                    self._say(f"takeoff: {exc}, but the vehicle is climbing (an earlier command's answer was lost)")
                    return
                if after != "disarmed" or attempt == retries:
                    raise
                self._say(f"takeoff refused ({exc}): the autopilot disarmed itself on the ground; arming again")
                self.vehicle.prepare_flight()
                self.vehicle.arm()

    def _after_refusal(self, wait_s: float = 1.5) -> str | None:
        """What the vehicle does within ``wait_s`` (s; a heartbeat comes once a second) of a refused takeoff:
        ``"climbing"`` (armed, 0.3 m or more above where it stood, or off the ground), ``"disarmed"`` (on the
        ground), else None."""
        deadline = self.clock() + wait_s
        while True:
            t = self.vehicle.telemetry
            if t.armed and (not t.on_ground or self._map_position().altitude_m > self._start_altitude_m + 0.3):
                return "climbing"
            if not t.armed and t.on_ground:
                return "disarmed"
            if self.clock() >= deadline:
                return None
            self._sample()  # the liftoff may come now
            self.sleep(self.poll_s)

    def _rounded(self, waypoints: np.ndarray) -> SmoothPath:
        """The path the mission flies through ``waypoints`` (map frame): rounded and speed-scheduled at its speeds,
        its corners widened within ``room_fn`` (half a margin off the legs at most while sensing)."""
        s = self.speeds
        return smooth_path(waypoints, corner_cut_m=self.corner_cut_m, cruise_mps=s.cruise_mps,
                           accel_mps2=s.accel_mps2, lateral_accel_mps2=s.lateral_accel_mps2,
                           vertical_mps=s.vertical_mps, room_fn=self.room_fn,
                           room_m=self.replan_margin_m,
                           max_cut_m=0.5 * self.replan_margin_m if self.sensing.active else math.inf,
                           speed_cap_fn=self._tilt_plan.caps_mps if self._tilt_binds else None)

    def _obstacles_version(self) -> int:
        """The observed obstacles' version (``ObstacleMap.version``; 0 without one)."""
        return int(getattr(self.sensing.obstacles, "version", 0))

    def _rounded_again(self, waypoints: np.ndarray, i: int, p) -> SmoothPath:
        """The corners rounded again, for the observed obstacles changed (an arc widened round what stood there
        before may not keep the margin any more), and the vehicle at ``p`` carried over onto the new path: the
        point nearest it between waypoint ``i - 1``'s corner (the last passed) and waypoint ``i``'s."""
        path = self._rounded(waypoints)
        since = float(path.waypoint_s_m[i - 1]) if i > 0 else 0.0
        stretch = float(path.waypoint_s_m[i]) - since + 1.0
        self._progress_s = path.project((p.north_m, p.east_m, p.altitude_m), since, window_m=stretch)
        return path

    def _follow(self, waypoints: np.ndarray) -> None:
        """Fly the rounded path through ``waypoints`` (see :func:`~.follower.steer`) and stop at the last one."""
        s = self.speeds
        path, rounded_at = self._rounded(waypoints), self._obstacles_version()
        last = len(waypoints) - 1
        ref_s, heading = self._progress_s, float(waypoints[0, 3])
        i = int(np.searchsorted(path.waypoint_s_m, self._progress_s, side="right"))
        i = min(max(i, 0), last)
        here = self._map_position()
        deadline, start_s = self._waypoint_deadline(waypoints[i], (here.north_m, here.east_m))
        ff_mps, ff_at = 0.0, self.clock()
        trim_at, self._trim_m = ff_at, np.zeros(2)
        self._near_goal_since = math.nan
        sent_at = -math.inf
        sent = follower.SentCommands()
        shifted_at = ff_at
        tried_goal = False
        while True:
            p = self._map_position()
            q = self._unshifted(p)  # relative to the route as shifted to keep off what reads close
            self._progress_s = path.project((q.north_m, q.east_m, q.altitude_m), self._progress_s)
            while i < last and self._progress_s >= path.waypoint_s_m[i] - 1e-6 and self._on_altitude(path, q):
                self._reached(i, last, path, p)
                i += 1
                deadline, start_s = self._waypoint_deadline(waypoints[i], waypoints[i - 1])
            if i == last and self._at_goal(waypoints[last]):
                if self._viewpoint_ne is not None:  # look from here; flies on to the goal, a viewpoint or a fallback
                    self._at_viewpoint(p)
                if self._target_ne is not None and not tried_goal:  # at the fallback point: the goal once more
                    tried_goal = True
                    self._goal_again(p)
                self._reached(i, last, path, p)
                if self._last_leg():  # the landing follows: come down over the goal first
                    self._come_down(*self._landing_point(waypoints[last]))
                self._fire(E.GOAL_REACHED)
                return
            if self.clock() > deadline:
                raise _Abort(self._not_reached(i, waypoints[i], i == last, deadline - start_s))
            self._sense(p, waypoints, i)
            self._reroute_if_reopened(p, waypoints, i)
            self._take_refined(p, waypoints, i)
            if self.room_fn is not None and self._obstacles_version() != rounded_at:
                path, rounded_at = self._rounded_again(waypoints, i, p), self._obstacles_version()
                ref_s = self._progress_s
            if self.clock() - sent_at < 0.9 * self.poll_s:  # woken early by a reading: checked, nothing to send
                self._tick(wake_on_sensor=True)
                continue
            sent_at = self.clock()
            t = self.vehicle.telemetry
            velocity = (t.local_v_north_mps, t.local_v_east_mps, -t.local_v_down_mps)
            rate = self._autopilot_rate()
            now = self.clock()
            self._keep_off_update(path, q, t, now, rate, rate * (now - shifted_at))
            shifted_at, q = now, self._unshifted(p)
            # the link's round trip is flown on the setpoints already sent (a Smith predictor); the poll is ahead
            round_trip_s = float(getattr(self.vehicle, "round_trip_s", 0.0) or 0.0)
            sent.drop_older(now - round_trip_s - self.poll_s)
            predicted, predicted_v = follower.predict_over_link(
                (q.north_m, q.east_m, q.altitude_m), velocity, sent.commands, now_s=now, rate=rate,
                down_s=0.5 * rate * round_trip_s, up_s=0.5 * rate * round_trip_s,
                response_s=max(self.brake_lag_s, self.velocity_lag_s), accel_mps2=s.accel_mps2)
            delay_s = rate * self.poll_s
            ahead_s = self.lead_s + delay_s
            drag_1_s = self._learn_air(t, velocity, rate, now)
            path = self._fit_to_tilt(path)
            s = self.speeds
            sp = follower.steer(path, s_m=self._progress_s, ref_s_m=ref_s, position=predicted,
                                velocity=predicted_v, ahead_s=ahead_s, accel_mps2=s.accel_mps2,
                                velocity_lag_s=self.velocity_lag_s, brake_lag_s=self.brake_lag_s,
                                heading_rad=heading, limits=self.limits,
                                clearance_fn=self.clearance_fn, previous_mps=ff_mps, dt_s=rate * (now - ff_at),
                                speed_cap_mps=self._sight_cap_mps(p, path.point_at(self._progress_s)[1]),
                                delay_s=delay_s, drag_1_s=drag_1_s)
            ref_s, heading = sp.ref_s, sp.heading_rad
            self._heading_rad = heading
            ff_mps, ff_at = (0.0 if sp.velocity is None else float(np.linalg.norm(sp.velocity))), now
            sent.add(now, sp.velocity)
            position = sp.position
            if sp.velocity is None and i == last:  # holding over the goal: take out the autopilot's steady offset
                position = self._trim(waypoints[last], q, t, rate * (now - trim_at))
            trim_at = now
            if self.keep_off is not None:
                position = np.array(position, float)
                position[:2] += self.keep_off.shift_ne
                position[2] += self.keep_off.lift_m
            target = self._to_local(*position)
            velocity_ned = None if sp.velocity is None else (float(sp.velocity[0]), float(sp.velocity[1]),
                                                             float(-sp.velocity[2]))
            if sp.acceleration is None or velocity_ned is None:
                self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading,
                                        velocity_ned=velocity_ned)
            else:
                a = sp.acceleration
                self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading,
                                        velocity_ned=velocity_ned, accel_ned=(float(a[0]), float(a[1]), float(-a[2])))
            self._setpoint_sent()
            self._say(self._flying_line(path, t), every=True)
            self._check_following(ff_mps, t)
            self._tick(wake_on_sensor=True)

    def _landing_point(self, end: np.ndarray) -> tuple[float, float]:
        """Where to come down (map north, east m): the goal itself when the route ends in its 1 m cell (the
        planners end routes at the goal cell's centre, up to 0.71 m off the goal; a free cell keeps the margin
        over its whole square, so the hop within it is clear), else the route's end (a fallback point)."""
        if self.goal_ne is not None and math.dist(self.goal_ne, (end[0], end[1])) <= math.sqrt(0.5) + 1e-6:
            return self.goal_ne
        return float(end[0]), float(end[1])

    def _last_leg(self) -> bool:
        """Whether the landing follows the leg :meth:`_follow` flies (a mission's always does)."""
        return True

    def _learn_air(self, t, velocity, rate: float, now: float) -> float:
        """Learn the vehicle's drag (:class:`~.drag.DragEstimate`) and the wind's lean (:class:`~.tilt.TiltBudget`)
        from this sample (telemetry without an attitude teaches nothing) and return the drag (1/s) to send as a
        feed-forward; 0 for an autopilot that does not take an acceleration as one
        (``limits.acceleration_feedforward``)."""
        sampled_at = float(getattr(t, "local_time_s", math.nan))  # the autopilot's clock: a sample once
        if not math.isfinite(sampled_at):
            sampled_at = rate * now
        if sampled_at != self._drag_at:
            dt_s = 0.0 if math.isnan(self._drag_at) else sampled_at - self._drag_at
            dt_s = dt_s if dt_s <= 0.5 else 0.0  # a gap (a hold) starts afresh
            self._drag_at = sampled_at
            attitude = [float(getattr(t, name, math.nan)) for name in ("roll_rad", "pitch_rad", "heading_rad")]
            self.drag.update(*attitude, velocity, dt_s)
            self.tilt.update(*attitude, velocity, dt_s, drag_1_s=self.drag.fitted_1_s)
        k = self.drag.k_1_s
        if not getattr(self.limits, "acceleration_feedforward", False):
            return 0.0
        if k > 0 and not self._drag_told:
            self._drag_told = True
            log.info("drag learnt from the attitude: %.2f m/s^2 per m/s; its lean goes with each setpoint as a "
                     "feed-forward acceleration", k)
        return k

    def _fit_to_tilt(self, path: SmoothPath) -> SmoothPath:
        """``path`` with its speeds scheduled again when what the tilt limit leaves after the wind's drag
        (:meth:`~.tilt.TiltBudget.plan`) has changed enough to matter (0.3 m/s^2 of the wind's lean, a tenth of the
        drag); the schedule as planned while it caps nothing."""
        plan = self.tilt.plan(self._calm_speeds)
        old = self._tilt_plan
        if plan is None or (old is not None and math.dist(plan.wind_lean_ne, old.wind_lean_ne) < 0.3
                            and abs(plan.drag_1_s - old.drag_1_s) < max(0.1 * old.drag_1_s, 0.02)):
            return path
        self._tilt_plan = plan
        binds = plan.speeds != self._calm_speeds or plan.binds(self._calm_speeds.cruise_mps)
        if not binds and not self._tilt_binds:
            return path
        if binds and not self._tilt_binds:
            self._say(f"wind: its drag takes {math.hypot(*plan.wind_lean_ne):.1f} of the "
                      f"{self.tilt.lean_limit_mps2:.1f} m/s^2 the tilt limit gives; flying within it "
                      f"({self._tilt_described(plan)})")
        else:
            log.info("tilt budget %s: %s", "fitted again" if binds else "no longer binds", self._tilt_described(plan))
        self._tilt_binds = binds
        self.speeds = plan.speeds if binds else self._calm_speeds
        s = self.speeds
        return path.rescheduled(cruise_mps=s.cruise_mps, accel_mps2=s.accel_mps2,
                                lateral_accel_mps2=s.lateral_accel_mps2, vertical_mps=s.vertical_mps,
                                speed_cap_fn=plan.caps_mps if binds else None)

    @staticmethod
    def _tilt_described(plan: TiltPlan) -> str:
        caps = plan.caps_round_mps()
        return (f"corners and braking at {plan.speeds.lateral_accel_mps2:.1f} and {plan.speeds.accel_mps2:.1f} "
                f"m/s^2, {min(caps.min(), plan.speeds.cruise_mps):.1f}-{min(caps.max(), plan.speeds.cruise_mps):.1f}"
                f" m/s by direction; "
                f"drag {plan.drag_1_s:.2f}/s")

    def _check_following(self, commanded_mps: float, t) -> None:
        """A vehicle in our mode that stands still for ``stuck_s`` while told to fly at ``stuck_mps`` or more has
        stopped following (e.g. an autopilot that dropped our stream without saying so): take control again."""
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        if commanded_mps < self.stuck_mps or speed > self.stop_speed_mps:
            self._stuck_since = math.nan
            return
        if math.isnan(self._stuck_since):
            self._stuck_since = self.clock()
        elif self.clock() - self._stuck_since >= self.stuck_s:
            self._stuck_since = math.nan
            self._recover(f"the vehicle stopped following our setpoints (told {commanded_mps:.1f} m/s, standing "
                          "still)", link_lost=False, retake=True)

    def _trim(self, goal: np.ndarray, p: LocalNED, t, dt_s: float) -> np.ndarray:
        """The hold position over ``goal``, moved against the vehicle's steady offset from it (integral action at
        ``trim_gain``/s, at most ``max_trim_m``; only once it has slowed down, so the approach does not wind it up).

        PX4 SIH hovered 0.4-0.5 m off its setpoint for seconds (measured), then drifted as much again landing."""
        slow = math.hypot(t.local_v_north_mps, t.local_v_east_mps) < 2.0 * self.stop_speed_mps
        if slow and math.isfinite(dt_s):
            error = np.array([goal[0] - p.north_m, goal[1] - p.east_m])
            self._trim_m = self._trim_m + self.trim_gain * min(dt_s, 0.5) * error
            norm = float(np.linalg.norm(self._trim_m))
            if norm > self.max_trim_m:
                self._trim_m *= self.max_trim_m / norm
        return np.array([goal[0] + self._trim_m[0], goal[1] + self._trim_m[1], goal[2]])

    def _flying_line(self, path: SmoothPath, t) -> str:
        to_go = max(path.length_m - self._progress_s, 0.0)
        return f"flying: {to_go:.0f} m to go at {math.hypot(t.local_v_north_mps, t.local_v_east_mps):.1f} m/s"

    def _reached(self, i: int, last: int, path: SmoothPath, p: LocalNED) -> None:
        t = self.vehicle.telemetry
        log.info("waypoint %d/%d reached at (%.1f N, %.1f E, %.1f m)", i, last, p.north_m, p.east_m, p.altitude_m)
        if i < last:
            self._say(f"waypoint {i}/{last} reached: {max(path.length_m - self._progress_s, 0):.0f} m to go at "
                      f"{math.hypot(t.local_v_north_mps, t.local_v_east_mps):.1f} m/s")
            self._fire(E.WAYPOINT_REACHED)
        else:
            what = "goal" if self._target_ne is None else "fallback point (the goal out of reach)"
            self._say(f"{what} reached at ({p.north_m:.1f} N, {p.east_m:.1f} E); landing")

    def _autopilot_rate(self) -> float:
        """Autopilot seconds per second of our clock since the takeoff command: a sped-up simulator's speedup,
        1 for a real autopilot or one that reports no clock."""
        elapsed = self.clock() - self._takeoff_s
        autopilot = self._autopilot_time_s() - self._takeoff_autopilot_s
        if not (elapsed > 0.2 and math.isfinite(autopilot) and autopilot > 0):
            return 1.0
        return autopilot / elapsed

    def _waypoint_deadline(self, wp, previous) -> tuple[float, float]:
        """``(deadline, now)`` for reaching ``wp``: ``leg_timeout_s`` + the horizontal leg at ``min_speed_mps``."""
        now = self.clock()
        leg_m = math.hypot(wp[0] - previous[0], wp[1] - previous[1])
        return now + self.leg_timeout_s + leg_m / self.min_speed_mps, now

    def _on_altitude(self, path: SmoothPath, p: LocalNED) -> bool:
        return abs(path.point_at(self._progress_s)[0][2] - p.altitude_m) <= self.altitude_tolerance_m

    def _not_reached(self, i: int, wp: np.ndarray, is_last: bool, timeout_s: float) -> str:
        """Why waypoint ``i`` timed out: how far off the vehicle is and how fast it still moves."""
        p = self._map_position()
        t = self.vehicle.telemetry
        horizontal = math.hypot(wp[0] - p.north_m, wp[1] - p.east_m)
        vertical = abs(wp[2] - p.altitude_m)
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        why = (f"waypoint {i} ({wp[0]:.1f} N, {wp[1]:.1f} E, {wp[2]:.1f} m) not reached in time ({timeout_s:.0f} s): "
               f"{horizontal:.2f} m off horizontally, {vertical:.2f} m vertically, moving {speed:.2f} m/s")
        if is_last:
            why += (f" (the goal needs <= {self.goal_tolerance_m:g} m, <= {self.altitude_tolerance_m:g} m vertically "
                    f"and <= {self.stop_speed_mps:g} m/s)")
        return why

    def _at_goal(self, wp: np.ndarray) -> bool:
        """Over the goal: within ``goal_tolerance_m`` and slower than ``stop_speed_mps``; or settled, within 1.5 x
        the tolerance for ``settle_s`` (position noise, e.g. PX4's, keeps some vehicles out of the strict box).
        A keep-off shift (:mod:`.keepoff`) moves the goal with the route: something reads too close to it."""
        p = self._flown_position()
        t = self.vehicle.telemetry
        horizontal = math.hypot(wp[0] - p.north_m, wp[1] - p.east_m)
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        if abs(wp[2] - p.altitude_m) > self.altitude_tolerance_m:
            return False
        if horizontal <= self.goal_tolerance_m and speed <= self.stop_speed_mps:
            return True
        if horizontal > 1.5 * self.goal_tolerance_m or speed > 2.0 * self.stop_speed_mps:
            self._near_goal_since = math.nan
            return False
        if math.isnan(self._near_goal_since):
            self._near_goal_since = self.clock()
        return self.clock() - self._near_goal_since >= self.settle_s
