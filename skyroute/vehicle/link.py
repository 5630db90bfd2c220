"""The MAVLink link: :class:`MavlinkLink`, one autopilot's telemetry, commands, parameters and setpoint stream.

Part of the ``vehicle`` package, the only code that imports pymavlink; :class:`~.control.MavlinkVehicle` adds
the flight actions. Three threads serve one link:

- the reader decodes every message (:class:`~.transport.Transport` reconnects a closed TCP link), counts any
  message of the target autopilot as a sign of life (:class:`~.health.LinkHealth`), and translates it into the
  SI :class:`~.telemetry.Telemetry` snapshot, reassembled STATUSTEXTs, parameters, acks and round trips;
- the sender sends our heartbeat at 1 Hz of the autopilot's clock (up to 10 Hz of ours against a sped-up SITL,
  whose GCS failsafe runs on its clock) and, while we control the vehicle, the current setpoint at
  ``setpoint_rate_hz`` (PX4 leaves OFFBOARD after COM_OF_LOSS_T without one);
- the keeper asks for the telemetry streams and asks again for those that do not arrive
  (:class:`~.streams.StreamKeeper`), pings TIMESYNC for the round trip, and requests HOME_POSITION,
  GPS_GLOBAL_ORIGIN and AUTOPILOT_VERSION until they come.

Identity: system 255 (the ground-station system id autopilots' link failsafes watch by default: ArduCopter's
MAV_GCS_SYSID), component 191 (MAV_COMP_ID_ONBOARD_COMPUTER, not QGroundControl's or Mission Planner's 190, so
their acks cannot be taken for ours), heartbeat MAV_TYPE_GCS (PX4 sends its arming refusals as STATUSTEXT only
to a ground station; with an onboard-controller heartbeat it said nothing, measured on PX4 1.15 SITL).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from . import limits as limits_mod
from .commands import Commander
from .errors import ConnectionTimeout, LinkLost, SigningRequired, TelemetryTimeout, VehicleError
from .health import AutopilotClock, LinkHealth
from .params import bytewise_encoding, decode_param_value, param_name
from .sensors import SensorFeed
from .statustext import StatusTextAssembler, refusal_reason
from .streams import ARDUPILOT_GROUPS, StreamKeeper
from .targets import TargetFeed
from .telemetry import Autopilot, Telemetry, is_autopilot_heartbeat, local_scale, update_telemetry, with_statustext
from .transport import Transport

log = logging.getLogger(__name__)
_NAN = math.nan

#: position + yaw only: ignore velocity, acceleration and yaw rate.
TYPE_MASK_POSITION_YAW = (
    mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
#: position + velocity (feed-forward) + yaw: ignore acceleration and yaw rate. PX4's position controller adds the
#: velocity to its position loop's output; ArduCopter's GUIDED takes position + velocity targets the same way.
TYPE_MASK_POSITION_VELOCITY_YAW = (
    mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
#: position + velocity + acceleration (feed-forwards) + yaw: ignore the yaw rate only. PX4 adds the acceleration to
#: its velocity loop's output (OFFBOARD holds it as it is; ArduCopter's GUIDED would integrate it into a moving
#: target, so it is sent to PX4 only: ``FlightLimits.acceleration_feedforward``).
TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW = mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
DEFAULT_SOURCE_SYSTEM = 255
DEFAULT_SOURCE_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
_SUBJECT = {mavlink.MAV_CMD_COMPONENT_ARM_DISARM: "arm", mavlink.MAV_CMD_DO_SET_MODE: "mode",
            mavlink.MAV_CMD_NAV_TAKEOFF: "takeoff"}
#: Messages asked for with REQUEST_MESSAGE every 2 s until they arrive: (message id, most requests).
_ONCE = {"HOME_POSITION": (mavlink.MAVLINK_MSG_ID_HOME_POSITION, math.inf),
         "GPS_GLOBAL_ORIGIN": (mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 3),
         "AUTOPILOT_VERSION": (mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 3)}


@dataclass(frozen=True)
class _Setpoint:
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float
    #: feed-forward velocity (m/s, local NED) or None; dropped from re-sends once older than the feed-forward timeout
    velocity_ned: tuple[float, float, float] | None = None
    set_at_s: float = 0.0
    #: feed-forward acceleration (m/s^2, local NED) or None; sent only with the velocity, and dropped with it
    accel_ned: tuple[float, float, float] | None = None


class MavlinkLink:
    """A MAVLink autopilot (PX4, ArduPilot or generic): its telemetry, commands, parameters, setpoint stream.

    Parameters
    ----------
    connection : str
        Any pymavlink connection string: ``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:...``, serial device.
    heartbeat_timeout_s : float
        How long to wait for the first autopilot heartbeat (and for a TCP connect to succeed).
    target_system : int, optional
        Fly this system id when several vehicles heartbeat on one link (default: the first autopilot heard).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing secret (see :func:`~.transport.signing_key`).
    link_floor_s : float
        Shortest silence counted as a lost link; longer on slow links (4 round trips).
    command_timeout_s, command_retries : float, int
        Each COMMAND_LONG waits this long (at least 2 round trips) for its ack, and is re-sent up to
        ``command_retries`` times.
    setpoint_rate_hz, telemetry_rate_hz, local_position_rate_hz : float
        Setpoint re-send rate while in control; requested rate of position/attitude messages; of
        LOCAL_POSITION_NED, which the mission steers by (40 bytes a message: 2 kB/s at 50 Hz).
    sensor_rate_hz : float
        Requested rate of DISTANCE_SENSOR (ArduPilot sends its proximity sectors and rangefinders only when asked;
        PX4 streams OBSTACLE_DISTANCE on its onboard link by itself). Readings go to :attr:`sensors`. It is asked
        for only once SYS_STATUS reports a proximity sensor or a laser rangefinder present (ArduPilot's way of
        saying it has one; 0 never asks): an autopilot without one is spared the request (asking ArduCopter SITL,
        which has none, for 10 Hz cost its killed-client test clearance, 3.46 m < 3.5 m).
    feedforward_timeout_s : float
        Re-sends drop the velocity feed-forward once it is older than this (the vehicle then brakes at the
        position), so a stalled mission never keeps the vehicle coasting on.
    tlog_path : str, optional
        Write a standard MAVLink tlog (8-byte big-endian microseconds + packet) of everything received and sent.

    Raises
    ------
    BadConnection
        pymavlink cannot open ``connection``.
    ConnectionTimeout
        No autopilot heartbeat within ``heartbeat_timeout_s``.
    """

    def __init__(
        self,
        connection: str = "tcp:127.0.0.1:5760",
        *,
        heartbeat_timeout_s: float = 10.0,
        target_system: int | None = None,
        signing_key: bytes | None = None,
        link_floor_s: float = 2.0,
        command_timeout_s: float = 1.5,
        command_retries: int = 3,
        setpoint_rate_hz: float = 20.0,
        telemetry_rate_hz: float = 10.0,
        feedforward_timeout_s: float = 0.5,
        local_position_rate_hz: float = 50.0,
        sensor_rate_hz: float = 10.0,
        source_system: int = DEFAULT_SOURCE_SYSTEM,
        source_component: int = DEFAULT_SOURCE_COMPONENT,
        tlog_path: str | os.PathLike | None = None,
    ):
        self.connection = connection
        self.command_timeout_s, self.command_retries = command_timeout_s, command_retries
        self.setpoint_rate_hz, self.feedforward_timeout_s = setpoint_rate_hz, feedforward_timeout_s
        self.us = (source_system, source_component)
        self.wanted_system = target_system
        self.health = LinkHealth(floor_s=link_floor_s)
        self.autopilot_clock = AutopilotClock()  # a sped-up SITL's timeouts run faster on our clock
        self._t0 = time.monotonic()
        self._telemetry = Telemetry()
        self._cond = threading.Condition()  # guards _telemetry, _target, _params
        self._target: tuple[int, int] | None = None
        self._target_signs = False  # its heartbeat came signed (MAVLink 2 signing)
        self._others: set[int] = set()
        self._mav_type = mavlink.MAV_TYPE_QUADROTOR
        self._capabilities: int | None = None
        self._params: dict[str, tuple[float, int]] = {}
        self._limits: limits_mod.FlightLimits | None = None
        self._texts = StatusTextAssembler()
        self._streams = StreamKeeper({
            "GLOBAL_POSITION_INT": telemetry_rate_hz,
            "LOCAL_POSITION_NED": max(telemetry_rate_hz, local_position_rate_hz),
            "ATTITUDE": telemetry_rate_hz, "EXTENDED_SYS_STATE": telemetry_rate_hz, "SYS_STATUS": 1.0,
            "GPS_RAW_INT": 2.0})
        self._sensor_rate_hz = sensor_rate_hz
        self.sensors = SensorFeed()  # obstacle sensor readings (skyroute.vehicle.sensors), drained by the mission
        self.targets = TargetFeed()  # ground target sightings (skyroute.vehicle.targets), drained by exploration
        self._once_received: set[str] = set()
        self._timesyncs: dict[int, float] = {}
        self._setpoint: _Setpoint | None = None
        self._streaming = False
        self._setpoint_gaps: list[tuple[float, float]] = []  # (when, gap s) of setpoint pauses > 0.3 s
        self._link_down_s = _NAN  # when the keeper last saw the link silent
        self._stop = threading.Event()
        self._tlog = open(tlog_path, "wb") if tlog_path else None  # noqa: SIM115 (closed in close())
        self._tlog_lock = threading.Lock()
        self.commander = Commander(self._send, self.us, self.health, self._refusal_reason)
        try:
            self.transport = Transport(connection, source_system=source_system, source_component=source_component,
                                       key=signing_key, connect_timeout_s=heartbeat_timeout_s,
                                       on_packet=self._write_tlog)
        except BaseException:
            self._close_tlog()
            raise
        self._threads = [threading.Thread(target=loop, name=f"mavlink-{name}", daemon=True)
                         for name, loop in (("reader", self._read_loop), ("sender", self._send_loop),
                                            ("keeper", self._keep_loop))]
        self._threads[0].start()
        self._threads[1].start()
        try:
            self._wait_for_autopilot(heartbeat_timeout_s)
        except BaseException:
            self.close()
            raise
        self._threads[2].start()

    # ------------------------------------------------------------------------------------------ connection
    def _wait_for_autopilot(self, timeout_s: float) -> None:
        with self._cond:
            if not self._cond.wait_for(lambda: self._target is not None, timeout=timeout_s):
                which = "" if self.wanted_system is None else f"system {self.wanted_system}: "
                seen = f"heard systems {sorted(self._others)}" if self._others else ""
                raise ConnectionTimeout(self.connection, timeout_s, (which + seen).strip(": ") or "")
            sysid, compid = self._target
            t = self._telemetry
            if self._target_signs and not self.transport.signing:
                raise SigningRequired(self.connection)
        log.info("connected to %s autopilot system %d component %d on %s (mode %s)%s",
                 t.autopilot.value, sysid, compid, self.connection, t.mode,
                 ", signed" if self.transport.signing else "")

    def close(self) -> None:
        self._stop.set()
        self.stop_streaming()
        self.commander.close()
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        if hasattr(self, "transport"):
            self.transport.close()
        self._close_tlog()

    def _close_tlog(self) -> None:
        with self._tlog_lock:
            if self._tlog is not None:
                self._tlog.close()
                self._tlog = None

    def __enter__(self) -> MavlinkLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------------------------------------- state
    @property
    def telemetry(self) -> Telemetry:
        """The latest telemetry snapshot (immutable)."""
        with self._cond:
            return self._telemetry

    @property
    def autopilot(self) -> Autopilot:
        return self.telemetry.autopilot

    @property
    def target(self) -> tuple[int, int]:
        return self._target

    @property
    def link_ok(self) -> bool:
        """True while the target autopilot has been heard within the link timeout (any message counts)."""
        return self.health.ok()

    @property
    def round_trip_s(self) -> float:
        """Measured round trip to the autopilot (s, TIMESYNC and acks; 0 before the first sample)."""
        return self.health.rtt_s

    @property
    def sensing(self) -> bool:
        """True while the autopilot streams horizontal obstacle data (OBSTACLE_DISTANCE, proximity sectors)."""
        return self.sensors.streaming

    def sensor_readings(self) -> list:
        """Every obstacle sensor reading since the last call (:class:`~.sensors.RangeScan`, :class:`~.sensors.
        HeightReading`), oldest first."""
        return self.sensors.drain()

    def target_sightings(self) -> list:
        """Every ground target sighting (LANDING_TARGET, :class:`~.targets.TargetSighting`) since the last call."""
        return self.targets.drain()

    def wait_sensor(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for a sensor reading; True if one is queued."""
        return self.sensors.wait(timeout_s)

    def check_link(self) -> None:
        """Raise :class:`LinkLost` when the autopilot has been silent for longer than the link timeout."""
        if not self.health.ok():
            raise LinkLost(self.health.silent_s(), self.health.timeout_s)

    def wait_for(self, predicate: Callable[[Telemetry], bool], timeout_s: float, what: str) -> Telemetry:
        """Block until ``predicate(telemetry)`` holds; raise :class:`TelemetryTimeout` (or LinkLost) otherwise."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not predicate(self._telemetry):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(timeout=min(remaining, 0.5))
            else:
                return self._telemetry
        self.check_link()
        raise TelemetryTimeout(what, timeout_s)

    # ----------------------------------------------------------------------------------------- parameters
    def read_params(self, names, timeout_s: float = 1.5) -> dict[str, float]:
        """Read parameters by name (PARAM_REQUEST_READ); returns those the autopilot has, decoded (see
        :func:`~.params.decode_param_value`). Names it does not answer are left out."""
        names = list(names)
        deadline = time.monotonic() + timeout_s
        for name in names:
            with self._cond:
                self._params.pop(name, None)
        while True:
            with self._cond:
                missing = [n for n in names if n not in self._params]
            if not missing or time.monotonic() >= deadline:
                break
            for name in missing:
                self._send(mavlink.MAVLink_param_request_read_message(*self._target, name.encode("ascii"), -1))
            with self._cond:  # a lost request is asked again; a name the autopilot lacks is never answered
                self._cond.wait_for(lambda: all(n in self._params for n in names),
                                    timeout=min(max(0.5, 3 * self.health.rtt_s), max(deadline - time.monotonic(), 0.0)))
        if self._capabilities is None:  # the encoding needs AUTOPILOT_VERSION; give it a moment
            with self._cond:
                self._cond.wait_for(lambda: self._capabilities is not None, timeout=1.0)
        bytewise = bytewise_encoding(self.autopilot, self._capabilities)
        with self._cond:
            raw = {n: self._params[n] for n in names if n in self._params}
        return {n: decode_param_value(v, ptype, bytewise) for n, (v, ptype) in raw.items()}

    # ------------------------------------------------------------------------------------------- commands
    def command_long(self, command: int, *params: float, timeout_s: float | None = None,
                     retries: int | None = None, retry_temporary_s: float = 0.0,
                     done: Callable[[Telemetry], bool] | None = None):
        """Send COMMAND_LONG to the autopilot and return its ACCEPTED ack, or None when an attempt went unanswered
        but ``done(telemetry)``, on a heartbeat received since it was first sent, says the command took effect
        (see :class:`~.commands.Commander`)."""
        since_s = time.monotonic()  # only a heartbeat sent after the command can show its effect

        def seen() -> bool:
            t = self.telemetry
            return t.last_heartbeat_s > since_s and bool(done(t))

        return self.commander.run(
            self._target, command, *params,
            timeout_s=self.command_timeout_s if timeout_s is None else timeout_s,
            retries=self.command_retries if retries is None else retries, retry_temporary_s=retry_temporary_s,
            done=None if done is None else seen)

    def _refusal_reason(self, command: int, since_s: float, until_s: float, grace_s: float = 0.3) -> str | None:
        time.sleep(grace_s)  # a text may trail its ack
        return refusal_reason(self.telemetry.statustexts, since_s, until_s + grace_s, _SUBJECT.get(command))

    # ------------------------------------------------------------------------------------------ setpoints
    def stream_setpoint(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
                        velocity_ned: tuple[float, float, float] | None = None,
                        accel_ned: tuple[float, float, float] | None = None) -> None:
        """Make this the setpoint re-sent at ``setpoint_rate_hz`` (local NED, m; yaw rad; velocity m/s;
        acceleration m/s^2, only with a velocity), send it now."""
        velocity = None if velocity_ned is None else tuple(float(v) for v in velocity_ned)
        accel = None if accel_ned is None or velocity is None else tuple(float(a) for a in accel_ned)
        self._setpoint = _Setpoint(float(north_m), float(east_m), float(down_m), float(yaw_rad), velocity,
                                   time.monotonic(), accel)
        self._streaming = True
        self._send_setpoint(self._setpoint)

    def shift_setpoint(self, north_m: float, east_m: float, down_m: float) -> None:
        """Move the streamed setpoint by (north, east, down) m: the autopilot's local frame moved under it (an
        EKF reset, a new origin), and the same place now has other local coordinates."""
        sp = self._setpoint
        if sp is not None:
            self._setpoint = dataclasses.replace(sp, north_m=sp.north_m + north_m, east_m=sp.east_m + east_m,
                                                 down_m=sp.down_m + down_m)

    def stop_streaming(self) -> None:
        """Stop re-sending setpoints (the autopilot keeps its current mode)."""
        self._streaming = False
        self._setpoint = None

    @property
    def streaming(self) -> bool:
        return self._streaming and self._setpoint is not None

    def setpoint_pause_s(self, window_s: float) -> float:
        """The longest pause (s) of our setpoint stream that ended in the last ``window_s`` (0 if none > 0.3 s)."""
        now = time.monotonic()
        return max((gap for when, gap in list(self._setpoint_gaps) if now - when <= window_s), default=0.0)

    def link_silent_within(self, window_s: float) -> bool:
        """True if the link counted as lost at some moment of the last ``window_s`` (checked 4 times a second)."""
        return time.monotonic() - self._link_down_s <= window_s

    # ------------------------------------------------------------------------------------------ threads
    def _send(self, msg) -> bool:
        return self.transport.send(msg)

    def _assume(self, **fields) -> None:
        """Take an ACCEPTED command's effect (e.g. ``armed=True``) as known until the next heartbeat says."""
        with self._cond:
            self._telemetry = dataclasses.replace(self._telemetry, **fields)
            self._cond.notify_all()

    def _write_tlog(self, packet: bytes) -> None:
        with self._tlog_lock:
            if self._tlog is not None:
                self._tlog.write(struct.pack(">Q", int(time.time() * 1e6) & ~3) + bytes(packet))
                self._tlog.flush()

    def _send_setpoint(self, sp: _Setpoint) -> None:
        if self._target is None:
            return
        now = time.monotonic()
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        velocity = sp.velocity_ned
        if velocity is not None and now - sp.set_at_s > self.feedforward_timeout_s:
            velocity = None
        accel = None if velocity is None else sp.accel_ned
        if velocity is None:
            mask = TYPE_MASK_POSITION_YAW
        else:
            mask = TYPE_MASK_POSITION_VELOCITY_YAW if accel is None else TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW
        vn, ve, vd = (0.0, 0.0, 0.0) if velocity is None else velocity
        an, ae, ad = (0.0, 0.0, 0.0) if accel is None else accel
        scale_n, scale_e = local_scale(self.telemetry)  # true metres -> the autopilot's local metres
        self._send(mavlink.MAVLink_set_position_target_local_ned_message(
            boot_ms, *self._target, mavlink.MAV_FRAME_LOCAL_NED, mask,
            sp.north_m * scale_n, sp.east_m * scale_e, sp.down_m, vn, ve, vd, an, ae, ad, sp.yaw_rad, 0))

    def _send_loop(self) -> None:
        period = 1.0 / self.setpoint_rate_hz
        last_heartbeat, last_setpoint = -math.inf, _NAN
        while not self._stop.is_set():
            now = time.monotonic()
            # 1 Hz on the autopilot's clock: a sped-up SITL's GCS failsafe (FS_GCS_TIMEOUT) runs on it
            if now - last_heartbeat >= 1.0 / min(max(self.autopilot_clock.rate(), 1.0), 10.0):
                last_heartbeat = now
                self._send(mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            sp = self._setpoint
            if self._streaming and sp is not None:
                if now - last_setpoint > 0.3:  # a pause (a busy process): the autopilot may have left OFFBOARD
                    self._setpoint_gaps = [*self._setpoint_gaps[-9:], (now, now - last_setpoint)]
                self._send_setpoint(sp)
                last_setpoint = now
            else:
                last_setpoint = _NAN
            self._stop.wait(period)

    def _keep_loop(self) -> None:
        next_timesync = 0.0
        once_asked: dict[str, tuple[float, int]] = {}  # name -> (when last asked, how often)
        while not self._stop.is_set():
            now = time.monotonic()
            if not self.health.ok(now):
                self._link_down_s = now
            elif self._target is not None:
                if now >= next_timesync:
                    next_timesync = now + 1.0
                    stamp = time.monotonic_ns()
                    self._timesyncs = {k: v for k, v in self._timesyncs.items() if now - v < 10.0}
                    self._timesyncs[stamp] = now
                    self._send(mavlink.MAVLink_timesync_message(0, stamp))
                if (self._sensor_rate_hz > 0 and self._telemetry.range_sensors
                        and "DISTANCE_SENSOR" not in self._streams):
                    self._streams.add("DISTANCE_SENSOR", self._sensor_rate_hz)
                for stream in self._streams.due(now):
                    self._request_stream(stream, now)
                for name, (msg_id, most) in _ONCE.items():
                    when, asks = once_asked.get(name, (-math.inf, 0))
                    if name not in self._once_received and now - when > 2.0 and asks < most:
                        once_asked[name] = (now, asks + 1)
                        self._request_quietly(mavlink.MAV_CMD_REQUEST_MESSAGE, msg_id)
            self._stop.wait(0.25)

    def _request_stream(self, stream, now: float) -> None:
        refused = not self._request_quietly(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, stream.msg_id, 1e6 / stream.rate_hz)
        self._streams.asked(stream.name, now, refused)
        if refused and self.autopilot is Autopilot.ARDUPILOT and stream.name in ARDUPILOT_GROUPS:
            for group in ARDUPILOT_GROUPS[stream.name]:
                self._send(mavlink.MAVLink_request_data_stream_message(
                    *self._target, group, max(1, round(stream.rate_hz)), 1))

    def _request_quietly(self, command: int, *params: float) -> bool:
        """Telemetry requests are best effort: some autopilots stream by default and refuse or ignore them."""
        try:
            self.command_long(command, *params, timeout_s=min(self.command_timeout_s, 1.0), retries=1)
            return True
        except VehicleError as exc:
            log.debug("telemetry request %s not accepted: %s", command, exc)
            return False

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            msg = self.transport.recv(0.05)
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self._write_tlog(msg.get_msgbuf())
            try:
                self._handle(msg)
            except Exception:  # a malformed message must not end the reader
                log.exception("could not handle %s", msg.get_type())

    def _choose_target(self, msg, src: tuple[int, int]) -> bool:
        if not is_autopilot_heartbeat(msg):
            return False
        if self.wanted_system is not None and src[0] != self.wanted_system:
            self._others.add(src[0])
            return False
        self._target, self._mav_type = src, msg.type
        self._target_signs = bool(msg.get_header().incompat_flags & mavlink.MAVLINK_IFLAG_SIGNED)
        return True

    def _handle(self, msg) -> None:
        now = time.monotonic()
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        with self._cond:
            if self._target is None and not (mtype == "HEARTBEAT" and self._choose_target(msg, src)):
                return
            if src[0] != self._target[0]:
                if mtype == "HEARTBEAT" and is_autopilot_heartbeat(msg) and src[0] not in self._others:
                    self._others.add(src[0])
                    log.warning("another vehicle (system %d) on %s: flying system %d; pick one with "
                                "--target-system", src[0], self.connection, self._target[0])
                return
            if src != self._target and mtype in ("HEARTBEAT", "COMMAND_ACK"):
                return  # another component of the same system (a camera, a gimbal)
            self.health.heard(now)
            self._streams.received(mtype, now)
            if mtype in _ONCE:
                self._once_received.add(mtype)
            if mtype == "AUTOPILOT_VERSION":
                self._capabilities = int(msg.capabilities)
            elif mtype == "PARAM_VALUE":
                self._params[param_name(msg.param_id)] = (float(msg.param_value), int(msg.param_type))
            elif mtype == "STATUSTEXT":
                for entry in self._texts.add(msg.severity, msg.text, getattr(msg, "id", 0),
                                             getattr(msg, "chunk_seq", 0), now):
                    self._telemetry = with_statustext(self._telemetry, entry)
                    level = logging.WARNING if entry.severity <= mavlink.MAV_SEVERITY_ERROR else logging.INFO
                    log.log(level, "autopilot says: %s", entry.text)
            elif mtype in SensorFeed.MESSAGES:
                t = self._telemetry
                self.sensors.handle(msg, now, t.heading_rad, (t.north_m, t.east_m), t.down_m,
                                    local_time_s=t.local_time_s,
                                    local_velocity_ned=(t.local_v_north_mps, t.local_v_east_mps, t.local_v_down_mps),
                                    heading_time_s=t.attitude_time_s, yaw_rate_rad_s=t.yaw_rate_rad_s,
                                    horizontal_accuracy_m=t.horizontal_accuracy_m)
            elif mtype in TargetFeed.MESSAGES:
                self.targets.handle(msg, now, local_scale(self._telemetry))
            else:
                self._telemetry = update_telemetry(self._telemetry, msg, now)
                if mtype in ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE"):  # stamped, from boot on
                    self.autopilot_clock.note(msg.time_boot_ms * 1e-3, now)
            self._cond.notify_all()
        if mtype == "COMMAND_ACK":
            self.commander.on_ack(msg, src)
        elif mtype == "TIMESYNC":
            self._on_timesync(msg, now)

    def _on_timesync(self, msg, now: float) -> None:
        if msg.tc1 == 0:  # the autopilot asks for our time: answer, as MAVSDK does
            self._send(mavlink.MAVLink_timesync_message(time.monotonic_ns(), msg.ts1))
            return
        sent = self._timesyncs.pop(msg.ts1, None)
        if sent is not None:
            self.health.round_trip(now - sent)
