"""Autopilot personalities: flight-mode tables, HEARTBEAT identity and the wording of their refusals.

Mode numbers come from pymavlink's tables (``mavutil.px4_map``, ``mavutil.mode_mapping_acm``), not
hand-written constants. Each mode maps to a :class:`Behaviour`, the thing the sim actually does.

PX4 ``custom_mode`` layout: ``(main_mode << 16) | (sub_mode << 24)``. ArduCopter: the mode number.

What may be armed, measured on the real autopilots (ArduCopter SITL V4.7.0-dev, PX4 v1.15.4 SIH):

* ArduCopter arms in STABILIZE, ALT_HOLD, LOITER, POSHOLD and GUIDED (no setpoints needed); RTL, LAND, BRAKE
  and SMART_RTL answer FAILED with "Arm: <NAME> mode not armable", AUTO without a mission "Arm: Mode requires
  mission".
* PX4 without RC (SITL has none) refuses arming in LAND and RTL (modes that prevent arming), in the manual
  modes (they need manual control), in MISSION without a mission and in OFFBOARD without a setpoint stream:
  TEMPORARILY_REJECTED, "Arming denied: Resolve system health failures first". It arms in LOITER (Hold) and
  TAKEOFF.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink


class Behaviour(enum.Enum):
    """What the vehicle does in a mode."""

    HOLD = "hold"  # hold position
    TAKEOFF = "takeoff"
    OFFBOARD = "offboard"  # follow SET_POSITION_TARGET_* (PX4 OFFBOARD, ArduCopter GUIDED)
    LAND = "land"
    RTL = "rtl"
    #: PX4's manual modes without RC (the failsafe's Position fallback): hold north/east, sink at the land speed.
    DESCEND = "descend"


@dataclass(frozen=True)
class Mode:
    """One flight mode of a personality.

    Attributes
    ----------
    name : str
        pymavlink's name (``mavutil.px4_map`` / ``mode_mapping_acm``).
    custom_mode : int
    base_flags : int
        HEARTBEAT base_mode without the armed bit.
    behaviour : Behaviour
    arm_refusal : str
        Empty if the mode can be armed in; else the real autopilot's reason.
    label : str
        The autopilot's own name for the mode in its messages ("SMARTRTL", "Offboard").
    needs_rc : bool
        PX4: the mode needs manual control (no RC here), so it cannot be selected while armed.
    """

    name: str
    custom_mode: int
    base_flags: int
    behaviour: Behaviour
    arm_refusal: str = ""
    label: str = ""
    needs_rc: bool = False

    @property
    def armable(self) -> bool:
        return not self.arm_refusal


@dataclass
class Task:
    """What the vehicle is doing inside the current mode (map frame positions)."""

    kind: Behaviour
    position_neu: np.ndarray
    phase: int = 0


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4 custom mode word.

    >>> hex(px4_custom_mode(4, 3))
    '0x3040000'
    """
    return (main_mode << 16) | (sub_mode << 24)


class Personality:
    """Mode table plus identity of one autopilot flavour."""

    name: str = ""
    autopilot: int = mavlink.MAV_AUTOPILOT_GENERIC
    boot_mode_name: str = ""

    def __init__(self, modes: list[Mode]) -> None:
        self.modes = {m.name: m for m in modes}
        self.by_custom = {m.custom_mode: m for m in modes}

    @property
    def boot_mode(self) -> Mode:
        return self.modes[self.boot_mode_name]

    def mode_for(self, behaviour: Behaviour) -> Mode:
        """The mode the autopilot switches to on its own for ``behaviour`` (after a command)."""
        raise NotImplementedError

    def decode_set_mode(self, base_mode: int, param2: float, param3: float) -> tuple[Mode | None, str]:
        """Mode requested by DO_SET_MODE ``(param1, param2, param3)``; ``(None, reason)`` if refused."""
        raise NotImplementedError

    def decode_custom_mode(self, custom_mode: int) -> Mode | None:
        """Mode for a SET_MODE message's ``custom_mode``."""
        return self.by_custom.get(int(custom_mode))

    def base_mode(self, mode: Mode, armed: bool, airborne: bool) -> int:
        """HEARTBEAT base_mode of ``mode`` now."""
        return mode.base_flags | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)


#: PX4's own names of its modes (commander's nav_state names), used in its messages.
_PX4_LABELS = {
    "MANUAL": "Manual", "STABILIZED": "Stabilized", "ACRO": "Acro", "RATTITUDE": "Rattitude",
    "ALTCTL": "Altitude", "POSCTL": "Position", "LOITER": "Hold", "MISSION": "Mission", "RTL": "Return",
    "LAND": "Land", "RTGS": "Return to groundstation", "FOLLOWME": "Follow Target", "OFFBOARD": "Offboard",
    "TAKEOFF": "Takeoff",
}
PX4_ARMING_DENIED = "Arming denied: Resolve system health failures first\t"


class Px4(Personality):
    """PX4 mode layout (main mode in bits 16-23, sub mode in bits 24-31)."""

    name = "px4"
    autopilot = mavlink.MAV_AUTOPILOT_PX4
    boot_mode_name = "LOITER"
    _BEHAVIOUR = {
        "LOITER": Behaviour.HOLD,
        "TAKEOFF": Behaviour.TAKEOFF,
        "LAND": Behaviour.LAND,
        "RTL": Behaviour.RTL,
        "OFFBOARD": Behaviour.OFFBOARD,
        "MISSION": Behaviour.HOLD,  # no mission: cannot be armed in, holds if entered in flight
        "MANUAL": Behaviour.DESCEND,
        "STABILIZED": Behaviour.DESCEND,
        "ACRO": Behaviour.DESCEND,
        "RATTITUDE": Behaviour.DESCEND,
        "ALTCTL": Behaviour.DESCEND,
        "POSCTL": Behaviour.DESCEND,
    }
    _NEEDS_RC = {"MANUAL", "STABILIZED", "ACRO", "RATTITUDE", "ALTCTL", "POSCTL"}
    #: Modes PX4 refuses to arm in here: they prevent arming, need RC, a mission, or (OFFBOARD) setpoints.
    _NOT_ARMABLE = {"LAND", "RTL", "MISSION"} | _NEEDS_RC
    #: Modes PX4 has that the sim refuses (no follow target, no ground station position).
    UNSUPPORTED = {"RTGS", "FOLLOWME"}
    #: HEARTBEAT base flags where PX4 1.15 differs from ``mavutil.px4_map`` (measured on SITL).
    _BASE_FLAGS = {"OFFBOARD": mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED}

    def __init__(self) -> None:
        modes = []
        for name, (flags, main, sub) in mavutil.px4_map.items():
            if name in self._BEHAVIOUR:
                refusal = PX4_ARMING_DENIED if name in self._NOT_ARMABLE else ""
                flags = self._BASE_FLAGS.get(name, flags)
                modes.append(Mode(name, px4_custom_mode(main, sub), flags, self._BEHAVIOUR[name], refusal,
                                  _PX4_LABELS[name], name in self._NEEDS_RC))
        super().__init__(modes)
        self._unsupported = {
            px4_custom_mode(main, sub): name
            for name, (_f, main, sub) in mavutil.px4_map.items()
            if name in self.UNSUPPORTED
        }

    def mode_for(self, behaviour: Behaviour) -> Mode:
        return self.modes[
            {
                Behaviour.HOLD: "LOITER",
                Behaviour.TAKEOFF: "TAKEOFF",
                Behaviour.OFFBOARD: "OFFBOARD",
                Behaviour.LAND: "LAND",
                Behaviour.RTL: "RTL",
                Behaviour.DESCEND: "POSCTL",
            }[behaviour]
        ]

    def decode_set_mode(self, base_mode: int, param2: float, param3: float) -> tuple[Mode | None, str]:
        main, sub = int(param2), int(param3)
        if main != mavutil.PX4_CUSTOM_MAIN_MODE_AUTO:
            sub = 0
        elif sub == mavutil.PX4_CUSTOM_SUB_MODE_AUTO_READY:
            sub = mavutil.PX4_CUSTOM_SUB_MODE_AUTO_LOITER
        custom = px4_custom_mode(main, sub)
        if custom in self._unsupported:
            return None, f"mode {self._unsupported[custom]} not supported by sim"
        mode = self.by_custom.get(custom)
        if mode is None:
            return None, f"unknown PX4 mode main={main} sub={sub}"
        return mode, ""

    def decode_custom_mode(self, custom_mode: int) -> Mode | None:
        main = (int(custom_mode) >> 16) & 0xFF
        sub = (int(custom_mode) >> 24) & 0xFF
        return self.decode_set_mode(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)[0]


class ArduCopter(Personality):
    """ArduCopter: custom_mode is the plain mode number (GUIDED 4, LAND 9, RTL 6, ...)."""

    name = "ardupilot"
    autopilot = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    boot_mode_name = "STABILIZE"
    _BEHAVIOUR = {
        "STABILIZE": Behaviour.HOLD,
        "ACRO": Behaviour.HOLD,
        "ALT_HOLD": Behaviour.HOLD,
        "AUTO": Behaviour.HOLD,  # no mission: cannot be armed in
        "LOITER": Behaviour.HOLD,
        "POSHOLD": Behaviour.HOLD,
        "BRAKE": Behaviour.HOLD,
        "GUIDED": Behaviour.OFFBOARD,
        "RTL": Behaviour.RTL,
        "SMART_RTL": Behaviour.RTL,
        "LAND": Behaviour.LAND,
    }
    #: ArduCopter's own mode names (Mode::name()) where they differ from pymavlink's.
    _LABELS = {"SMART_RTL": "SMARTRTL"}
    _NOT_ARMABLE = {"RTL", "SMART_RTL", "LAND", "BRAKE"}
    #: base_mode has GUIDED_ENABLED while the position controller runs: measured on SITL, disarmed on the ground,
    #: in these modes; RTL, SMART_RTL and AUTO only run it in flight.
    _GUIDED_FLAG = {"LOITER", "GUIDED", "POSHOLD", "BRAKE", "LAND"}
    GUIDED_FLAG_IN_FLIGHT = {"AUTO", "RTL", "SMART_RTL"}
    #: Modes in which NAV_TAKEOFF works (modes with a user takeoff).
    TAKEOFF_MODES = {"GUIDED", "LOITER", "ALT_HOLD", "POSHOLD"}

    def __init__(self) -> None:
        base = (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
                | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
        modes = []
        for number, name in mavutil.mode_mapping_acm.items():
            if name in self._BEHAVIOUR:
                flags = base | (mavlink.MAV_MODE_FLAG_GUIDED_ENABLED if name in self._GUIDED_FLAG else 0)
                label = self._LABELS.get(name, name)
                if name in self._NOT_ARMABLE:
                    refusal = f"Arm: {label} mode not armable"
                elif name == "AUTO":
                    refusal = "Arm: Mode requires mission"
                else:
                    refusal = ""
                modes.append(Mode(name, number, flags, self._BEHAVIOUR[name], refusal, label))
        super().__init__(modes)

    def base_mode(self, mode: Mode, armed: bool, airborne: bool) -> int:
        flags = super().base_mode(mode, armed, airborne)
        if airborne and mode.name in self.GUIDED_FLAG_IN_FLIGHT:
            flags |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags

    def mode_for(self, behaviour: Behaviour) -> Mode:
        return self.modes[
            {
                Behaviour.HOLD: "LOITER",
                Behaviour.TAKEOFF: "GUIDED",
                Behaviour.OFFBOARD: "GUIDED",
                Behaviour.LAND: "LAND",
                Behaviour.RTL: "RTL",
                Behaviour.DESCEND: "LAND",
            }[behaviour]
        ]

    def decode_set_mode(self, base_mode: int, param2: float, param3: float) -> tuple[Mode | None, str]:
        number = int(param2)
        mode = self.by_custom.get(number)
        if mode is None:
            name = mavutil.mode_mapping_acm.get(number, "?")
            return None, f"ArduCopter mode {number} ({name}) not supported by sim"
        return mode, ""


def make_personality(name: str) -> Personality:
    """``"px4"`` or ``"ardupilot"``.

    Raises
    ------
    ValueError
        For any other name.
    """
    if name == "px4":
        return Px4()
    if name == "ardupilot":
        return ArduCopter()
    raise ValueError(f"unknown autopilot personality {name!r} (expected 'px4' or 'ardupilot')")
