"""Autopilot personalities: flight-mode tables and HEARTBEAT identity.

Mode numbers come from pymavlink's tables (``mavutil.px4_map``, ``mavutil.mode_mapping_acm``), not
hand-written constants. Each mode maps to a :class:`Behaviour`, the thing the sim actually does.

PX4 ``custom_mode`` layout: ``(main_mode << 16) | (sub_mode << 24)``. ArduCopter: the mode number.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink


class Behaviour(enum.Enum):
    """What the vehicle does in a mode."""

    HOLD = "hold"  # hold position (manual-type modes too: there is no RC)
    TAKEOFF = "takeoff"
    OFFBOARD = "offboard"  # follow SET_POSITION_TARGET_* (PX4 OFFBOARD, ArduCopter GUIDED)
    LAND = "land"
    RTL = "rtl"


@dataclass(frozen=True)
class Mode:
    """One flight mode of a personality."""

    name: str
    custom_mode: int
    base_flags: int
    behaviour: Behaviour
    armable: bool = True


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
        "MANUAL": Behaviour.HOLD,
        "STABILIZED": Behaviour.HOLD,
        "ACRO": Behaviour.HOLD,
        "RATTITUDE": Behaviour.HOLD,
        "ALTCTL": Behaviour.HOLD,
        "POSCTL": Behaviour.HOLD,
    }
    _NOT_ARMABLE = {"LAND", "RTL"}
    #: Modes PX4 has that the sim refuses (no mission, no follow target).
    UNSUPPORTED = {"MISSION", "RTGS", "FOLLOWME"}

    def __init__(self) -> None:
        modes = []
        for name, (flags, main, sub) in mavutil.px4_map.items():
            if name in self._BEHAVIOUR:
                modes.append(
                    Mode(name, px4_custom_mode(main, sub), flags, self._BEHAVIOUR[name],
                         name not in self._NOT_ARMABLE)
                )
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
            }[behaviour]
        ]

    def decode_set_mode(self, base_mode: int, param2: float, param3: float) -> tuple[Mode | None, str]:
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None, "DO_SET_MODE without CUSTOM_MODE_ENABLED"
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
        "LOITER": Behaviour.HOLD,
        "POSHOLD": Behaviour.HOLD,
        "BRAKE": Behaviour.HOLD,
        "GUIDED": Behaviour.OFFBOARD,
        "RTL": Behaviour.RTL,
        "SMART_RTL": Behaviour.RTL,
        "LAND": Behaviour.LAND,
    }
    _NOT_ARMABLE = {"RTL", "SMART_RTL", "LAND"}

    def __init__(self) -> None:
        flags = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        modes = []
        for number, name in mavutil.mode_mapping_acm.items():
            if name in self._BEHAVIOUR:
                extra = mavlink.MAV_MODE_FLAG_GUIDED_ENABLED if name == "GUIDED" else 0
                armable = name not in self._NOT_ARMABLE
                modes.append(Mode(name, number, flags | extra, self._BEHAVIOUR[name], armable))
        super().__init__(modes)

    def mode_for(self, behaviour: Behaviour) -> Mode:
        return self.modes[
            {
                Behaviour.HOLD: "LOITER",
                Behaviour.TAKEOFF: "GUIDED",
                Behaviour.OFFBOARD: "GUIDED",
                Behaviour.LAND: "LAND",
                Behaviour.RTL: "RTL",
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
