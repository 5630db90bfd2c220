"""Telemetry: the autopilot's MAVLink messages as one SI-unit :class:`Telemetry` snapshot.

One pure ``telemetry_from_*`` function per message family, each ``(telemetry, msg, now_s) -> Telemetry``,
dispatched by :func:`update_telemetry`; plus the map-frame helpers :func:`map_offset` and :func:`map_position`.
STATUSTEXT is reassembled from its chunks first (:mod:`.statustext`) and added with :func:`with_statustext`.
Part of the ``vehicle`` package, the only code that imports pymavlink.

The map frame is NED at the map's origin (lat0, lon0) with altitude 0 at the map's ground; the ground's altitude
above mean sea level (``ground_amsl_m``) ties the autopilot's AMSL altitudes to it (not its home, which real
autopilots move to wherever they arm).
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute.frames import Geodetic, LocalNED, geodetic_to_ned

from .statustext import StatusText

log = logging.getLogger(__name__)

STATUSTEXT_KEEP = 64
_NOT_AUTOPILOT_TYPES = frozenset(
    {
        mavlink.MAV_TYPE_GCS,
        mavlink.MAV_TYPE_GIMBAL,
        mavlink.MAV_TYPE_ADSB,
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink.MAV_TYPE_CAMERA,
    }
)


# ------------------------------------------------------------------------------------------------ telemetry
class Autopilot(enum.Enum):
    """Which mode conventions the autopilot follows, from ``HEARTBEAT.autopilot``."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"
    GENERIC = "generic"  # flown with PX4's conventions


class LandedState(enum.IntEnum):
    """``MAV_LANDED_STATE`` from EXTENDED_SYS_STATE."""

    UNDEFINED = mavlink.MAV_LANDED_STATE_UNDEFINED
    ON_GROUND = mavlink.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink.MAV_LANDED_STATE_LANDING


_NAN = math.nan


@dataclass(frozen=True)
class Telemetry:
    """Everything we know about the vehicle, in SI units. NaN / None until the message first arrives.

    Global: ``lat_deg``, ``lon_deg``, ``alt_amsl_m``, ``relative_alt_m`` (above home), NED ground velocity
    ``v*_mps``. Local (autopilot's EKF frame, NED): ``north_m``, ``east_m``, ``down_m``, ``local_v*_mps``.
    ``*_time_s`` are the autopilot's time since boot of that sample, ``*_rx_s`` our monotonic receive time.
    ``heading_rad`` is yaw from north, clockwise, ``yaw_rate_rad_s`` its rate (clockwise positive) at
    ``attitude_time_s``. ``gps_fix_type`` is GPS_RAW_INT's GPS_FIX_TYPE (-1: never reported),
    ``horizontal_accuracy_m`` its receiver's horizontal accuracy (m, NaN unknown), ``origin`` the EKF origin
    (GPS_GLOBAL_ORIGIN, AMSL), ``home`` HOME_POSITION (AMSL).
    """

    autopilot: Autopilot = Autopilot.GENERIC
    armed: bool = False
    mode: str = ""
    system_status: int = 0
    last_heartbeat_s: float = _NAN
    lat_deg: float = _NAN
    lon_deg: float = _NAN
    alt_amsl_m: float = _NAN
    relative_alt_m: float = _NAN
    v_north_mps: float = _NAN
    v_east_mps: float = _NAN
    v_down_mps: float = _NAN
    global_time_s: float = _NAN
    global_rx_s: float = _NAN
    north_m: float = _NAN
    east_m: float = _NAN
    down_m: float = _NAN
    local_v_north_mps: float = _NAN
    local_v_east_mps: float = _NAN
    local_v_down_mps: float = _NAN
    local_time_s: float = _NAN
    local_rx_s: float = _NAN
    roll_rad: float = _NAN
    pitch_rad: float = _NAN
    heading_rad: float = _NAN
    yaw_rate_rad_s: float = _NAN
    attitude_time_s: float = _NAN
    landed_state: LandedState = LandedState.UNDEFINED
    landed_rx_s: float = _NAN
    battery_voltage_v: float = _NAN
    battery_remaining_pct: float = _NAN
    prearm_ok: bool | None = None
    range_sensors: bool = False  # SYS_STATUS reports a proximity sensor or a laser rangefinder present
    home: Geodetic | None = None
    origin: Geodetic | None = None
    gps_fix_type: int = -1
    satellites: int = -1
    horizontal_accuracy_m: float = math.nan
    statustexts: tuple[StatusText, ...] = field(default_factory=tuple)

    @property
    def has_global(self) -> bool:
        """A global position estimate: ArduPilot streams GLOBAL_POSITION_INT with lat = lon = 0 before it has one."""
        return not math.isnan(self.lat_deg) and not (self.lat_deg == 0.0 and self.lon_deg == 0.0)

    @property
    def has_local(self) -> bool:
        return not math.isnan(self.north_m)

    @property
    def local(self) -> LocalNED:
        """Position in the autopilot's local NED frame."""
        return LocalNED(self.north_m, self.east_m, self.down_m)

    @property
    def on_ground(self) -> bool:
        """Landed: EXTENDED_SYS_STATE says ON_GROUND (or, without it, near home altitude), and not moving vertically.

        The vertical-speed check guards against a landed state that is a moment old: just after takeoff the
        last EXTENDED_SYS_STATE may still say ON_GROUND while the vehicle climbs (at 1.5 m/s or more; a booting
        PX4's estimate wanders at up to ~0.2 m/s while it stands).
        """
        still = not abs(self.v_down_mps) >= 0.5  # an unknown (NaN) speed does not veto the landed state
        if self.landed_state is not LandedState.UNDEFINED:
            return self.landed_state is LandedState.ON_GROUND and still
        return self.relative_alt_m < 0.3 and still

    @property
    def ground_speed_mps(self) -> float:
        return math.hypot(self.local_v_north_mps, self.local_v_east_mps)


def autopilot_from_heartbeat(msg) -> Autopilot:
    """PX4, ArduPilot or generic from ``HEARTBEAT.autopilot``."""
    if msg.autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return Autopilot.PX4
    if msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return Autopilot.ARDUPILOT
    return Autopilot.GENERIC


def is_autopilot_heartbeat(msg) -> bool:
    """True for a flight controller's heartbeat; False for ground stations, gimbals, cameras, companions."""
    return msg.type not in _NOT_AUTOPILOT_TYPES and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID


def telemetry_from_heartbeat(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Armed flag, mode name (pymavlink's tables; PX4's for generic autopilots), autopilot kind, receive time."""
    autopilot = autopilot_from_heartbeat(msg)
    if autopilot is Autopilot.GENERIC and msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        mode = mavutil.interpret_px4_mode(msg.base_mode, msg.custom_mode)  # flown with PX4 conventions
    else:
        mode = mavutil.mode_string_v10(msg)
    return dataclasses.replace(
        t,
        autopilot=autopilot,
        armed=bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED),
        mode=mode,
        system_status=msg.system_status,
        last_heartbeat_s=now_s,
    )


def telemetry_from_global_position_int(t: Telemetry, msg, now_s: float) -> Telemetry:
    """degE7 -> deg, mm -> m, cm/s -> m/s, cdeg heading -> rad (only when ATTITUDE has not given one)."""
    heading = t.heading_rad
    if math.isnan(heading) and msg.hdg != 65535:
        heading = math.radians(msg.hdg / 100.0)
    return dataclasses.replace(
        t,
        lat_deg=msg.lat * 1e-7,
        lon_deg=msg.lon * 1e-7,
        alt_amsl_m=msg.alt * 1e-3,
        relative_alt_m=msg.relative_alt * 1e-3,
        v_north_mps=msg.vx * 1e-2,
        v_east_mps=msg.vy * 1e-2,
        v_down_mps=msg.vz * 1e-2,
        global_time_s=msg.time_boot_ms * 1e-3,
        global_rx_s=now_s,
        heading_rad=heading,
    )


#: The sphere each autopilot's local frame measures metres on (m): ArduPilot's Location::get_distance_NE (and
#: its EKF's GPS fusion) uses LOCATION_SCALING_FACTOR, the equatorial radius; PX4's map projection (lib/geo,
#: azimuthal equidistant) CONSTANTS_RADIUS_OF_EARTH.
LOCAL_FRAME_RADIUS_M = {Autopilot.ARDUPILOT: 6378137.0, Autopilot.PX4: 6371000.0}
_WGS84_A, _WGS84_E2 = 6378137.0, 6.69437999014e-3


def local_scale(t: Telemetry) -> tuple[float, float]:
    """The autopilot's local metres per true metre, north and east, at its origin's latitude.

    An autopilot's LOCAL_POSITION_NED is a latitude/longitude difference times its own sphere's radius, not
    metres on the WGS84 ellipsoid: at SF's latitude ArduPilot's north is 0.29 % long and its east 0.13 % short,
    PX4's 0.18 % and 0.24 %. Measured on ArduCopter SITL: a goal 460 m from home, flown in its local frame as if
    it were true metres, landed 0.98 m from the goal's latitude and longitude (0.05 m by the local estimate).
    Telemetry divides the local frame by this and setpoints multiply by it, so the mission works in true metres.
    (1, 1) for a generic autopilot (its frame unknown: taken as true metres) or before any latitude is known.

    >>> [round(v, 5) for v in local_scale(Telemetry(autopilot=Autopilot.ARDUPILOT, lat_deg=37.79248))]
    [1.00295, 0.99874]
    """
    radius = LOCAL_FRAME_RADIUS_M.get(t.autopilot)
    place = t.origin or t.home
    lat = place.lat_deg if place is not None else t.lat_deg
    if radius is None or not math.isfinite(lat):
        return 1.0, 1.0
    w = 1.0 - _WGS84_E2 * math.sin(math.radians(lat)) ** 2
    meridian, normal = _WGS84_A * (1.0 - _WGS84_E2) / w**1.5, _WGS84_A / math.sqrt(w)
    return radius / meridian, radius / normal


def telemetry_from_local_position_ned(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Autopilot-local NED position (m, in true metres: see :func:`local_scale`) and velocity (m/s)."""
    scale_n, scale_e = local_scale(t)
    return dataclasses.replace(
        t,
        north_m=float(msg.x) / scale_n,
        east_m=float(msg.y) / scale_e,
        down_m=float(msg.z),
        local_v_north_mps=float(msg.vx),
        local_v_east_mps=float(msg.vy),
        local_v_down_mps=float(msg.vz),
        local_time_s=msg.time_boot_ms * 1e-3,
        local_rx_s=now_s,
    )


def telemetry_from_attitude(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Roll, pitch, and yaw as ``heading_rad`` in [0, 2 pi); the yaw rate and the sample's time since boot."""
    return dataclasses.replace(
        t, roll_rad=float(msg.roll), pitch_rad=float(msg.pitch), heading_rad=float(msg.yaw) % (2 * math.pi),
        yaw_rate_rad_s=float(msg.yawspeed), attitude_time_s=msg.time_boot_ms * 1e-3,
    )


def telemetry_from_extended_sys_state(t: Telemetry, msg, now_s: float) -> Telemetry:
    try:
        landed = LandedState(msg.landed_state)
    except ValueError:
        landed = LandedState.UNDEFINED
    return dataclasses.replace(t, landed_state=landed, landed_rx_s=now_s)


def telemetry_from_sys_status(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Battery (mV -> V, -1 unknown -> NaN), the pre-arm check bit when the autopilot reports it, and whether a
    proximity sensor or a laser rangefinder is present (ArduPilot then sends DISTANCE_SENSOR when asked)."""
    prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    ranging = mavlink.MAV_SYS_STATUS_SENSOR_PROXIMITY | mavlink.MAV_SYS_STATUS_SENSOR_LASER_POSITION
    return dataclasses.replace(
        t,
        range_sensors=bool(msg.onboard_control_sensors_present & ranging),
        battery_voltage_v=msg.voltage_battery * 1e-3 if msg.voltage_battery != 65535 else _NAN,
        battery_remaining_pct=float(msg.battery_remaining) if msg.battery_remaining >= 0 else _NAN,
        prearm_ok=bool(msg.onboard_control_sensors_health & prearm)
        if msg.onboard_control_sensors_present & prearm
        else None,
    )


def telemetry_from_home_position(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Home as a :class:`Geodetic` (degE7 -> deg, mm AMSL -> m)."""
    return dataclasses.replace(t, home=Geodetic(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3))


def telemetry_from_gps_global_origin(t: Telemetry, msg, now_s: float) -> Telemetry:
    """The EKF origin as a :class:`Geodetic` (degE7 -> deg, mm AMSL -> m)."""
    return dataclasses.replace(t, origin=Geodetic(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3))


def telemetry_from_gps_raw_int(t: Telemetry, msg, now_s: float) -> Telemetry:
    """GPS fix type (GPS_FIX_TYPE: 3 = 3D), satellites visible (255 unknown -> -1) and the receiver's horizontal
    accuracy (``h_acc``, a MAVLink 2 extension in mm; 0, UINT32_MAX or a MAVLink 1 frame: unknown -> NaN m)."""
    satellites = -1 if msg.satellites_visible == 255 else int(msg.satellites_visible)
    h_acc = int(getattr(msg, "h_acc", 0) or 0)
    accuracy = h_acc / 1000.0 if 0 < h_acc < 0xFFFFFFFF else math.nan
    return dataclasses.replace(t, gps_fix_type=int(msg.fix_type), satellites=satellites,
                               horizontal_accuracy_m=accuracy)


def with_statustext(t: Telemetry, entry: StatusText) -> Telemetry:
    """Append one whole text (keeping the last :data:`STATUSTEXT_KEEP`)."""
    return dataclasses.replace(t, statustexts=(*t.statustexts, entry)[-STATUSTEXT_KEEP:])


TRANSLATORS: dict[str, Callable[[Telemetry, object, float], Telemetry]] = {
    "HEARTBEAT": telemetry_from_heartbeat,
    "GLOBAL_POSITION_INT": telemetry_from_global_position_int,
    "LOCAL_POSITION_NED": telemetry_from_local_position_ned,
    "ATTITUDE": telemetry_from_attitude,
    "EXTENDED_SYS_STATE": telemetry_from_extended_sys_state,
    "SYS_STATUS": telemetry_from_sys_status,
    "HOME_POSITION": telemetry_from_home_position,
    "GPS_GLOBAL_ORIGIN": telemetry_from_gps_global_origin,
    "GPS_RAW_INT": telemetry_from_gps_raw_int,
}


def update_telemetry(t: Telemetry, msg, now_s: float) -> Telemetry:
    """Apply one decoded message; messages we do not translate (STATUSTEXT among them) leave ``t`` unchanged."""
    translate = TRANSLATORS.get(msg.get_type())
    return translate(t, msg, now_s) if translate else t


def map_offset(t: Telemetry, map_origin: Geodetic, ground_amsl_m: float) -> LocalNED:
    """Offset from the autopilot's local frame to the map frame: ``map_ned = local_ned + offset``.

    The map frame is NED at ``map_origin`` (lat0, lon0) with altitude 0 at the map's ground, ``ground_amsl_m``
    metres above mean sea level; the vehicle's map altitude is ``alt_amsl_m - ground_amsl_m``. The local sample is
    extrapolated with its velocity to the global sample's time, so the two describe the same instant.

    >>> t = Telemetry(lat_deg=37.79248, lon_deg=-122.39745, alt_amsl_m=25.0, global_time_s=10.0,
    ...               north_m=1.0, east_m=2.0, down_m=-4.0, local_v_north_mps=2.0, local_v_east_mps=0.0,
    ...               local_v_down_mps=0.0, local_time_s=9.5)
    >>> [round(v, 3) for v in map_offset(t, Geodetic(37.79248, -122.39745), ground_amsl_m=20.0)]
    [-2.0, -2.0, -1.0]
    """
    if not (t.has_global and t.has_local):
        raise ValueError("map_offset needs both GLOBAL_POSITION_INT and LOCAL_POSITION_NED")
    if not math.isfinite(ground_amsl_m):
        raise ValueError(f"map_offset needs a finite ground altitude, got {ground_amsl_m}")
    dt = t.global_time_s - t.local_time_s
    if not math.isfinite(dt) or abs(dt) > 1.0:
        dt = 0.0
    local = LocalNED(
        t.north_m + t.local_v_north_mps * dt, t.east_m + t.local_v_east_mps * dt, t.down_m + t.local_v_down_mps * dt
    )
    here = map_position(t, map_origin, ground_amsl_m)
    return LocalNED(here.north_m - local.north_m, here.east_m - local.east_m, here.down_m - local.down_m)


def map_position(t: Telemetry, map_origin: Geodetic, ground_amsl_m: float) -> LocalNED:
    """The vehicle's map-frame position from its global position alone (down = ``ground_amsl_m - alt_amsl_m``).

    >>> t = Telemetry(lat_deg=37.79248, lon_deg=-122.39745, alt_amsl_m=7.5)
    >>> map_position(t, Geodetic(37.79248, -122.39745), ground_amsl_m=2.5).altitude_m
    5.0
    """
    horizontal = geodetic_to_ned(Geodetic(t.lat_deg, t.lon_deg, map_origin.alt_m), map_origin)
    return LocalNED(horizontal.north_m, horizontal.east_m, ground_amsl_m - t.alt_amsl_m)
