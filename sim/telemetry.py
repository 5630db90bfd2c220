"""Outgoing MAVLink: telemetry message builders.

Builders read a :class:`TelemetrySnapshot` (SI units, map frame) and return pymavlink message
objects of the common v2 dialect; the transport packs them per link. What is sent when is
:mod:`sim.streams`; the parameter table is :mod:`sim.params`.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

SYSTEM_ID = 1
COMPONENT_ID = 1

M = mavlink  # short alias for enum names below

SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_PREARM_CHECK
)
#: What SYS_STATUS adds while the obstacle sensors stream, as ArduPilot reports a configured proximity sensor and
#: rangefinder (GCS_MAVLINK::update_sensor_status_flags): a client learns from these bits that DISTANCE_SENSOR is
#: worth asking for.
RANGE_SENSORS = M.MAV_SYS_STATUS_SENSOR_PROXIMITY | M.MAV_SYS_STATUS_SENSOR_LASER_POSITION

#: AUTOPILOT_VERSION.capabilities as the real autopilots send them (measured on PX4 1.15.4 and ArduCopter 4.7.0-dev
#: SITL). PX4's includes MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE: its integer parameters come bytewise
#: (sim.params), which a client reads from this bit.
CAPABILITIES_PX4 = 0xE8FF
CAPABILITIES_ARDUPILOT = 0xFBEF


@dataclass
class TelemetrySnapshot:
    """Everything the builders need, in SI units.

    Positions are reported values (GPS noise applied); ``local_*`` are relative to the local NED
    origin; altitudes are metres above the map datum.
    """

    time_boot_ms: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    relative_alt_m: float
    local_north_m: float
    local_east_m: float
    local_down_m: float
    vel_north_m_s: float
    vel_east_m_s: float
    vel_down_m_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    yaw_rate_rad_s: float
    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float
    home_local_north_m: float
    home_local_east_m: float
    home_local_down_m: float
    autopilot: int
    base_mode: int
    custom_mode: int
    system_status: int
    landed_state: int
    armable: bool
    throttle_pct: int
    gps_fix_type: int
    gps_has_fix: bool
    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_m: float
    #: ArduPilot's GLOBAL_POSITION_INT reads 0,0 until the GPS has a fix.
    global_zero_until_fix: bool
    #: The obstacle sensors (horizontal and downward) are on: SYS_STATUS reports them present.
    range_sensors: bool = False
    #: GPS_RAW_INT's accuracy: HDOP and VDOP x 100, horizontal and vertical accuracy (mm).
    gps_eph: int = 70
    gps_epv: int = 110
    gps_h_acc_mm: int = 900
    gps_v_acc_mm: int = 900


def _deg7(value: float) -> int:
    return int(round(value * 1e7))


def _cdeg(yaw_rad: float) -> int:
    return int(round(math.degrees(yaw_rad) % 360.0 * 100.0)) % 36000


def heartbeat(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(
        M.MAV_TYPE_QUADROTOR, s.autopilot, s.base_mode, s.custom_mode, s.system_status, 3
    )


def sys_status(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    present = SENSORS | (RANGE_SENSORS if s.range_sensors else 0)
    health = present if s.armable else present & ~M.MAV_SYS_STATUS_PREARM_CHECK
    return mavlink.MAVLink_sys_status_message(
        present, present, health, 200, 16000, -1, 100, 0, 0, 0, 0, 0, 0
    )


def gps_raw_int(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    if not s.gps_has_fix or s.gps_fix_type < M.GPS_FIX_TYPE_2D_FIX:
        return mavlink.MAVLink_gps_raw_int_message(s.time_boot_ms * 1000, s.gps_fix_type, 0, 0, 0, 65535, 65535,
                                                   0, 65535, 0)
    vel = math.hypot(s.vel_north_m_s, s.vel_east_m_s)
    cog = _cdeg(math.atan2(s.vel_east_m_s, s.vel_north_m_s)) if vel > 0.1 else 65535
    return mavlink.MAVLink_gps_raw_int_message(
        s.time_boot_ms * 1000, s.gps_fix_type, _deg7(s.lat_deg), _deg7(s.lon_deg),
        int(round(s.alt_m * 1000)), s.gps_eph, s.gps_epv, int(round(vel * 100)), cog, 14,
        h_acc=s.gps_h_acc_mm, v_acc=s.gps_v_acc_mm,
    )


def global_position_int(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    if s.global_zero_until_fix and not s.gps_has_fix:
        return mavlink.MAVLink_global_position_int_message(s.time_boot_ms, 0, 0, 0, 0, 0, 0, 0, _cdeg(s.yaw_rad))
    return mavlink.MAVLink_global_position_int_message(
        s.time_boot_ms, _deg7(s.lat_deg), _deg7(s.lon_deg), int(round(s.alt_m * 1000)),
        int(round(s.relative_alt_m * 1000)), int(round(s.vel_north_m_s * 100)),
        int(round(s.vel_east_m_s * 100)), int(round(s.vel_down_m_s * 100)), _cdeg(s.yaw_rad),
    )


def local_position_ned(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_local_position_ned_message(
        s.time_boot_ms, s.local_north_m, s.local_east_m, s.local_down_m,
        s.vel_north_m_s, s.vel_east_m_s, s.vel_down_m_s,
    )


def _quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]


def attitude(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_attitude_message(
        s.time_boot_ms, s.roll_rad, s.pitch_rad, s.yaw_rad, 0.0, 0.0, s.yaw_rate_rad_s
    )


def attitude_quaternion(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    q = _quaternion(s.roll_rad, s.pitch_rad, s.yaw_rad)
    return mavlink.MAVLink_attitude_quaternion_message(s.time_boot_ms, *q, 0.0, 0.0, s.yaw_rate_rad_s)


def extended_sys_state(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_MC, s.landed_state)


def home_position(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_home_position_message(
        _deg7(s.home_lat_deg), _deg7(s.home_lon_deg), int(round(s.home_alt_m * 1000)),
        s.home_local_north_m, s.home_local_east_m, s.home_local_down_m,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, s.time_boot_ms * 1000,
    )


def gps_global_origin(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_gps_global_origin_message(
        _deg7(s.origin_lat_deg), _deg7(s.origin_lon_deg), int(round(s.origin_alt_m * 1000)), s.time_boot_ms * 1000
    )


def system_time(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_system_time_message(int(time.time() * 1e6), s.time_boot_ms)


def vfr_hud(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    ground = math.hypot(s.vel_north_m_s, s.vel_east_m_s)
    return mavlink.MAVLink_vfr_hud_message(
        ground, ground, _cdeg(s.yaw_rad) // 100, s.throttle_pct, s.alt_m, -s.vel_down_m_s
    )


def battery_status(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    cells = [4000] * 4 + [65535] * 6
    return mavlink.MAVLink_battery_status_message(
        0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500, cells, -1, -1, -1, 100
    )


def autopilot_version(s: TelemetrySnapshot) -> mavlink.MAVLink_message:
    capabilities = CAPABILITIES_PX4 if s.autopilot == M.MAV_AUTOPILOT_PX4 else CAPABILITIES_ARDUPILOT
    return mavlink.MAVLink_autopilot_version_message(
        capabilities, 0x01000000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5349_4D00_0000_0001
    )


BUILDERS = {
    M.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    M.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    M.MAVLINK_MSG_ID_ATTITUDE: attitude,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: attitude_quaternion,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    M.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    M.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
    M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: gps_global_origin,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
}


_CHUNK_IDS = itertools.count()


def statustext(severity: int, text: str) -> list[mavlink.MAVLink_message]:
    """STATUSTEXT message(s); texts longer than 50 bytes are chunked with a shared id."""
    raw = text.encode("ascii", errors="replace")
    if len(raw) <= 50:
        return [mavlink.MAVLink_statustext_message(severity, raw, 0, 0)]
    chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)]
    ident = next(_CHUNK_IDS) % 65535 + 1
    return [mavlink.MAVLink_statustext_message(severity, c, ident, k) for k, c in enumerate(chunks)]
