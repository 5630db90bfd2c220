"""Which messages each link gets, how often, and from when (all in simulated seconds).

Measured on a fresh link with the real autopilots' default settings:

* ArduCopter SITL (default SRx_* rates) volunteers only HEARTBEAT (1 Hz), STATUSTEXT and, when the EKF origin
  and home are set, GPS_GLOBAL_ORIGIN and HOME_POSITION (once each, to every link; again when home moves).
  Everything else must be asked for: SET_MESSAGE_INTERVAL per message, or REQUEST_DATA_STREAM per group
  (:data:`ARDUPILOT_STREAM_GROUPS`, the groups' members the sim builds).
* PX4's onboard/API link (UDP 14540, the link a companion-computer client uses) streams without being asked,
  at the rates of :data:`PX4_ONBOARD_RATES_HZ` (plus messages the sim does not build: HIGHRES_IMU, ODOMETRY,
  ALTITUDE, ...). GLOBAL_POSITION_INT only once the estimator has a global position.

Rates are in simulated time, as on SITL with a speed-up. To keep the wall-clock load bounded, a message is sent
at most once per physics step and at most :data:`MAX_WALL_RATE_HZ` times per wall-clock second per link; so at
``--speedup 10`` a 50 Hz stream arrives at 5 Hz of simulated time (50 Hz of wall-clock time).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from . import telemetry as tm
from .sensors import SENSOR_MESSAGE_IDS

M = mavlink
#: At most this many messages of one kind per wall-clock second per link.
MAX_WALL_RATE_HZ = 50.0

#: PX4 v1.15.4 onboard link, measured (Hz, simulated time). ATTITUDE is measured at 100 Hz (the physics step
#: limits it to 50).
PX4_ONBOARD_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: 8.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 10.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
}
ARDUPILOT_DEFAULT_RATES_HZ: dict[int, float] = {M.MAVLINK_MSG_ID_HEARTBEAT: 1.0}

#: ArduCopter's REQUEST_DATA_STREAM groups, measured, restricted to the messages the sim builds.
ARDUPILOT_STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    M.MAV_DATA_STREAM_RAW_SENSORS: (),
    M.MAV_DATA_STREAM_EXTENDED_STATUS: (M.MAVLINK_MSG_ID_SYS_STATUS, M.MAVLINK_MSG_ID_GPS_RAW_INT),
    M.MAV_DATA_STREAM_RC_CHANNELS: (),
    M.MAV_DATA_STREAM_RAW_CONTROLLER: (),
    M.MAV_DATA_STREAM_POSITION: (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    M.MAV_DATA_STREAM_EXTRA1: (M.MAVLINK_MSG_ID_ATTITUDE,),
    M.MAV_DATA_STREAM_EXTRA2: (M.MAVLINK_MSG_ID_VFR_HUD,),
    M.MAV_DATA_STREAM_EXTRA3: (M.MAVLINK_MSG_ID_SYSTEM_TIME, M.MAVLINK_MSG_ID_BATTERY_STATUS,
                               M.MAVLINK_MSG_ID_DISTANCE_SENSOR),
}


def default_rates_hz(autopilot: str, sensor_hz: float | None = None) -> dict[int, float]:
    """What a fresh link gets without asking (Hz, simulated time). ``sensor_hz``: the obstacle sensors' rate when
    they are on (PX4 streams OBSTACLE_DISTANCE and the downward DISTANCE_SENSOR at it; ArduPilot only when asked)."""
    rates = dict(PX4_ONBOARD_RATES_HZ if autopilot == "px4" else ARDUPILOT_DEFAULT_RATES_HZ)
    if autopilot == "px4" and sensor_hz is not None:
        rates[M.MAVLINK_MSG_ID_OBSTACLE_DISTANCE] = sensor_hz
        rates[M.MAVLINK_MSG_ID_DISTANCE_SENSOR] = sensor_hz
    return rates


def available(ap, msg_id: int) -> bool:
    """Whether the vehicle has the data for ``msg_id`` yet (see :mod:`sim.boot`)."""
    t, boot = ap.sim_time_s, ap.boot
    if msg_id == M.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
        return t >= boot.local_position_s
    if msg_id == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        return not ap.is_px4 or t >= boot.global_position_s
    if msg_id == M.MAVLINK_MSG_ID_HOME_POSITION:
        return ap.home_neu is not None
    if msg_id == M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
        return ap.origin_set
    if msg_id in SENSOR_MESSAGE_IDS:
        return ap.sensor is not None and t >= boot.heartbeat_s
    return t >= boot.heartbeat_s


class StreamScheduler:
    """Per-link stream rates and due times (simulated seconds).

    Parameters
    ----------
    autopilot : {"px4", "ardupilot"}
    speedup : float
    physics_dt_s : float
        No message is due more often than once per physics step.
    sensor_hz : float or None
        The obstacle sensors' rate, None when they are off (see :func:`default_rates_hz`).
    """

    def __init__(self, autopilot: str, speedup: float, physics_dt_s: float, sensor_hz: float | None = None) -> None:
        self.autopilot = autopilot
        self.sensor_hz = sensor_hz
        self.min_interval_s = max(physics_dt_s, speedup / MAX_WALL_RATE_HZ)

    def attach(self, link, now_s: float) -> None:
        """Give a new link the default streams, first due now."""
        link.intervals = {}
        link.next_due = {}
        for msg_id, hz in default_rates_hz(self.autopilot, self.sensor_hz).items():
            self.set_rate(link, msg_id, hz, now_s)

    def set_rate(self, link, msg_id: int, hz: float | None, now_s: float) -> None:
        """Stream ``msg_id`` at ``hz`` (None or <= 0: stop)."""
        if hz is None or not math.isfinite(hz) or hz <= 0:
            link.intervals.pop(msg_id, None)
            link.next_due.pop(msg_id, None)
            return
        link.intervals[msg_id] = max(self.min_interval_s, 1.0 / hz)
        link.next_due[msg_id] = now_s

    def default_hz(self, msg_id: int) -> float | None:
        return default_rates_hz(self.autopilot, self.sensor_hz).get(msg_id)

    def due(self, link, now_s: float, ready=None) -> list[int]:
        """Message ids due on ``link`` now (and ``ready(msg_id)``, if given); advances their due times.

        A message that is due but not ready keeps its turn, so it goes out as soon as it is ready.
        """
        out = []
        for msg_id, interval in link.intervals.items():
            due = link.next_due.get(msg_id, now_s)
            if now_s + 1e-9 < due or (ready is not None and not ready(msg_id)):
                continue
            out.append(msg_id)
            nxt = due + interval
            link.next_due[msg_id] = nxt if nxt > now_s else now_s + interval
        return out


def request_data_stream(scheduler: StreamScheduler, link, stream_id: int, rate_hz: float, start: bool,
                        now_s: float) -> None:
    """ArduPilot's REQUEST_DATA_STREAM: start (at ``rate_hz``) or stop a group, or all groups for id 0."""
    if stream_id == M.MAV_DATA_STREAM_ALL:
        groups = list(ARDUPILOT_STREAM_GROUPS.values())
    else:
        groups = [ARDUPILOT_STREAM_GROUPS.get(stream_id, ())]
    hz = rate_hz if start and rate_hz > 0 else None
    for group in groups:
        for msg_id in group:
            scheduler.set_rate(link, msg_id, hz, now_s)


def build(ap, msg_id: int, snapshot: tm.TelemetrySnapshot):
    """The message ``msg_id`` from ``snapshot``, or None if the sim does not build it (or not now: PX4 stops
    GLOBAL_POSITION_INT once its estimator has no position, measured on 1.15 SITL; LOCAL_POSITION_NED goes on)."""
    if msg_id == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT and ap.is_px4 and not ap.position_valid:
        return None
    builder = tm.BUILDERS.get(msg_id)
    return None if builder is None else builder(snapshot)
