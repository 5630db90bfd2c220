"""Flight modes: DO_SET_MODE numbers from pymavlink's tables, the mode we fly in, and what a mode change means.

Part of the ``vehicle`` package. PX4 (and generic autopilots, flown with PX4's conventions) are flown in
OFFBOARD, ArduPilot in GUIDED. Any other mode is classified by :func:`mode_kind`, so the mission can tell a
vehicle that merely stopped (hold, brake), one that is coming down on its own (land, return), and one a person
flies (manual, position, altitude modes), which it hands over.
"""

from __future__ import annotations

import enum

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .errors import UnsupportedMode
from .telemetry import Autopilot


class ModeKind(enum.Enum):
    """What the vehicle's current mode says about who flies it."""

    OURS = "ours"  # OFFBOARD / GUIDED: following our setpoints
    HOLD = "hold"  # stopped by the autopilot: PX4 Hold (AUTO.LOITER), ArduCopter BRAKE
    RETURN = "return"  # coming down or home on its own: land, return-to-launch
    PILOT = "pilot"  # a person flies: manual, stabilized, altitude, position modes
    OTHER = "other"  # another automatic mode: a mission, follow-me, ...


_PX4_KINDS = {
    "OFFBOARD": ModeKind.OURS,
    "LOITER": ModeKind.HOLD,
    "LAND": ModeKind.RETURN,
    "RTL": ModeKind.RETURN,
    "RTGS": ModeKind.RETURN,
    "MANUAL": ModeKind.PILOT,
    "STABILIZED": ModeKind.PILOT,
    "ACRO": ModeKind.PILOT,
    "RATTITUDE": ModeKind.PILOT,
    "ALTCTL": ModeKind.PILOT,
    "POSCTL": ModeKind.PILOT,
}
_ARDUCOPTER_KINDS = {
    "GUIDED": ModeKind.OURS,
    "BRAKE": ModeKind.HOLD,
    "LAND": ModeKind.RETURN,
    "RTL": ModeKind.RETURN,
    "SMART_RTL": ModeKind.RETURN,
    "AUTO_RTL": ModeKind.RETURN,
    **{name: ModeKind.PILOT for name in (
        "STABILIZE", "ACRO", "ALT_HOLD", "LOITER", "POSITION", "OF_LOITER", "DRIFT", "SPORT", "FLIP", "AUTOTUNE",
        "POSHOLD", "THROW", "GUIDED_NOGPS", "FLOWHOLD", "ZIGZAG", "SYSTEMID", "TURTLE", "RATE_ACRO")},
}


def flight_mode(autopilot: Autopilot) -> str:
    """The mode the mission flies in: ``GUIDED`` on ArduPilot, ``OFFBOARD`` on PX4 and generic autopilots."""
    return "GUIDED" if autopilot is Autopilot.ARDUPILOT else "OFFBOARD"


def mode_kind(autopilot: Autopilot, mode: str) -> ModeKind:
    """Classify a mode name (as :class:`~skyroute.vehicle.telemetry.Telemetry` reports it).

    >>> mode_kind(Autopilot.PX4, "POSCTL"), mode_kind(Autopilot.ARDUPILOT, "LOITER")
    (<ModeKind.PILOT: 'pilot'>, <ModeKind.PILOT: 'pilot'>)
    >>> mode_kind(Autopilot.PX4, "LOITER"), mode_kind(Autopilot.ARDUPILOT, "GUIDED")
    (<ModeKind.HOLD: 'hold'>, <ModeKind.OURS: 'ours'>)
    """
    table = _ARDUCOPTER_KINDS if autopilot is Autopilot.ARDUPILOT else _PX4_KINDS
    return table.get(mode.upper(), ModeKind.OTHER)


def mode_numbers(autopilot: Autopilot, mode: str, mav_type: int = mavlink.MAV_TYPE_QUADROTOR) -> tuple[int, int]:
    """``(param2, param3)`` of DO_SET_MODE for ``mode``, from pymavlink's tables.

    PX4 / generic: (custom main mode, custom sub mode), e.g. ``OFFBOARD`` -> (6, 0). ArduPilot: (mode number, 0)
    from the table for ``mav_type`` (ArduCopter for multirotors), e.g. ``GUIDED`` -> (4, 0).

    >>> mode_numbers(Autopilot.PX4, "offboard"), mode_numbers(Autopilot.ARDUPILOT, "GUIDED")
    ((6, 0), (4, 0))
    """
    mode = mode.upper()
    if autopilot is Autopilot.ARDUPILOT:
        table = mavutil.mode_mapping_byname(mav_type) or {v: k for k, v in mavutil.mode_mapping_acm.items()}
        if mode not in table:
            raise UnsupportedMode(mode, autopilot.value)
        return int(table[mode]), 0
    if mode not in mavutil.px4_map:
        raise UnsupportedMode(mode, autopilot.value)
    _, main_mode, sub_mode = mavutil.px4_map[mode]
    return int(main_mode), int(sub_mode)
