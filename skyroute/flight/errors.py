"""The mission's errors: each says what happened to the vehicle. ``result`` holds the mission so far."""

from __future__ import annotations

from typing import TYPE_CHECKING

from skyroute.frames import LocalNED

from .states import MissionState

if TYPE_CHECKING:
    from .mission import MissionResult


class MissionError(Exception):
    """Base of the mission's errors. ``result`` holds what happened up to the failure."""

    result: MissionResult | None = None


class NotReady(MissionError):
    """The vehicle did not get ready for the mission (position estimate, home, pre-arm checks) in time, or is not
    on the ground; it was never armed."""


class ArmingFailed(MissionError):
    """The autopilot refused to arm, or to take the flight mode we arm in (``action``): for good (a DENIED/FAILED
    answer while it says it is ready), or until the timeout. ``reason`` is its latest answer."""

    def __init__(self, why: str, attempts: int, reason: str, action: str = "arm"):
        self.attempts, self.reason, self.action = attempts, reason, action
        super().__init__(f"the autopilot refused to {action} {why} ({attempts} attempt{'s' * (attempts != 1)}): "
                         f"{reason}")


class NoPathFound(MissionError):
    """The planner found no path; the vehicle was never armed."""


class PlanningFailed(MissionError):
    """The planner raised something other than a no-path error; the vehicle was never armed."""


class OutsideGeofence(MissionError):
    """The route leaves the autopilot's own geofence round home (it would return or land at the breach); the
    vehicle was never armed."""


class FlightAborted(MissionError):
    """A failure after takeoff; the message says what failed and whether the vehicle landed or is holding."""


class VehicleDisarmedInFlight(FlightAborted):
    """The vehicle disarmed between takeoff and touchdown: crashed, or the autopilot killed the motors.

    Also raised when it disarmed on the ground before the goal (e.g. it came down on a roof). Nothing is commanded
    after it: a disarmed vehicle cannot be landed. ``position`` is its map position, ``on_ground`` what the
    autopilot said, ``state`` the mission state when it was noticed.
    """

    def __init__(self, state: MissionState, position: LocalNED, on_ground: bool, context: str = ""):
        self.state, self.position, self.on_ground = state, position, on_ground
        where = (f"at map position {position.north_m:.1f} N, {position.east_m:.1f} E, "
                 f"{position.altitude_m:.1f} m above the map's ground")
        if on_ground:
            what = (f"the vehicle disarmed on the ground in state {state.name}, before reaching the goal "
                    f"(crashed or came down short, e.g. on a roof) {where}")
        else:
            what = (f"the vehicle disarmed in the air in state {state.name} (crashed or killed by the autopilot) "
                    f"{where}")
        super().__init__(f"{context}; then {what}" if context else what)


class LandedMeanwhile(MissionError):
    """After an outage the vehicle was found landed and disarmed (its failsafe landed it); we do not take off
    again on our own."""


class ControlTakenOver(MissionError):
    """Someone else has the vehicle and we handed it over: a pilot (a manual, position or altitude mode we never
    select), or the autopilot's own failsafe or an operator (a return or landing nothing on our side explains)."""


class LinkLostInFlight(MissionError):
    """The link stayed lost for the link timeout; the autopilot's failsafe owns the vehicle."""


class GoalUnreachableInFlight(MissionError):
    """In flight, obstacles the map does not show blocked the goal or cut it off: the vehicle held, flew to the
    nearest reachable safe point and landed there (or where it was, if there was none)."""
