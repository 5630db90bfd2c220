"""The mission's state machine as data: states, events and the transition table.

:data:`TRANSITIONS` maps ``(MissionState, MissionEvent)`` to the next state and :func:`next_state` refuses
anything else. The flow on a real autopilot: wait for the estimator (PREFLIGHT), plan from where the vehicle is
(PLANNING), select the flight mode and arm (ARMING), take off at once, fly, land, disarm. An outage or a lost
mode in the air goes through RECOVERING, which resumes the flight, ends it (landed meanwhile, link gone for
good) or hands the vehicle over to a pilot who took it or to the autopilot's own failsafe (HANDED_OVER). An
obstacle the map does not show on the path goes through REPLANNING (PATH_BLOCKED; REPLANNED flies on,
GOAL_UNREACHABLE flies to the nearest reachable safe point and lands there).
"""

from __future__ import annotations

import enum


class MissionState(enum.Enum):
    MANUAL = "manual"  # on the ground, disarmed, not under our control (start and normal end)
    PREFLIGHT = "preflight"  # waiting for what the mission needs: position estimates, home, pre-arm checks
    PLANNING = "planning"
    ARMING = "arming"  # selecting our flight mode and arming
    TAKEOFF = "takeoff"
    WAYPOINT = "waypoint"
    REPLANNING = "replanning"  # the sensor showed an obstacle on the path: braking if need be, planning anew
    RECOVERING = "recovering"  # the link or our flight mode was lost in the air: waiting, reading, taking back
    LANDING = "landing"
    DISARMING = "disarming"
    FAILED = "failed"  # terminal: we could not bring the vehicle back to MANUAL (link lost for good, could not
    #                     land or disarm, the vehicle disarmed before touchdown)
    HANDED_OVER = "handed over"  # terminal: a pilot took the vehicle (a manual/position/altitude mode), or the
    #                               autopilot's own failsafe or an operator sent it home or down


class MissionEvent(enum.Enum):
    START = "start"
    READY = "ready"
    NOT_READY = "not ready"  # the vehicle did not get ready in time, or is not on the ground
    PLANNED = "planned"
    NO_PATH = "no path"
    ARMED = "armed"
    ARM_FAILED = "arm failed"  # never armed: nothing to undo
    TAKEOFF_DONE = "takeoff done"
    WAYPOINT_REACHED = "waypoint reached"
    GOAL_REACHED = "goal reached"
    ABORT = "abort"  # a failure or Ctrl-C: land if flying, disarm if armed on the ground
    LINK_LOST = "link lost"
    CONTROL_LOST = "control lost"  # the autopilot left our flight mode, or stopped following
    RESUMED = "resumed"  # link back and control taken back: fly on from where the vehicle is
    LINK_TIMEOUT = "link timeout"  # the link stayed lost for the link timeout: the autopilot's failsafe has it
    LANDED_MEANWHILE = "landed meanwhile"  # found landed and disarmed after an outage: never take off again
    TAKEN_OVER = "taken over"  # a pilot flies it now, or the autopilot's own failsafe or an operator has it
    LANDED = "landed"
    LAND_FAILED = "land failed"  # landing could not be commanded or confirmed
    DISARMED = "disarmed"
    DISARM_FAILED = "disarm failed"
    DISARMED_IN_FLIGHT = "disarmed in flight"  # between takeoff and touchdown: crashed or killed by the autopilot
    PATH_BLOCKED = "path blocked"  # an observed obstacle (or its margin) on the path within the look-ahead
    REPLANNED = "replanned"  # a new route from where the vehicle is: fly on along it
    GOAL_UNREACHABLE = "goal unreachable"  # the goal is blocked or cut off: fly to the nearest reachable safe point


S, E = MissionState, MissionEvent
_FLYING = (S.TAKEOFF, S.WAYPOINT, S.REPLANNING)
TRANSITIONS: dict[tuple[MissionState, MissionEvent], MissionState] = {
    (S.MANUAL, E.START): S.PREFLIGHT,
    (S.PREFLIGHT, E.READY): S.PLANNING,
    (S.PREFLIGHT, E.NOT_READY): S.MANUAL,
    (S.PREFLIGHT, E.ABORT): S.MANUAL,
    (S.PREFLIGHT, E.LINK_LOST): S.MANUAL,
    (S.PLANNING, E.PLANNED): S.ARMING,
    (S.PLANNING, E.NO_PATH): S.MANUAL,
    (S.PLANNING, E.ABORT): S.MANUAL,
    (S.PLANNING, E.LINK_LOST): S.MANUAL,
    (S.ARMING, E.ARMED): S.TAKEOFF,
    (S.ARMING, E.ARM_FAILED): S.MANUAL,
    (S.ARMING, E.ABORT): S.DISARMING,
    (S.ARMING, E.LINK_LOST): S.FAILED,
    (S.TAKEOFF, E.TAKEOFF_DONE): S.WAYPOINT,
    (S.WAYPOINT, E.WAYPOINT_REACHED): S.WAYPOINT,
    (S.WAYPOINT, E.GOAL_REACHED): S.LANDING,
    (S.WAYPOINT, E.PATH_BLOCKED): S.REPLANNING,
    (S.REPLANNING, E.REPLANNED): S.WAYPOINT,
    (S.REPLANNING, E.GOAL_UNREACHABLE): S.WAYPOINT,
    **{(state, E.ABORT): S.LANDING for state in _FLYING},
    **{(state, E.LINK_LOST): S.RECOVERING for state in _FLYING},
    **{(state, E.CONTROL_LOST): S.RECOVERING for state in _FLYING},
    **{(state, E.TAKEN_OVER): S.HANDED_OVER for state in (*_FLYING, S.RECOVERING)},
    (S.RECOVERING, E.RESUMED): S.WAYPOINT,
    (S.RECOVERING, E.LINK_TIMEOUT): S.FAILED,
    (S.RECOVERING, E.LANDED_MEANWHILE): S.MANUAL,
    (S.RECOVERING, E.ABORT): S.LANDING,
    (S.LANDING, E.LANDED): S.DISARMING,
    (S.LANDING, E.LAND_FAILED): S.FAILED,
    (S.LANDING, E.LINK_LOST): S.LANDING,  # the autopilot keeps landing; we wait for the link
    (S.LANDING, E.LINK_TIMEOUT): S.FAILED,
    (S.DISARMING, E.DISARMED): S.MANUAL,
    (S.DISARMING, E.DISARM_FAILED): S.FAILED,
    (S.DISARMING, E.LINK_LOST): S.FAILED,
    **{(state, E.DISARMED_IN_FLIGHT): S.FAILED for state in (*_FLYING, S.RECOVERING, S.LANDING)},
}
del S, E

#: States in which the vehicle may be in the air under our control.
AIRBORNE_STATES = frozenset({MissionState.TAKEOFF, MissionState.WAYPOINT, MissionState.REPLANNING,
                             MissionState.RECOVERING, MissionState.LANDING})


class IllegalTransition(ValueError):
    """``event`` is not allowed in ``state``."""

    def __init__(self, state: MissionState, event: MissionEvent):
        self.state, self.event = state, event
        super().__init__(f"event {event.name} is not allowed in state {state.name}")


def next_state(state: MissionState, event: MissionEvent) -> MissionState:
    """The state after ``event`` in ``state``, from :data:`TRANSITIONS`.

    >>> next_state(MissionState.MANUAL, MissionEvent.START)
    <MissionState.PREFLIGHT: 'preflight'>
    """
    try:
        return TRANSITIONS[(state, event)]
    except KeyError:
        raise IllegalTransition(state, event) from None
