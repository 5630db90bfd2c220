"""The MAVLink vehicle: the only package that imports pymavlink.

:class:`MavlinkVehicle` (``control``) flies a PX4, ArduPilot or generic autopilot over any pymavlink
connection; underneath, ``link`` runs the reader, sender and keeper threads over one ``transport`` (MAVLink 2,
signing, TCP reconnects), ``commands`` matches acks to commands, ``streams`` keeps the telemetry coming,
``health`` judges the link by any message and its round trip, ``params`` decodes parameters, ``limits`` turns
them into speed limits and link-loss behaviour, ``readiness`` says what a fresh autopilot still lacks,
``modes`` names and classifies flight modes, ``statustext`` reassembles the autopilot's texts, and
``telemetry`` translates MAVLink into the SI :class:`Telemetry` snapshot.

Frames: ``LOCAL_POSITION_NED`` is relative to wherever the autopilot's EKF started, which need not be the map
origin. :func:`map_offset` computes ``map_ned - autopilot_local_ned`` from one GLOBAL_POSITION_INT sample and the
LOCAL_POSITION_NED sample extrapolated to the same instant; map altitude 0 is the map's ground, whose altitude
above mean sea level the mission works out (not the autopilot's home, which real autopilots reset at arming).
"""

from .control import MavlinkVehicle
from .errors import (
    BadConnection,
    CommandRejected,
    CommandTimeout,
    ConnectionTimeout,
    LinkLost,
    SigningRequired,
    TelemetryTimeout,
    UnsupportedMode,
    VehicleError,
    command_name,
    result_name,
)
from .limits import FlightLimits, flight_limits
from .link import (
    TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW,
    TYPE_MASK_POSITION_VELOCITY_YAW,
    TYPE_MASK_POSITION_YAW,
    MavlinkLink,
)
from .modes import ModeKind, flight_mode, mode_kind, mode_numbers
from .readiness import Readiness, readiness
from .statustext import StatusText, StatusTextAssembler, refusal_reason
from .telemetry import (
    STATUSTEXT_KEEP,
    Autopilot,
    LandedState,
    Telemetry,
    autopilot_from_heartbeat,
    is_autopilot_heartbeat,
    map_offset,
    map_position,
    telemetry_from_attitude,
    telemetry_from_extended_sys_state,
    telemetry_from_global_position_int,
    telemetry_from_gps_global_origin,
    telemetry_from_gps_raw_int,
    telemetry_from_heartbeat,
    telemetry_from_home_position,
    telemetry_from_local_position_ned,
    telemetry_from_sys_status,
    update_telemetry,
    with_statustext,
)
from .transport import signing_key

__all__ = [
    "STATUSTEXT_KEEP", "TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW", "TYPE_MASK_POSITION_VELOCITY_YAW",
    "TYPE_MASK_POSITION_YAW", "Autopilot", "BadConnection",
    "CommandRejected", "CommandTimeout", "ConnectionTimeout", "FlightLimits", "LandedState", "LinkLost",
    "MavlinkLink", "MavlinkVehicle", "ModeKind", "Readiness", "SigningRequired", "StatusText", "StatusTextAssembler",
    "Telemetry", "TelemetryTimeout", "UnsupportedMode", "VehicleError", "autopilot_from_heartbeat", "command_name",
    "flight_limits", "flight_mode", "is_autopilot_heartbeat", "map_offset", "map_position", "mode_kind",
    "mode_numbers", "readiness", "refusal_reason", "result_name", "signing_key", "telemetry_from_attitude",
    "telemetry_from_extended_sys_state", "telemetry_from_global_position_int", "telemetry_from_gps_global_origin",
    "telemetry_from_gps_raw_int", "telemetry_from_heartbeat", "telemetry_from_home_position",
    "telemetry_from_local_position_ned", "telemetry_from_sys_status", "update_telemetry", "with_statustext",
]
