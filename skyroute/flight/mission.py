"""The mission state machine: arm, plan, take off, fly the waypoints, land at the goal, disarm.

The machine is data: :data:`TRANSITIONS` maps ``(MissionState, MissionEvent)`` to the next state and
:func:`next_state` refuses anything else. :class:`Mission` only talks to an injected vehicle (anything with the
methods of :class:`Vehicle`, e.g. ``vehicle.MavlinkVehicle`` or a test fake) and never imports pymavlink.

Frames: waypoints are in the MAP frame (NED at the map's lat0/lon0, altitude 0 = home altitude) as
``[north_m, east_m, altitude_m, heading_rad]``. The vehicle is commanded in the autopilot's local frame;
``vehicle.map_offset(map_origin)`` gives ``map = local + offset`` once, before arming.

Safety: any failure after the takeoff command lands the vehicle (or holds it, if landing cannot be commanded)
before the error propagates; Ctrl-C in flight lands first and then re-raises KeyboardInterrupt, and so does an
unexpected exception (a bug is re-raised as itself, never retried as a vehicle refusal); a lost link is waited for
``link_lost_timeout_s`` and then reported (the autopilot's own failsafe owns the vehicle). A vehicle that disarms
between takeoff and touchdown (a crash, or the autopilot killed the motors) is not commanded any more: the mission
stops streaming setpoints and raises :class:`VehicleDisarmedInFlight` with where it happened.
"""

from __future__ import annotations

import enum
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from skyroute.flight.path import SmoothPath, leg_headings, path_length_m, smooth_path
from skyroute.frames import Geodetic, LocalNED

log = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------ state machine
class MissionState(enum.Enum):
    MANUAL = "manual"  # on the ground, disarmed, not under our control (start and normal end)
    ARMING = "arming"
    PLANNING = "planning"
    TAKEOFF = "takeoff"
    WAYPOINT = "waypoint"
    LANDING = "landing"
    DISARMING = "disarming"
    FAILED = "failed"  # terminal: we could not bring the vehicle back to MANUAL (link lost, could not land/disarm,
    #                     the vehicle disarmed before touchdown)


class MissionEvent(enum.Enum):
    START = "start"
    ARMED = "armed"
    ARM_FAILED = "arm failed"  # never armed: nothing to undo
    PLANNED = "planned"
    NO_PATH = "no path"
    TAKEOFF_DONE = "takeoff done"
    WAYPOINT_REACHED = "waypoint reached"
    GOAL_REACHED = "goal reached"
    ABORT = "abort"  # a failure or Ctrl-C: land if flying, disarm if armed on the ground
    LANDED = "landed"
    LAND_FAILED = "land failed"  # landing could not be commanded: holding
    DISARMED = "disarmed"
    DISARM_FAILED = "disarm failed"
    LINK_LOST = "link lost"
    DISARMED_IN_FLIGHT = "disarmed in flight"  # between takeoff and touchdown: crashed or killed by the autopilot


S, E = MissionState, MissionEvent
TRANSITIONS: dict[tuple[MissionState, MissionEvent], MissionState] = {
    (S.MANUAL, E.START): S.ARMING,
    (S.ARMING, E.ARMED): S.PLANNING,
    (S.ARMING, E.ARM_FAILED): S.MANUAL,
    (S.ARMING, E.ABORT): S.DISARMING,
    (S.PLANNING, E.PLANNED): S.TAKEOFF,
    (S.PLANNING, E.NO_PATH): S.DISARMING,
    (S.PLANNING, E.ABORT): S.DISARMING,
    (S.TAKEOFF, E.TAKEOFF_DONE): S.WAYPOINT,
    (S.TAKEOFF, E.ABORT): S.LANDING,
    (S.WAYPOINT, E.WAYPOINT_REACHED): S.WAYPOINT,
    (S.WAYPOINT, E.GOAL_REACHED): S.LANDING,
    (S.WAYPOINT, E.ABORT): S.LANDING,
    (S.LANDING, E.LANDED): S.DISARMING,
    (S.LANDING, E.LAND_FAILED): S.FAILED,
    (S.DISARMING, E.DISARMED): S.MANUAL,
    (S.DISARMING, E.DISARM_FAILED): S.FAILED,
    **{(state, E.LINK_LOST): S.FAILED
       for state in (S.ARMING, S.PLANNING, S.TAKEOFF, S.WAYPOINT, S.LANDING, S.DISARMING)},
    **{(state, E.DISARMED_IN_FLIGHT): S.FAILED for state in (S.TAKEOFF, S.WAYPOINT, S.LANDING)},
}
del S, E


class IllegalTransition(ValueError):
    """``event`` is not allowed in ``state``."""

    def __init__(self, state: MissionState, event: MissionEvent):
        self.state, self.event = state, event
        super().__init__(f"event {event.name} is not allowed in state {state.name}")


def next_state(state: MissionState, event: MissionEvent) -> MissionState:
    """The state after ``event`` in ``state``, from :data:`TRANSITIONS`.

    >>> next_state(MissionState.MANUAL, MissionEvent.START)
    <MissionState.ARMING: 'arming'>
    """
    try:
        return TRANSITIONS[(state, event)]
    except KeyError:
        raise IllegalTransition(state, event) from None


# ---------------------------------------------------------------------------------------------- errors
class MissionError(Exception):
    """Base of the mission's errors. ``result`` holds what happened up to the failure."""

    result: MissionResult | None = None


class ArmingFailed(MissionError):
    """The autopilot refused to arm until the readiness timeout; ``reason`` is its latest answer."""

    def __init__(self, timeout_s: float, attempts: int, reason: str):
        self.timeout_s, self.attempts, self.reason = timeout_s, attempts, reason
        super().__init__(f"the autopilot refused to arm for {timeout_s:g} s ({attempts} attempts): {reason}")


class NoPathFound(MissionError):
    """The planner found no path; the vehicle was disarmed and never took off."""


class PlanningFailed(MissionError):
    """The planner raised something other than a no-path error; the vehicle was disarmed and never took off."""


class FlightAborted(MissionError):
    """A failure after takeoff; the message says what failed and whether the vehicle landed or is holding."""


class VehicleDisarmedInFlight(FlightAborted):
    """The vehicle disarmed between takeoff and touchdown: crashed, or the autopilot killed the motors.

    Also raised when it disarmed on the ground before the goal (e.g. it came down on a roof). Nothing is commanded
    after it: a disarmed vehicle cannot be landed. ``position`` is its map position (``down_m`` = -altitude above
    home), ``on_ground`` what the autopilot said, ``state`` the mission state when it was noticed.
    """

    def __init__(self, state: MissionState, position: LocalNED, on_ground: bool, context: str = ""):
        self.state, self.position, self.on_ground = state, position, on_ground
        where = (f"at map position {position.north_m:.1f} N, {position.east_m:.1f} E, "
                 f"{position.altitude_m:.1f} m above home")
        if on_ground:
            what = (f"the vehicle disarmed on the ground in state {state.name}, before reaching the goal "
                    f"(crashed or came down short, e.g. on a roof) {where}")
        else:
            what = (f"the vehicle disarmed in the air in state {state.name} (crashed or killed by the autopilot) "
                    f"{where}")
        super().__init__(f"{context}; then {what}" if context else what)


class LinkLostInFlight(MissionError):
    """The link stayed lost for ``link_lost_timeout_s``; the autopilot's failsafe owns the vehicle."""


# ------------------------------------------------------------------------------------------- interfaces
class Telemetry(Protocol):
    """The telemetry fields the mission reads (``vehicle.Telemetry`` has them; SI units, autopilot local NED)."""

    armed: bool
    north_m: float
    east_m: float
    down_m: float
    local_v_north_mps: float
    local_v_east_mps: float
    local_v_down_mps: float

    @property
    def on_ground(self) -> bool: ...


class Vehicle(Protocol):
    """What the mission needs from a vehicle (``vehicle.MavlinkVehicle`` implements it)."""

    @property
    def telemetry(self) -> Telemetry: ...

    @property
    def link_ok(self) -> bool: ...

    def map_offset(self, map_origin: Geodetic) -> LocalNED: ...

    def arm(self) -> None: ...

    def disarm(self) -> None: ...

    def takeoff(self, altitude_m: float) -> LocalNED: ...

    def goto_local(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
                   velocity_ned: tuple[float, float, float] | None = None) -> None: ...

    def land(self) -> None: ...

    def hold(self) -> None: ...

    def release_control(self) -> None: ...


PlanFn = Callable[[float, float], np.ndarray]


@dataclass
class MissionResult:
    """What a mission did. Lengths in m, times in s, positions in the map frame.

    ``planned_length_m`` counts the climb from the start to the first waypoint, the waypoint polyline and the
    descent from the last waypoint to the ground; ``flown_length_m`` is the 3D length of ``track`` (rows
    ``[time_s, north_m, east_m, altitude_m]`` from the takeoff command to touchdown). ``landing_error_m`` is the
    horizontal distance from the touchdown point to the last waypoint. ``flight_time_s`` runs from the takeoff
    command to touchdown in the autopilot's clock (LOCAL_POSITION_NED time since boot) when it reports one, so it
    is simulated time against a sped-up simulator; ``track`` times are our own monotonic clock.
    """

    final_state: MissionState
    completed: bool = False
    waypoints: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    planned_length_m: float = math.nan
    flown_length_m: float = math.nan
    flight_time_s: float = math.nan
    landing_error_m: float = math.nan
    track: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    history: list[tuple[MissionState, MissionEvent, MissionState]] = field(default_factory=list)

    def summary(self) -> str:
        """One line: planned length, flown length, flight time, landing error."""
        return (f"planned {self.planned_length_m:.1f} m, flown {self.flown_length_m:.1f} m, "
                f"flight time {self.flight_time_s:.1f} s, landing error {self.landing_error_m:.2f} m")


# ------------------------------------------------------------------------------------------------ mission
#: Remaining path (m) from which the last waypoint is commanded as a plain position (no feed-forward), or earlier
#: once the vehicle needs all of the remaining path to brake at ``accel_mps2`` (it lags the schedule): at the
#: default 3 m/s^2 the schedule is down to sqrt(2 * 3 * 1) = 2.4 m/s there, and the autopilot brakes the rest.
FINAL_APPROACH_M = 1.0


class _Abort(Exception):
    """Internal: a timeout or refusal during flight that must end in a landing."""


class Mission:
    """Fly ``plan_fn``'s waypoints with ``vehicle``; see the module docstring for the flow and the failures.

    Parameters
    ----------
    vehicle : Vehicle
        Connected vehicle; the mission never closes it.
    plan_fn : callable ``(start_north_m, start_east_m) -> ndarray (K, 4)``
        Map-frame waypoints ``[north_m, east_m, altitude_m, heading_rad]``; called after arming. Altitude NaN
        means ``altitude_m``. The heading column is ignored: the mission flies along each leg.
    altitude_m : float
        Flight altitude above home (m), for waypoints without one.
    map_origin : Geodetic
        The map's lat0/lon0 (alt 0).
    no_path_errors : tuple of exception types
        What ``plan_fn`` raises when there is no path (e.g. ``skyroute.planning.errors.NoPathError``).
    vehicle_errors : tuple of exception types
        What vehicle calls raise on refusal/timeout (e.g. ``vehicle.VehicleError``): arming is retried on these
        and a flight that raises them lands. Required: anything else (a bug) propagates as itself.
    corner_cut_m, cruise_mps, accel_mps2, lateral_accel_mps2, vertical_mps : float
        The flight path (:func:`smooth_path`): corners rounded by arcs at most ``corner_cut_m`` inside the planned
        legs, flown at ``cruise_mps`` on straights, ``sqrt(lateral_accel_mps2 * r)`` on an arc of radius r, at most
        ``vertical_mps`` vertically, braking at ``accel_mps2``. Defaults suit the sim's PX4/ArduPilot limits
        (10 m/s, 4 m/s^2); keep them below the autopilot's own (MPC_XY_VEL_MAX/MPC_ACC_HOR, WPNAV_SPEED/ACCEL).
    lead_s, velocity_lag_s : float
        Steering: the command is the path point nearest to where the vehicle will be ``lead_s`` (autopilot time:
        telemetry and link latency) plus one poll from now, with the scheduled velocity ``velocity_lag_s``
        further on (the autopilot's velocity loop lags by about that much) as a feed-forward.
    clock, sleep : callables
        Injected for tests (monotonic seconds; sleep seconds).
    """

    def __init__(self, vehicle: Vehicle, plan_fn: PlanFn, *, altitude_m: float, map_origin: Geodetic,
                 no_path_errors: tuple[type[BaseException], ...] = (NoPathFound,),
                 vehicle_errors: tuple[type[BaseException], ...],
                 arm_timeout_s: float = 60.0, arm_retry_s: float = 1.0,
                 takeoff_timeout_s: float = 60.0, leg_timeout_s: float = 60.0, min_speed_mps: float = 1.0,
                 landing_timeout_s: float = 120.0, disarm_timeout_s: float = 15.0,
                 link_lost_timeout_s: float = 30.0,
                 goal_tolerance_m: float = 0.3, stop_speed_mps: float = 0.3, altitude_tolerance_m: float = 1.0,
                 corner_cut_m: float = 0.5, cruise_mps: float = 10.0, accel_mps2: float = 3.0,
                 lateral_accel_mps2: float = 3.0, vertical_mps: float = 1.5, lead_s: float = 0.2,
                 velocity_lag_s: float = 0.15,
                 poll_s: float = 0.02, track_interval_s: float = 0.2,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        if not altitude_m > 0:
            raise ValueError(f"altitude_m must be > 0, got {altitude_m}")
        self.vehicle, self.plan_fn = vehicle, plan_fn
        self.altitude_m, self.map_origin = float(altitude_m), map_origin
        self.no_path_errors = tuple(no_path_errors) + (NoPathFound,)
        self.vehicle_errors = tuple(vehicle_errors)
        self.arm_timeout_s, self.arm_retry_s = arm_timeout_s, arm_retry_s
        self.takeoff_timeout_s, self.leg_timeout_s, self.min_speed_mps = takeoff_timeout_s, leg_timeout_s, min_speed_mps
        self.landing_timeout_s, self.disarm_timeout_s = landing_timeout_s, disarm_timeout_s
        self.link_lost_timeout_s = link_lost_timeout_s
        self.goal_tolerance_m, self.stop_speed_mps = goal_tolerance_m, stop_speed_mps
        self.altitude_tolerance_m = altitude_tolerance_m
        self.corner_cut_m, self.cruise_mps, self.accel_mps2 = corner_cut_m, cruise_mps, accel_mps2
        self.lateral_accel_mps2, self.vertical_mps, self.lead_s = lateral_accel_mps2, vertical_mps, lead_s
        self.velocity_lag_s = velocity_lag_s
        self.poll_s, self.track_interval_s = poll_s, track_interval_s
        self.clock, self.sleep = clock, sleep
        self.state = MissionState.MANUAL
        self.result = MissionResult(final_state=self.state)
        self._offset = LocalNED(0.0, 0.0, 0.0)
        self._track: list[tuple[float, float, float, float]] = []
        self._takeoff_s = math.nan
        self._takeoff_autopilot_s = math.nan
        self._land_commanded = False

    # ------------------------------------------------------------------------------------------ plumbing
    def _fire(self, event: MissionEvent) -> MissionState:
        new = next_state(self.state, event)
        log.info("%s --%s--> %s", self.state.name, event.name, new.name)
        self.result.history.append((self.state, event, new))
        self.state = self.result.final_state = new
        return new

    def _map_position(self) -> LocalNED:
        """Vehicle position in the map frame (down = -altitude above home)."""
        t = self.vehicle.telemetry
        return LocalNED(t.north_m + self._offset.north_m, t.east_m + self._offset.east_m,
                        t.down_m + self._offset.down_m)

    def _to_local(self, north_m: float, east_m: float, altitude_m: float) -> LocalNED:
        return LocalNED(north_m - self._offset.north_m, east_m - self._offset.east_m,
                        -altitude_m - self._offset.down_m)

    def _autopilot_time_s(self) -> float:
        """The autopilot's time since boot (s), NaN if it does not say: flight times are in its time, which
        also holds against a simulator running faster than the wall clock."""
        return float(getattr(self.vehicle.telemetry, "local_time_s", math.nan))

    def _sample(self, force: bool = False) -> None:
        now = self.clock()
        if force or not self._track or now - self._track[-1][0] >= self.track_interval_s:
            p = self._map_position()
            self._track.append((now, p.north_m, p.east_m, p.altitude_m))

    def _tick(self) -> None:
        """One poll: wait, record the track, notice a lost link and a vehicle that disarmed in flight."""
        self.sleep(self.poll_s)
        if not self.vehicle.link_ok:
            self._link_lost()
        self._sample()
        self._check_armed()

    def _check_armed(self, context: str = "") -> None:
        """Raise :class:`VehicleDisarmedInFlight` if the vehicle disarmed between takeoff and touchdown.

        In TAKEOFF and WAYPOINT any disarm is one (on the ground too: it came down short of the goal); in LANDING
        a disarm on the ground is the autopilot's auto-disarm after touchdown. Fires DISARMED_IN_FLIGHT (-> FAILED)
        and stops streaming setpoints, so a re-armed vehicle does not fly off to the last one.
        """
        if self.state not in (MissionState.TAKEOFF, MissionState.WAYPOINT, MissionState.LANDING):
            return
        t = self.vehicle.telemetry
        if t.armed:
            return
        on_ground = bool(t.on_ground)
        if on_ground and self.state is MissionState.LANDING:
            return
        state, position = self.state, self._map_position()
        self._sample(force=True)
        log.error("the vehicle disarmed %s in state %s at map (%.1f N, %.1f E, %.1f m)",
                  "on the ground" if on_ground else "in the air", state.name, position.north_m, position.east_m,
                  position.altitude_m)
        self._fire(MissionEvent.DISARMED_IN_FLIGHT)
        try:
            self.vehicle.release_control()
        except self.vehicle_errors as exc:
            log.warning("could not release control after the disarm: %s", exc)
        raise VehicleDisarmedInFlight(state, position, on_ground, context)

    def _link_lost(self) -> None:
        """Wait up to ``link_lost_timeout_s`` for the link; if it comes back, abort (land); else fail."""
        log.error("link lost in state %s; waiting up to %g s for it", self.state.name, self.link_lost_timeout_s)
        deadline = self.clock() + self.link_lost_timeout_s
        while self.clock() < deadline:
            self.sleep(self.poll_s)
            if self.vehicle.link_ok:
                log.warning("link back after an outage")
                if self.state is MissionState.LANDING:
                    return  # keep landing
                raise _Abort("the link was lost and came back")
        state = self.state
        self._fire(MissionEvent.LINK_LOST)
        raise LinkLostInFlight(f"link lost in state {state.name} for {self.link_lost_timeout_s:g} s; "
                               "the autopilot's failsafe now owns the vehicle")

    def _finish(self, error: MissionError | None = None) -> MissionResult:
        r = self.result
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
        ArmingFailed
            Arming refused until ``arm_timeout_s`` (never armed).
        NoPathFound, PlanningFailed
            The planner failed; the vehicle was disarmed and never took off.
        FlightAborted
            Something failed after takeoff; the vehicle landed (or holds, if landing could not be commanded).
        VehicleDisarmedInFlight
            A FlightAborted: the vehicle disarmed after takeoff and before touchdown (crash, or the autopilot
            killed it), or on the ground short of the goal; final state FAILED, nothing more was commanded.
        LinkLostInFlight
            The link stayed lost; the autopilot's failsafe owns the vehicle.
        KeyboardInterrupt, or any exception that is not a MissionError nor in ``vehicle_errors`` (a bug)
            Re-raised after landing (in flight) or disarming (on the ground), unless making the vehicle safe
            raised LinkLostInFlight or VehicleDisarmedInFlight, which then replaces it.

        Every MissionError carries ``.result`` (the partial :class:`MissionResult`).
        """
        self._offset = self.vehicle.map_offset(self.map_origin)
        try:
            self._fire(MissionEvent.START)
            self._arm()
            waypoints = self._plan()
            self._fly(waypoints)
        except MissionError as exc:
            self._finish(exc)
            raise
        except KeyboardInterrupt:
            log.warning("interrupted in state %s", self.state.name)
            self._abandon("interrupted (Ctrl-C)")
            raise
        except Exception as exc:  # a bug, not a refusal: make the vehicle safe, then re-raise it unchanged
            log.exception("unexpected error in state %s", self.state.name)
            self._abandon(f"unexpected error {exc!r}")
            raise
        return self._finish()

    def _abandon(self, why: str) -> None:
        """Make the vehicle safe after Ctrl-C or a bug; a MissionError from that (lost link, disarm in flight)
        replaces the original exception, with ``why`` in its message."""
        try:
            outcome = self._make_safe(why)
        except MissionError as exc:
            self._finish(exc)
            raise
        log.warning("%s: %s", why, outcome)
        self._finish()

    def _arm(self) -> None:
        deadline = self.clock() + self.arm_timeout_s
        attempts, reason = 0, ""
        while True:
            attempts += 1
            try:
                self.vehicle.arm()
                break
            except self.vehicle_errors as exc:
                reason = str(exc)
                if not self.vehicle.link_ok:
                    self._link_lost_on_ground()
                remaining_s = deadline - self.clock()
                if remaining_s <= 0:
                    self._fire(MissionEvent.ARM_FAILED)
                    raise ArmingFailed(self.arm_timeout_s, attempts, reason) from exc
                log.info("arming refused (%s); retrying", reason)
                self.sleep(min(self.arm_retry_s, remaining_s))
        self._fire(MissionEvent.ARMED)

    def _link_lost_on_ground(self) -> None:
        self._fire(MissionEvent.LINK_LOST)
        raise LinkLostInFlight(f"link lost in state {MissionState.ARMING.name}; the vehicle is on the ground")

    def _plan(self) -> np.ndarray:
        start = self._map_position()
        log.info("planning from map (%.1f N, %.1f E)", start.north_m, start.east_m)
        try:
            waypoints = np.array(self.plan_fn(start.north_m, start.east_m), dtype=float).reshape(-1, 4)
        except self.no_path_errors as exc:
            self._fire(MissionEvent.NO_PATH)
            self._disarm_on_ground()
            raise NoPathFound(f"no path: {exc}; disarmed, never took off") from exc
        except Exception as exc:
            self._fire(MissionEvent.ABORT)
            self._disarm_on_ground()
            raise PlanningFailed(f"planning failed: {exc!r}; disarmed, never took off") from exc
        if len(waypoints) == 0:
            self._fire(MissionEvent.NO_PATH)
            self._disarm_on_ground()
            raise NoPathFound("the planner returned no waypoints; disarmed, never took off")
        waypoints[np.isnan(waypoints[:, 2]), 2] = self.altitude_m
        waypoints[:, 3] = leg_headings(waypoints)
        r = self.result
        r.waypoints = waypoints
        r.planned_length_m = (math.dist((start.north_m, start.east_m, start.altitude_m), waypoints[0, :3])
                              + path_length_m(waypoints) + waypoints[-1, 2])
        log.info("planned %d waypoints, %.1f m: %s", len(waypoints), r.planned_length_m,
                 " ".join(f"({n:.1f} N, {e:.1f} E, {a:.1f} m)" for n, e, a in waypoints[:, :3]))
        self._fire(MissionEvent.PLANNED)
        return waypoints

    def _disarm_on_ground(self) -> None:
        self._disarm()
        self._fire(MissionEvent.DISARMED)

    def _disarm(self) -> None:
        deadline = self.clock() + self.disarm_timeout_s
        while self.vehicle.telemetry.armed:
            try:
                self.vehicle.disarm()
            except self.vehicle_errors as exc:
                if self.clock() >= deadline:
                    self._fire(MissionEvent.DISARM_FAILED)
                    raise MissionError(f"could not disarm within {self.disarm_timeout_s:g} s: {exc}") from exc
                log.info("disarm refused (%s); retrying", exc)
                self.sleep(0.5)

    # ------------------------------------------------------------------------------------------- flight
    def _fly(self, waypoints: np.ndarray) -> None:
        try:
            self._takeoff(float(waypoints[0, 2]))
            self._follow(waypoints)
            self._land()
        except MissionError:
            raise
        except (_Abort, *self.vehicle_errors) as exc:
            log.error("flight failed in state %s: %s", self.state.name, exc)
            outcome = self._make_safe(str(exc))
            raise FlightAborted(f"{exc}; {outcome}") from exc
        self.result.completed = True

    def _takeoff(self, altitude_m: float) -> None:
        if not self.vehicle.link_ok:
            self._link_lost()
        if not self.vehicle.telemetry.armed:  # e.g. PX4 disarms after ~10 s on the ground while we planned
            log.warning("the vehicle disarmed while planning; re-arming")
            self.vehicle.arm()
        here = self._map_position()
        self._takeoff_s = self.clock()
        self._takeoff_autopilot_s = self._autopilot_time_s()
        self._sample(force=True)
        self.vehicle.takeoff(altitude_m - here.altitude_m)
        deadline = self.clock() + self.takeoff_timeout_s
        while self._map_position().altitude_m < altitude_m - self.altitude_tolerance_m:
            if self.clock() > deadline:
                raise _Abort(f"takeoff did not reach {altitude_m:.1f} m within {self.takeoff_timeout_s:g} s")
            self._tick()
        log.info("takeoff done at %.1f m", self._map_position().altitude_m)
        self._fire(MissionEvent.TAKEOFF_DONE)

    def _follow(self, waypoints: np.ndarray) -> None:
        """Fly the rounded path through ``waypoints`` (see :func:`smooth_path`) and stop at the last one.

        Each poll predicts where the vehicle will be while this command is the autopilot's latest (``lead_s`` of
        autopilot latency plus one poll, in autopilot time, at its current velocity) and commands the path point
        nearest to that, with the scheduled velocity along the path as a feed-forward: the autopilot flies the
        schedule and its position loop only corrects the cross-track error, so it neither brakes at each
        waypoint nor cuts more than ``corner_cut_m`` (plus its tracking error) off a corner. Near the end (see
        :data:`FINAL_APPROACH_M`) the command is the last waypoint alone: the autopilot's position loop stops
        there.
        """
        path = smooth_path(waypoints, corner_cut_m=self.corner_cut_m, cruise_mps=self.cruise_mps,
                           accel_mps2=self.accel_mps2, lateral_accel_mps2=self.lateral_accel_mps2,
                           vertical_mps=self.vertical_mps)
        last = len(waypoints) - 1
        s, ref_s, heading = 0.0, 0.0, float(waypoints[0, 3])
        here = self._map_position()
        i, (deadline, start_s) = 0, self._waypoint_deadline(waypoints[0], (here.north_m, here.east_m))
        while True:
            p = self._map_position()
            s = path.project((p.north_m, p.east_m, p.altitude_m), s)
            while i < last and s >= path.waypoint_s_m[i] - 1e-6 and self._on_altitude(path, s, p):
                log.info("waypoint %d/%d reached at (%.1f N, %.1f E, %.1f m)", i, last, p.north_m, p.east_m,
                         p.altitude_m)
                self._fire(MissionEvent.WAYPOINT_REACHED)
                i += 1
                deadline, start_s = self._waypoint_deadline(waypoints[i], waypoints[i - 1])
            if i == last and self._at_goal(waypoints[last]):
                log.info("waypoint %d/%d reached at (%.1f N, %.1f E, %.1f m)", i, last, p.north_m, p.east_m,
                         p.altitude_m)
                self._fire(MissionEvent.GOAL_REACHED)
                return
            if self.clock() > deadline:
                raise _Abort(self._not_reached(i, waypoints[i], i == last, deadline - start_s))
            # where the vehicle will be, on average, while this command is the latest one the autopilot has
            t = self.vehicle.telemetry
            ahead_s = self.lead_s + self._autopilot_rate() * self.poll_s
            predicted = (p.north_m + t.local_v_north_mps * ahead_s, p.east_m + t.local_v_east_mps * ahead_s,
                         p.altitude_m - t.local_v_down_mps * ahead_s)
            ref_s = path.project(predicted, max(s, ref_s))
            speed = math.sqrt(t.local_v_north_mps**2 + t.local_v_east_mps**2 + t.local_v_down_mps**2)
            remaining_m = path.length_m - s
            if remaining_m <= max(FINAL_APPROACH_M, speed**2 / (2 * self.accel_mps2)):
                ref_s = path.length_m  # the autopilot's position loop brakes to the goal from here
            position, _ = path.point_at(ref_s)
            # the velocity wanted velocity_lag_s later: the autopilot's velocity loop takes about that long to follow
            ff_s = min(ref_s + speed * self.velocity_lag_s, path.length_m)
            tangent = path.point_at(ff_s)[1]
            if math.hypot(tangent[0], tangent[1]) > 0.1:
                heading = math.atan2(tangent[1], tangent[0]) % (2 * math.pi)
            target = self._to_local(*position)
            if ref_s >= path.length_m:
                self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading)
            else:
                # speeding up by at most accel_mps2 over the prediction: a small along-track velocity error leaves
                # the autopilot's acceleration limit free to correct the cross-track one (e.g. leaving an arc)
                velocity = tangent * min(path.speed_at(ff_s), speed + self.accel_mps2 * max(ahead_s, 0.1))
                self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading,
                                        velocity_ned=(float(velocity[0]), float(velocity[1]), float(-velocity[2])))
            self._tick()

    def _autopilot_rate(self) -> float:
        """Autopilot seconds per second of our clock since the takeoff command: a sped-up simulator's speedup,
        1 for a real autopilot or one that reports no clock."""
        elapsed = self.clock() - self._takeoff_s
        autopilot = self._autopilot_time_s() - self._takeoff_autopilot_s
        if not (elapsed > 0.2 and math.isfinite(autopilot) and autopilot > 0):
            return 1.0
        return autopilot / elapsed

    def _waypoint_deadline(self, wp, previous) -> tuple[float, float]:
        """``(deadline, now)`` for reaching ``wp`` from now: ``leg_timeout_s`` + the horizontal leg from
        ``previous`` (north, east, ...) at ``min_speed_mps``."""
        now = self.clock()
        leg_m = math.hypot(wp[0] - previous[0], wp[1] - previous[1])
        return now + self.leg_timeout_s + leg_m / self.min_speed_mps, now

    def _on_altitude(self, path: SmoothPath, s_m: float, p: LocalNED) -> bool:
        return abs(path.point_at(s_m)[0][2] - p.altitude_m) <= self.altitude_tolerance_m

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
        """At the last waypoint ``wp``: within ``goal_tolerance_m`` horizontally, ``altitude_tolerance_m`` vertically,
        and slower than ``stop_speed_mps``."""
        p = self._map_position()
        t = self.vehicle.telemetry
        horizontal = math.hypot(wp[0] - p.north_m, wp[1] - p.east_m)
        vertical = abs(wp[2] - p.altitude_m)
        speed = math.hypot(t.local_v_north_mps, t.local_v_east_mps)
        return (horizontal <= self.goal_tolerance_m and vertical <= self.altitude_tolerance_m
                and speed <= self.stop_speed_mps)

    def _land(self) -> None:
        """Land here, wait for touchdown, disarm, release control (LANDING -> DISARMING -> MANUAL)."""
        self.vehicle.land()
        self._land_commanded = True
        self._await_touchdown()

    def _await_touchdown(self) -> None:
        deadline = self.clock() + self.landing_timeout_s
        self._check_armed()
        while not self.vehicle.telemetry.on_ground:  # an autopilot that auto-disarms on touchdown says so too
            if self.clock() > deadline:
                raise _Abort(f"no touchdown within {self.landing_timeout_s:g} s of the land command")
            self._tick()
        self._sample(force=True)
        r = self.result
        r.flight_time_s = self._autopilot_time_s() - self._takeoff_autopilot_s
        if not math.isfinite(r.flight_time_s):  # no autopilot clock: our own
            r.flight_time_s = self.clock() - self._takeoff_s
        r.flown_length_m = path_length_m(np.array(self._track)[:, 1:])
        if len(r.waypoints):
            p = self._map_position()
            r.landing_error_m = math.hypot(p.north_m - r.waypoints[-1, 0], p.east_m - r.waypoints[-1, 1])
        log.info("landed; %s", r.summary())
        self._fire(MissionEvent.LANDED)
        self._disarm()
        self.vehicle.release_control()
        self._fire(MissionEvent.DISARMED)

    def _make_safe(self, why: str) -> str:
        """After a failure or Ctrl-C: land if flying (hold if landing fails), disarm if armed on the ground.

        Returns what was done, for the error message. Raises only LinkLostInFlight (the link stayed lost while
        landing) and VehicleDisarmedInFlight (the vehicle disarmed before touchdown), with ``why`` in the message.
        """
        if self.state is MissionState.MANUAL:
            return "nothing to undo: the vehicle is disarmed and not under our control"
        if self.state is MissionState.FAILED:
            return ("the mission had already failed (link lost, landing or disarming failed, or the vehicle disarmed "
                    "in flight): it may still be in the air, the autopilot's failsafe owns it")
        if self.state in (MissionState.ARMING, MissionState.PLANNING, MissionState.DISARMING):
            if self.state is not MissionState.DISARMING:
                self._fire(MissionEvent.ABORT)
            try:
                self._disarm_on_ground()
            except (MissionError, *self.vehicle_errors) as exc:
                return f"could not disarm: {exc}"
            return "disarmed on the ground" if math.isnan(self._takeoff_s) else "landed and disarmed"
        self._check_armed(why)  # a disarmed vehicle cannot be landed
        if self.state is not MissionState.LANDING:
            self._fire(MissionEvent.ABORT)
        log.warning("%s: landing where we are", why)
        if not self._land_commanded:
            try:
                self.vehicle.land()
                self._land_commanded = True
            except self.vehicle_errors as exc:
                log.error("could not land (%s); holding", exc)
                self._fire(MissionEvent.LAND_FAILED)
                try:
                    self.vehicle.hold()
                except self.vehicle_errors as hold_exc:
                    return (f"could not land ({exc}) nor hold ({hold_exc}); "
                            "the autopilot's failsafe owns the vehicle")
                return f"could not land ({exc}); holding position"
        try:
            self._await_touchdown()
        except _Abort as exc:
            self._fire(MissionEvent.LAND_FAILED)
            return f"landing commanded but not confirmed ({exc}); the autopilot is landing"
        except LinkLostInFlight as exc:  # not landed: the autopilot's failsafe has it
            raise LinkLostInFlight(f"{why}; landing commanded, then {exc}") from exc
        except VehicleDisarmedInFlight as exc:
            raise VehicleDisarmedInFlight(exc.state, exc.position, exc.on_ground, f"{why}; landing") from exc
        except (MissionError, *self.vehicle_errors) as exc:  # touchdown confirmed: disarm or release failed
            return f"landed, then {exc}"
        p = self._map_position()
        return f"landed at ({p.north_m:.1f} N, {p.east_m:.1f} E) and disarmed"

