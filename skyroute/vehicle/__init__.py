"""The MAVLink link to the autopilot: the only module that imports pymavlink.

:class:`MavlinkVehicle` connects with any pymavlink connection string, waits for the autopilot's heartbeat,
requests telemetry, and runs two threads: a reader that translates every message into the SI :class:`Telemetry`
dataclass, and a sender that sends our HEARTBEAT at 1 Hz and, while we control the vehicle, re-sends the current
position setpoint at ``setpoint_rate_hz`` (PX4 leaves OFFBOARD after 0.5 s without one).

MAVLink is translated at one boundary: one pure ``telemetry_from_*`` function per message family, each
``(telemetry, msg, now_s) -> Telemetry``, dispatched by :func:`update_telemetry`.

Frames: ``LOCAL_POSITION_NED`` is relative to wherever the autopilot's EKF started, which need not be the map
origin. :func:`map_offset` computes ``map_ned - autopilot_local_ned`` from one GLOBAL_POSITION_INT sample and
the LOCAL_POSITION_NED sample extrapolated to the same instant; map altitude 0 is the home altitude, so the map
``down`` of the vehicle is ``-relative_alt_m``.
"""

from .link import (
    TYPE_MASK_POSITION_VELOCITY_YAW,
    TYPE_MASK_POSITION_YAW,
    CommandRejected,
    CommandTimeout,
    ConnectionTimeout,
    LinkLost,
    MavlinkVehicle,
    TelemetryTimeout,
    UnsupportedMode,
    VehicleError,
    command_name,
    mode_numbers,
    result_name,
)
from .telemetry import (
    STATUSTEXT_KEEP,
    Autopilot,
    LandedState,
    StatusText,
    Telemetry,
    autopilot_from_heartbeat,
    is_autopilot_heartbeat,
    map_offset,
    map_position,
    telemetry_from_attitude,
    telemetry_from_extended_sys_state,
    telemetry_from_global_position_int,
    telemetry_from_heartbeat,
    telemetry_from_home_position,
    telemetry_from_local_position_ned,
    telemetry_from_statustext,
    telemetry_from_sys_status,
    update_telemetry,
)

__all__ = [
    "STATUSTEXT_KEEP", "TYPE_MASK_POSITION_VELOCITY_YAW", "TYPE_MASK_POSITION_YAW", "Autopilot", "CommandRejected",
    "CommandTimeout", "ConnectionTimeout", "LandedState", "LinkLost", "MavlinkVehicle", "StatusText", "Telemetry",
    "TelemetryTimeout", "UnsupportedMode", "VehicleError", "autopilot_from_heartbeat", "command_name",
    "is_autopilot_heartbeat", "map_offset", "map_position", "mode_numbers", "result_name", "telemetry_from_attitude",
    "telemetry_from_extended_sys_state", "telemetry_from_global_position_int", "telemetry_from_heartbeat",
    "telemetry_from_home_position", "telemetry_from_local_position_ned", "telemetry_from_statustext",
    "telemetry_from_sys_status", "update_telemetry",
]
