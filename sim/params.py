"""The parameter tables of both personalities and their MAVLink encoding (PARAM_VALUE / PARAM_SET).

Names, defaults and MAV_PARAM_TYPEs were read from the real autopilots with PARAM_REQUEST_READ: ArduCopter
SITL V4.7.0-dev with ``copter.parm`` and PX4 v1.15.4 SITL (SIH quadcopter, airframe 10040). Each parameter here
changes what the sim does (the description says how); the real tables hold ~1350 (ArduCopter) and ~900 (PX4)
parameters, so ``param_count`` differs (a known difference).

Encoding, as measured:

* ArduPilot sends every value as the float of its number (DISARM_DELAY, an INT8, reads 10.0) and answers a read
  by name, and echoes a PARAM_SET, with ``param_index`` 65535; reads by index and PARAM_REQUEST_LIST carry the
  index.
* PX4 sends INT32 parameters bytewise: the int32's four bytes reinterpreted as a float (COM_DL_LOSS_T = 10 reads
  1.4e-44), and decodes a PARAM_SET of an INT32 parameter the same way. It always sends the real index.

Neither answers a read or a set of a name it does not know.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32
INT16 = mavlink.MAV_PARAM_TYPE_INT16
INT8 = mavlink.MAV_PARAM_TYPE_INT8
#: ArduPilot's param_index for a PARAM_VALUE that answers a read by name or a PARAM_SET.
ARDUPILOT_NAMED_INDEX = 65535


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its real default, MAVLink type, and what the sim does with it."""

    default: float
    ptype: int
    description: str


PX4_PARAMS: dict[str, ParamSpec] = {
    "COM_OF_LOSS_T": ParamSpec(1.0, REAL32, "offboard setpoints older than this (s) -> COM_OBL_RC_ACT"),
    "COM_OBL_RC_ACT": ParamSpec(0, INT32, "offboard loss action: 0 position, 1 altitude, 2 manual (no RC: the "
                                          "vehicle sinks to the ground at MPC_LAND_SPEED), 3 return, 4 land, "
                                          "5 hold, 6 terminate, 7 disarm"),
    "NAV_DLL_ACT": ParamSpec(0, INT32, "GCS heartbeat loss action: 0 none, 1 hold, 2 return, 3 land, "
                                       "5 terminate, 6 disarm"),
    "COM_DL_LOSS_T": ParamSpec(10, INT32, "no GCS heartbeat for this long (s) = data link lost"),
    "COM_DISARM_PRFLT": ParamSpec(10.0, REAL32, "armed without taking off for this long (s) -> disarm (<= 0: off)"),
    "COM_DISARM_LAND": ParamSpec(2.0, REAL32, "landed for this long (s) -> disarm (< 0: off)"),
    "MPC_XY_VEL_MAX": ParamSpec(12.0, REAL32, "max horizontal speed (m/s)"),
    "MPC_ACC_HOR": ParamSpec(3.0, REAL32, "max horizontal acceleration in Hold, takeoff, land, return (m/s^2)"),
    "MPC_ACC_HOR_MAX": ParamSpec(5.0, REAL32, "max horizontal acceleration in OFFBOARD (m/s^2; SITL: a 40 m step "
                                              "reached ~5-7 m/s^2, not MPC_ACC_HOR)"),
    "MPC_TILTMAX_AIR": ParamSpec(45.0, REAL32, "max tilt in the air (deg): bounds the lean that accelerates the "
                                               "vehicle and holds it against the wind"),
    "MPC_Z_VEL_MAX_UP": ParamSpec(3.0, REAL32, "max climb rate (m/s)"),
    "MPC_Z_VEL_MAX_DN": ParamSpec(1.5, REAL32, "max descent rate (m/s)"),
    "MPC_LAND_SPEED": ParamSpec(0.7, REAL32, "landing descent rate (m/s)"),
    "MIS_TAKEOFF_ALT": ParamSpec(2.5, REAL32, "takeoff height above home when NAV_TAKEOFF param7 is NaN (m)"),
    "RTL_RETURN_ALT": ParamSpec(30.0, REAL32, "RTL climbs to this height above home first (m)"),
    "COM_LOW_BAT_ACT": ParamSpec(2, INT32, "battery failsafe at the critical level: 0 warning, 2 land, 3 return "
                                           "(--battery-low is the low level: a warning only, as on PX4)"),
    "GF_ACTION": ParamSpec(2, INT32, "geofence breach: 0 none, 1 warning, 2 hold, 3 return, 5 land (in OFFBOARD "
                                     "only \"Failsafe activated\", as measured on PX4 1.15 SITL)"),
    "GF_MAX_HOR_DIST": ParamSpec(0.0, REAL32, "geofence: the most (m) from home horizontally (0: none)"),
    "GF_MAX_VER_DIST": ParamSpec(0.0, REAL32, "geofence: the most (m) above home (0: none)"),
}

ARDUPILOT_PARAMS: dict[str, ParamSpec] = {
    "FS_GCS_ENABLE": ParamSpec(0, INT8, "GCS heartbeat loss action: 0 none, 1/2/3/6 RTL, 4/5/7 land"),
    "FS_GCS_TIMEOUT": ParamSpec(5.0, REAL32, "no GCS heartbeat (from MAV_GCS_SYSID) for this long (s) = lost"),
    "MAV_GCS_SYSID": ParamSpec(255, INT16, "system id whose heartbeats count as the GCS's"),
    "GUID_TIMEOUT": ParamSpec(3.0, REAL32, "GUIDED: a velocity target is followed for this long (s) after the "
                                           "last setpoint, then the vehicle stops"),
    "WPNAV_SPEED": ParamSpec(1000.0, REAL32, "max horizontal speed (cm/s)"),
    "WPNAV_ACCEL": ParamSpec(250.0, REAL32, "max horizontal acceleration, GUIDED included (cm/s^2; SITL: a 40 m "
                                            "step peaked at ~2.6 m/s^2)"),
    "WPNAV_SPEED_UP": ParamSpec(250.0, REAL32, "max climb rate (cm/s)"),
    "WPNAV_SPEED_DN": ParamSpec(150.0, REAL32, "max descent rate (cm/s)"),
    "LAND_SPEED": ParamSpec(50, INT16, "landing descent rate (cm/s)"),
    "ANGLE_MAX": ParamSpec(3000, INT16, "max lean angle (centidegrees): bounds the lean that accelerates the vehicle "
                                        "and holds it against the wind"),
    "DISARM_DELAY": ParamSpec(10, INT8, "landed (or armed on the ground) for this long (s) -> disarm (0: off)"),
    "PILOT_TKOFF_ALT": ParamSpec(0.0, REAL32, "takeoff height when NAV_TAKEOFF param7 is NaN (cm; at least 1 m)"),
    "RTL_ALT": ParamSpec(1500, INT32, "RTL climbs to this height above home first (cm)"),
    "BATT_FS_LOW_ACT": ParamSpec(0, INT8, "low battery action (--battery-low): 0 warning, 1 land, 2 RTL, "
                                          "3/4 SmartRTL, 5 terminate"),
    "FENCE_ENABLE": ParamSpec(0, INT8, "geofence on (1) or off (0)"),
    "FENCE_TYPE": ParamSpec(7, INT8, "fence kinds, bits: 1 max altitude, 2 circle round home (4 polygon: not "
                                     "simulated)"),
    "FENCE_ACTION": ParamSpec(1, INT8, "breach: 0 report only, 1 RTL, 2 land, 3/5 SmartRTL, 4 brake"),
    "FENCE_RADIUS": ParamSpec(150.0, REAL32, "circle fence radius round home (m; SITL's copter.parm sets 150, the "
                                             "firmware's default is 300)"),
    "FENCE_ALT_MAX": ParamSpec(100.0, REAL32, "altitude fence above home (m)"),
    "FENCE_MARGIN": ParamSpec(2.0, REAL32, "how far inside the fence the autopilot tries to stay (m)"),
}

#: Link-loss timeouts that ``SimConfig(scale_timeouts=True)`` multiplies by the speedup (see sim/__init__.py).
LINK_LOSS_TIMEOUTS = ("COM_OF_LOSS_T", "COM_DL_LOSS_T", "FS_GCS_TIMEOUT")


def table_for(autopilot: str) -> dict[str, ParamSpec]:
    """The parameter table of ``"px4"`` or ``"ardupilot"``."""
    return PX4_PARAMS if autopilot == "px4" else ARDUPILOT_PARAMS


def _as_int32_bits(value: float) -> float:
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def _from_int32_bits(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


class ParamTable:
    """Current parameter values of one vehicle.

    Parameters
    ----------
    autopilot : {"px4", "ardupilot"}
    overrides : dict, optional
        ``{name: value}`` set at boot (as SITL's defaults file or PX4's ``param set``).
    speedup : float
        With ``scale_timeouts``, :data:`LINK_LOSS_TIMEOUTS` are multiplied by it.
    scale_timeouts : bool

    Raises
    ------
    ValueError
        For an override of a name this personality does not have, or a value that is not finite.
    """

    def __init__(self, autopilot: str, overrides: dict | None = None, speedup: float = 1.0,
                 scale_timeouts: bool = False) -> None:
        self.autopilot = autopilot
        self.specs = table_for(autopilot)
        self.names = list(self.specs)
        self.values = {name: float(spec.default) for name, spec in self.specs.items()}
        if scale_timeouts:
            for name in LINK_LOSS_TIMEOUTS:
                if name in self.values:
                    self.values[name] = self._typed(name, self.values[name] * speedup)
        for name, value in (overrides or {}).items():
            if name not in self.specs:
                raise ValueError(f"unknown parameter {name!r} for the {autopilot} personality "
                                 f"(known: {', '.join(self.names)})")
            if not math.isfinite(float(value)):
                raise ValueError(f"parameter {name} must be a finite number, not {value}")
            self.values[name] = self._typed(name, float(value))

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def __contains__(self, name: str) -> bool:
        return name in self.values

    def _typed(self, name: str, value: float) -> float:
        return value if self.specs[name].ptype == REAL32 else float(round(value))

    def index(self, name: str) -> int:
        return self.names.index(name)

    def decode_set(self, name: str, wire_value: float) -> float | None:
        """The value a PARAM_SET asks for, or None if ``name`` is unknown or the value is not finite."""
        if name not in self.specs:
            return None
        if self.autopilot == "px4" and self.specs[name].ptype == INT32:
            return float(_from_int32_bits(wire_value))
        return self._typed(name, float(wire_value)) if math.isfinite(wire_value) else None

    def set(self, name: str, value: float) -> None:
        self.values[name] = self._typed(name, value)

    def value_message(self, name: str, named: bool) -> mavlink.MAVLink_param_value_message:
        """PARAM_VALUE for ``name``; ``named``: answering a read by name or a PARAM_SET (ArduPilot index 65535)."""
        spec = self.specs[name]
        value = self.values[name]
        if self.autopilot == "px4" and spec.ptype == INT32:
            wire = _as_int32_bits(value)
        else:
            wire = value
        index = ARDUPILOT_NAMED_INDEX if named and self.autopilot == "ardupilot" else self.index(name)
        return mavlink.MAVLink_param_value_message(name.encode("ascii"), wire, spec.ptype, len(self.names), index)
