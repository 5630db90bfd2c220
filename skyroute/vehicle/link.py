"""The MAVLink link: :class:`MavlinkVehicle`, its typed errors and the autopilots' mode numbers.

Part of the ``vehicle`` package, the only code that imports pymavlink.
"""

from __future__ import annotations

import logging
import math
import os
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute.frames import Geodetic, LocalNED

from .telemetry import (
    Autopilot,
    StatusText,
    Telemetry,
    is_autopilot_heartbeat,
    map_offset,
    update_telemetry,
)

log = logging.getLogger(__name__)
_NAN = math.nan

#: position + yaw only: ignore velocity, acceleration and yaw rate.
TYPE_MASK_POSITION_YAW = (
    mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
#: position + velocity (feed-forward) + yaw: ignore acceleration and yaw rate. PX4's position controller adds the
#: velocity to its position loop's output (offboard "position with velocity feed-forward"); ArduCopter's GUIDED
#: takes position + velocity targets (all three axes of each) the same way.
TYPE_MASK_POSITION_VELOCITY_YAW = (
    mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)


# --------------------------------------------------------------------------------------------------- errors
class VehicleError(Exception):
    """Base class of every error raised by this module."""


class ConnectionTimeout(VehicleError):
    """No autopilot heartbeat arrived on ``connection`` within ``timeout_s``."""

    def __init__(self, connection: str, timeout_s: float, detail: str = ""):
        self.connection, self.timeout_s, self.detail = connection, timeout_s, detail
        msg = f"no autopilot heartbeat on {connection} within {timeout_s:g} s"
        super().__init__(f"{msg} ({detail})" if detail else msg)


class CommandRejected(VehicleError):
    """The autopilot answered a command with a result other than ACCEPTED.

    ``command`` and ``result`` are the MAVLink numbers; ``reason`` is the autopilot's latest STATUSTEXT, if any.
    """

    def __init__(self, command: int, result: int, reason: str | None = None):
        self.command, self.result, self.reason = command, result, reason
        text = f"{command_name(command)} rejected: {result_name(result)}"
        super().__init__(f"{text}: {reason}" if reason else text)


class CommandTimeout(VehicleError):
    """No COMMAND_ACK for ``command`` after ``attempts`` sends of ``timeout_s`` each."""

    def __init__(self, command: int, attempts: int, timeout_s: float):
        self.command, self.attempts, self.timeout_s = command, attempts, timeout_s
        super().__init__(f"no COMMAND_ACK for {command_name(command)} after {attempts} x {timeout_s:g} s")


class LinkLost(VehicleError):
    """The autopilot's heartbeat stopped for longer than the link timeout."""

    def __init__(self, silent_s: float):
        self.silent_s = silent_s
        super().__init__(f"link lost: no autopilot heartbeat for {silent_s:.1f} s")


class TelemetryTimeout(VehicleError):
    """A telemetry condition (``what``) did not hold within ``timeout_s``."""

    def __init__(self, what: str, timeout_s: float):
        self.what, self.timeout_s = what, timeout_s
        super().__init__(f"timed out after {timeout_s:g} s waiting for {what}")


class UnsupportedMode(VehicleError):
    """The mode name is not in pymavlink's table for this autopilot."""

    def __init__(self, mode: str, autopilot: Autopilot):
        self.mode, self.autopilot = mode, autopilot
        super().__init__(f"mode {mode!r} unknown for {autopilot.value}")


def command_name(command: int) -> str:
    """``MAV_CMD_...`` name of a command number (or the number)."""
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name if entry else f"command {command}"


def result_name(result: int) -> str:
    """``MAV_RESULT_...`` name of a result number (or the number)."""
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name if entry else f"result {result}"


def mode_numbers(autopilot: Autopilot, mode: str, mav_type: int = mavlink.MAV_TYPE_QUADROTOR) -> tuple[int, int]:
    """``(param2, param3)`` of DO_SET_MODE for ``mode``, from pymavlink's tables.

    PX4 / generic: (custom main mode, custom sub mode), e.g. ``OFFBOARD`` -> (6, 0). ArduPilot: (mode number, 0)
    from the table for ``mav_type`` (ArduCopter for multirotors), e.g. ``GUIDED`` -> (4, 0).
    """
    mode = mode.upper()
    if autopilot is Autopilot.ARDUPILOT:
        table = mavutil.mode_mapping_byname(mav_type) or {v: k for k, v in mavutil.mode_mapping_acm.items()}
        if mode not in table:
            raise UnsupportedMode(mode, autopilot)
        return int(table[mode]), 0
    if mode not in mavutil.px4_map:
        raise UnsupportedMode(mode, autopilot)
    _, main_mode, sub_mode = mavutil.px4_map[mode]
    return int(main_mode), int(sub_mode)


# ------------------------------------------------------------------------------------------------- vehicle
@dataclass(frozen=True)
class _Setpoint:
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float
    #: feed-forward velocity (m/s, local NED) or None; dropped from re-sends once older than the feed-forward timeout
    velocity_ned: tuple[float, float, float] | None = None
    set_at_s: float = 0.0


class MavlinkVehicle:
    """A MAVLink autopilot (PX4, ArduPilot or generic) behind SI-unit methods.

    Parameters
    ----------
    connection : str
        Any pymavlink connection string: ``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:...``, serial device.
    heartbeat_timeout_s : float
        How long to wait for the first autopilot heartbeat (and for a TCP connect to succeed).
    link_timeout_s : float
        Heartbeat silence after which the link counts as lost.
    command_timeout_s, command_retries : float, int
        Each COMMAND_LONG waits this long for its COMMAND_ACK, and is re-sent up to ``command_retries`` times.
    setpoint_rate_hz, telemetry_rate_hz : float
        Setpoint re-send rate while in control; requested rate of position/attitude messages.
    local_position_rate_hz : float
        Requested rate of LOCAL_POSITION_NED (40 bytes a message: 2 kB/s at 50 Hz, within a 57600 baud radio),
        which the mission steers by: at 10 Hz a vehicle at 10 m/s moves 1 m between fixes.
    tlog_path : str, optional
        Write a standard MAVLink tlog (8-byte big-endian microseconds + packet) of everything received and sent.

    Raises
    ------
    ConnectionTimeout
        No autopilot heartbeat within ``heartbeat_timeout_s``.
    """

    def __init__(
        self,
        connection: str = "tcp:127.0.0.1:5760",
        *,
        heartbeat_timeout_s: float = 10.0,
        link_timeout_s: float = 3.0,
        command_timeout_s: float = 1.5,
        command_retries: int = 3,
        setpoint_rate_hz: float = 20.0,
        telemetry_rate_hz: float = 10.0,
        feedforward_timeout_s: float = 0.5,
        local_position_rate_hz: float = 50.0,
        source_system: int = 255,
        source_component: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
        tlog_path: str | os.PathLike | None = None,
    ):
        self.connection = connection
        self.link_timeout_s = link_timeout_s
        self.command_timeout_s = command_timeout_s
        self.command_retries = command_retries
        self.setpoint_rate_hz = setpoint_rate_hz
        self.feedforward_timeout_s = feedforward_timeout_s
        self.local_position_rate_hz = local_position_rate_hz
        self._source_system = source_system
        self._t0 = time.monotonic()
        self._telemetry = Telemetry()
        self._cond = threading.Condition()  # guards _telemetry, _acks, _target
        self._acks: list = []
        self._target: tuple[int, int] | None = None
        self._mav_type = mavlink.MAV_TYPE_QUADROTOR
        self._send_lock = threading.Lock()  # guards the MAVLink encoder (sequence numbers) and the socket
        self._command_lock = threading.Lock()  # one command in flight at a time
        self._setpoint: _Setpoint | None = None
        self._streaming = False
        self._eof = False
        self._stop = threading.Event()
        self._tlog = open(tlog_path, "wb") if tlog_path else None  # noqa: SIM115 (closed in close())
        self._tlog_lock = threading.Lock()
        try:
            self._conn = self._open(connection, heartbeat_timeout_s, source_system, source_component)
        except BaseException:
            self._close_tlog()
            raise
        self._conn.mav.set_send_callback(self._on_sent)
        if hasattr(self._conn, "handle_eof"):  # TCP: note the peer closing instead of printing in a loop
            self._conn.handle_eof = self._on_eof
            self._conn.handle_disconnect = self._on_eof
        self._reader = threading.Thread(target=self._read_loop, name="mavlink-reader", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name="mavlink-sender", daemon=True)
        self._reader.start()
        self._sender.start()
        try:
            self._wait_for_autopilot(heartbeat_timeout_s)
            self._request_telemetry(telemetry_rate_hz)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------------------------------ connection
    @staticmethod
    def _open(connection: str, timeout_s: float, source_system: int, source_component: int):
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                conn = mavutil.mavlink_connection(
                    connection, source_system=source_system, source_component=source_component,
                    retries=0, autoreconnect=False,
                )
            except OSError as exc:  # TCP refused: the autopilot may still be starting
                if time.monotonic() >= deadline:
                    raise ConnectionTimeout(connection, timeout_s, str(exc)) from exc
                time.sleep(0.2)
                continue
            if not conn.mavlink20():
                # Speak MAVLink 2 from our first packet (pymavlink would otherwise start with MAVLink 1 and swap
                # its encoder on the first MAVLink 2 packet it reads, racing our sender thread).
                conn.mav = mavlink.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
                conn.mav.robust_parsing = True
                conn.WIRE_PROTOCOL_VERSION = "2.0"
            return conn

    def _wait_for_autopilot(self, timeout_s: float) -> None:
        with self._cond:
            if not self._cond.wait_for(lambda: self._target is not None, timeout=timeout_s):
                raise ConnectionTimeout(self.connection, timeout_s)
            sysid, compid = self._target
            t = self._telemetry
        log.info("connected to %s autopilot system %d component %d on %s (mode %s)",
                 t.autopilot.value, sysid, compid, self.connection, t.mode)

    def _request_telemetry(self, rate_hz: float) -> None:
        rates = {
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: rate_hz,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: max(rate_hz, self.local_position_rate_hz),
            mavlink.MAVLINK_MSG_ID_ATTITUDE: rate_hz,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: rate_hz,  # touchdown detection
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        }
        for msg_id, hz in rates.items():
            self._request_quietly(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)
        self._request_quietly(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION)

    def _request_quietly(self, command: int, *params: float) -> None:
        """Telemetry requests are best effort: some autopilots stream by default and refuse or ignore them."""
        try:
            self.command_long(command, *params, timeout_s=min(self.command_timeout_s, 1.0), retries=1)
        except (CommandRejected, CommandTimeout) as exc:
            log.warning("telemetry request ignored: %s", exc)

    def close(self) -> None:
        """Stop both threads, close the link and flush/close the tlog. Safe to call twice."""
        self._streaming = False
        self._stop.set()
        for thread in (getattr(self, "_reader", None), getattr(self, "_sender", None)):
            if thread is not None and thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        conn = getattr(self, "_conn", None)
        if conn is not None:
            try:
                conn.close()
            except OSError:
                pass
            self._conn = None
        self._close_tlog()

    def _close_tlog(self) -> None:
        with self._tlog_lock:
            if self._tlog is not None:
                self._tlog.close()
                self._tlog = None

    def __enter__(self) -> MavlinkVehicle:
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
    def link_ok(self) -> bool:
        """True while the autopilot's heartbeat is younger than ``link_timeout_s``."""
        return self.heartbeat_age_s() <= self.link_timeout_s

    def heartbeat_age_s(self) -> float:
        last = self.telemetry.last_heartbeat_s
        return math.inf if math.isnan(last) else time.monotonic() - last

    def check_link(self) -> None:
        """Raise :class:`LinkLost` when the heartbeat has been silent for longer than ``link_timeout_s``."""
        age = self.heartbeat_age_s()
        if age > self.link_timeout_s:
            raise LinkLost(age)

    @property
    def in_control(self) -> bool:
        """True while the autopilot is in OFFBOARD (PX4) or GUIDED (ArduPilot)."""
        return self.telemetry.mode in ("OFFBOARD", "GUIDED")

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

    def map_offset(self, map_origin: Geodetic, timeout_s: float = 10.0) -> LocalNED:
        """``map_ned - autopilot_local_ned`` (see :func:`map_offset`), once both positions have arrived."""
        t = self.wait_for(lambda t: t.has_global and t.has_local, timeout_s,
                          "GLOBAL_POSITION_INT and LOCAL_POSITION_NED")
        offset = map_offset(t, map_origin)
        log.info("map frame = autopilot local frame + (%.2f, %.2f, %.2f) m", *offset)
        return offset

    # ------------------------------------------------------------------------------------------- commands
    def command_long(self, command: int, *params: float, timeout_s: float | None = None,
                     retries: int | None = None):
        """Send COMMAND_LONG and wait for its COMMAND_ACK; returns the ack message.

        Re-sends with ``confirmation`` incremented when no ack arrives; IN_PROGRESS acks extend the wait.

        Raises
        ------
        CommandRejected
            Any result but ACCEPTED, with the autopilot's latest STATUSTEXT as the reason.
        CommandTimeout
            No ack after ``1 + retries`` attempts.
        LinkLost
            The heartbeat is silent (before sending, or when the retries ran out).
        """
        timeout_s = self.command_timeout_s if timeout_s is None else timeout_s
        retries = self.command_retries if retries is None else retries
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.check_link()
        with self._command_lock:
            sent_s = time.monotonic()
            for confirmation in range(retries + 1):
                with self._cond:
                    self._acks.clear()
                sysid, compid = self._target
                self._send(self._conn.mav.command_long_encode(sysid, compid, command, confirmation, *p))
                ack = self._wait_ack(command, timeout_s)
                if ack is None:
                    log.debug("no ack for %s (attempt %d)", command_name(command), confirmation + 1)
                    continue
                if ack.result == mavlink.MAV_RESULT_ACCEPTED:
                    return ack
                raise CommandRejected(command, ack.result, self._reason_since(sent_s))
        self.check_link()
        raise CommandTimeout(command, retries + 1, timeout_s)

    def _wait_ack(self, command: int, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for i, ack in enumerate(self._acks):
                    if ack.command != command:
                        continue
                    del self._acks[i]
                    if ack.result == mavlink.MAV_RESULT_IN_PROGRESS:
                        deadline = time.monotonic() + timeout_s
                        break
                    return ack
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(timeout=remaining)

    def _reason_since(self, since_s: float, grace_s: float = 0.3) -> str | None:
        """The autopilot's latest STATUSTEXT since ``since_s`` (waiting ``grace_s`` for one that trails the ack)."""

        def latest(t: Telemetry) -> StatusText | None:
            recent = [s for s in t.statustexts if s.time_s >= since_s - 0.5]
            return recent[-1] if recent else None

        try:
            t = self.wait_for(lambda t: latest(t) is not None, grace_s, "STATUSTEXT")
        except VehicleError:
            return None
        return latest(t).text

    def arm(self) -> None:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM 1) and wait for the heartbeat to say so."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        self.wait_for(lambda t: t.armed, 3.0, "heartbeat armed flag")
        log.info("armed")

    def disarm(self, *, force: bool = False) -> None:
        """Disarm; ``force`` sends the 21196 magic (disarm in the air) — never used by the mission."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)
        self.wait_for(lambda t: not t.armed, 3.0, "heartbeat disarmed flag")
        log.info("disarmed")

    def set_mode(self, mode: str) -> None:
        """DO_SET_MODE by name, using pymavlink's PX4 or ArduPilot table (raises :class:`UnsupportedMode`)."""
        main_mode, sub_mode = mode_numbers(self.autopilot, mode, self._mav_type)
        self.command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_mode,
                          sub_mode)
        log.info("mode %s requested", mode)

    def start_offboard(self, warmup_s: float = 0.5) -> None:
        """Take position control: PX4/generic OFFBOARD (setpoints stream first), ArduPilot GUIDED."""
        t = self.telemetry
        if self.autopilot is Autopilot.ARDUPILOT:
            self.set_mode("GUIDED")
            return
        if self._setpoint is None:
            self._setpoint = _Setpoint(t.north_m, t.east_m, t.down_m, _heading_or_zero(t))
        self._streaming = True
        time.sleep(warmup_s)
        self.set_mode("OFFBOARD")

    def takeoff(self, altitude_m: float) -> LocalNED:
        """Climb ``altitude_m`` above the current position; returns the local target. Does not wait.

        PX4/generic: OFFBOARD with a position setpoint straight above. ArduPilot: GUIDED + MAV_CMD_NAV_TAKEOFF.
        """
        t = self.telemetry
        target = LocalNED(t.north_m, t.east_m, t.down_m - altitude_m)
        if self.autopilot is Autopilot.ARDUPILOT:
            self._streaming, self._setpoint = False, None  # a position target would cut the takeoff short
            if t.mode != "GUIDED":
                self.set_mode("GUIDED")
            self.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, _NAN, 0, 0, altitude_m)
        else:
            self._setpoint = _Setpoint(t.north_m, t.east_m, t.down_m, _heading_or_zero(t))
            if not self.in_control:
                self.start_offboard()
            self.goto_local(*target, yaw_rad=_heading_or_zero(t))
        log.info("takeoff to %.1f m above the ground", altitude_m)
        return target

    def goto_local(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
                   velocity_ned: tuple[float, float, float] | None = None) -> None:
        """Fly to a position in the autopilot's LOCAL_NED frame (m) with a heading (rad); re-sent until changed.

        ``velocity_ned`` (m/s, local NED) is sent with the position as a feed-forward: the autopilot flies at that
        velocity plus its position loop's correction towards the position, so a client that moves the position
        along a path with the path's velocity gets flown through it without braking at each setpoint. Re-sends
        drop it after ``feedforward_timeout_s`` without a new call (position only: the vehicle brakes there).
        """
        velocity = None if velocity_ned is None else tuple(float(v) for v in velocity_ned)
        self._setpoint = _Setpoint(float(north_m), float(east_m), float(down_m), float(yaw_rad), velocity,
                                   time.monotonic())
        self._streaming = True
        self._send_setpoint(self._setpoint)

    def land(self) -> None:
        """Land where we are: PX4 MAV_CMD_NAV_LAND (falls back to AUTO.LAND mode), ArduPilot LAND mode.

        Setpoints keep streaming until the autopilot accepts, so a slow answer cannot drop PX4 out of OFFBOARD.
        """
        if self.autopilot is Autopilot.ARDUPILOT:
            self.set_mode("LAND")
        else:
            try:
                self.command_long(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, _NAN, _NAN, _NAN, _NAN)
            except CommandRejected as exc:
                log.warning("%s; switching to LAND mode instead", exc)
                self.set_mode("LAND")
        self._streaming = False
        log.info("landing")

    def hold(self) -> None:
        """Hover in place: LOITER mode; if refused, keep streaming a setpoint at the current position."""
        t = self.telemetry
        if self.in_control:
            self.goto_local(t.north_m, t.east_m, t.down_m, _heading_or_zero(t))
        try:
            self.set_mode("LOITER")
        except (CommandRejected, UnsupportedMode) as exc:
            if not self.in_control:
                raise
            log.warning("%s; holding with a position setpoint instead", exc)
        else:
            self._streaming = False
        log.info("holding position")

    def release_control(self) -> None:
        """Stop streaming setpoints (the autopilot keeps its current mode)."""
        self._streaming = False
        self._setpoint = None

    # ------------------------------------------------------------------------------------------ threads
    def _send(self, msg) -> None:
        with self._send_lock:
            if self._conn is not None:
                self._conn.mav.send(msg)

    def _on_sent(self, msg) -> None:  # called by the encoder under _send_lock
        self._write_tlog(msg.get_msgbuf())

    def _write_tlog(self, packet: bytes) -> None:
        with self._tlog_lock:
            if self._tlog is not None:
                self._tlog.write(struct.pack(">Q", int(time.time() * 1e6) & ~3) + bytes(packet))
                self._tlog.flush()

    def _on_eof(self) -> None:
        if not self._eof:
            log.error("the autopilot closed the connection %s", self.connection)
        self._eof = True

    def _send_setpoint(self, sp: _Setpoint) -> None:
        if self._target is None:
            return
        sysid, compid = self._target
        now = time.monotonic()
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        velocity = sp.velocity_ned
        if velocity is not None and now - sp.set_at_s > self.feedforward_timeout_s:
            velocity = None
        mask = TYPE_MASK_POSITION_YAW if velocity is None else TYPE_MASK_POSITION_VELOCITY_YAW
        vn, ve, vd = (0.0, 0.0, 0.0) if velocity is None else velocity
        self._send(self._conn.mav.set_position_target_local_ned_encode(
            boot_ms, sysid, compid, mavlink.MAV_FRAME_LOCAL_NED, mask,
            sp.north_m, sp.east_m, sp.down_m, vn, ve, vd, 0, 0, 0, sp.yaw_rad, 0))

    def _send_loop(self) -> None:
        period = 1.0 / self.setpoint_rate_hz
        next_heartbeat = 0.0
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if now >= next_heartbeat:
                    next_heartbeat = now + 1.0
                    self._send(self._conn.mav.heartbeat_encode(
                        mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE))
                sp = self._setpoint
                if self._streaming and sp is not None:
                    self._send_setpoint(sp)
            except (OSError, AttributeError) as exc:  # AttributeError: connection closed under us
                if self._stop.is_set():
                    return
                log.debug("send failed: %s", exc)
            self._stop.wait(period)

    def _read_loop(self) -> None:
        conn = self._conn
        while not self._stop.is_set():
            if self._eof:
                self._stop.wait(0.1)
                continue
            try:
                msg = conn.recv_msg()
            except OSError as exc:
                if not self._stop.is_set():
                    log.error("link read failed: %s", exc)
                self._eof = True
                continue
            if msg is None:
                conn.select(0.05)
                continue
            if msg.get_type() == "BAD_DATA":
                continue
            self._write_tlog(msg.get_msgbuf())
            self._handle(msg)

    def _handle(self, msg) -> None:
        now = time.monotonic()
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        with self._cond:
            if self._target is None:
                if mtype != "HEARTBEAT" or not is_autopilot_heartbeat(msg):
                    return
                self._target = src
                self._mav_type = msg.type
            if src[0] != self._target[0]:
                return
            if mtype == "HEARTBEAT" and src != self._target:
                return  # another component of the same system
            if mtype == "COMMAND_ACK":
                if getattr(msg, "target_system", 0) in (0, self._source_system):
                    self._acks.append(msg)
            self._telemetry = update_telemetry(self._telemetry, msg, now)
            self._cond.notify_all()
        if mtype == "STATUSTEXT":
            level = logging.WARNING if msg.severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO
            log.log(level, "autopilot says: %s", str(msg.text).rstrip("\x00"))


def _heading_or_zero(t: Telemetry) -> float:
    return 0.0 if math.isnan(t.heading_rad) else t.heading_rad
