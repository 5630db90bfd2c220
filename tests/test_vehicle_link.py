"""The vehicle link against a small fake autopilot on 127.0.0.1: identity, acks, retries, streams, liveness,
round trips, parameters, reconnects, signing and the flight actions; at the end, against the in-process sim.

The fake speaks real MAVLink 2 (pymavlink's generated messages) and behaves, knob by knob, the way the SITL
autopilots were measured to: it acks the sender it heard, answers PARAM_REQUEST_READ with PX4's bytewise
integers, streams a message only once asked, answers TIMESYNC. What the client did is judged from what the fake
received, not from the client's own account.
"""

from __future__ import annotations

import math
import select
import socket
import struct
import threading
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute import vehicle as vh
from skyroute.vehicle import limits
from skyroute.vehicle.telemetry import local_scale


class FakeAutopilot:
    """A few dozen lines of autopilot on 127.0.0.1:PORT (TCP), system ``sysid`` component 1.

    Knobs: ``deny`` / ``temporary`` / ``in_progress`` {command: how many DENIED / TEMPORARILY_REJECTED /
    IN_PROGRESS answers first}; ``silent`` {command: sends to ignore}; ``lost_acks`` {command: sends obeyed but
    not answered}; ``send_heartbeat``, ``send_positions``;
    ``on_request_only``: stream LOCAL_POSITION_NED only after a SET_MESSAGE_INTERVAL for it; ``latency_s`` delays
    everything it sends; ``params`` {name: (value, MAV_PARAM_TYPE)} sent PX4-style (integers bytewise);
    ``foreign_acks``: answer each command first with an ack addressed to another ground station (255, 190);
    ``other_system``: a second vehicle's heartbeat on the same link; ``key``: MAVLink 2 signing; ``sensors_present``:
    SYS_STATUS's present bits (ArduPilot sets PROXIMITY and LASER_POSITION for a configured proximity sensor and
    rangefinder).
    """

    def __init__(self, autopilot=mavlink.MAV_AUTOPILOT_PX4, *, sysid=1, deny=None, temporary=None,
                 in_progress=None, silent=None, mav_type=None, send_heartbeat=True, send_positions=True,
                 on_request_only=False, latency_s=0.0, params=None, foreign_acks=False, other_system=None,
                 key=None, deny_text=b"Preflight Fail: GPS not ready", ack_delay_s=0.0, sensors_present=0,
                 lost_acks=None):
        self.autopilot, self.sysid = autopilot, sysid
        self.mav_type = mavlink.MAV_TYPE_QUADROTOR if mav_type is None else mav_type
        self.deny, self.temporary = dict(deny or {}), dict(temporary or {})
        self.in_progress, self.silent = dict(in_progress or {}), dict(silent or {})
        self.lost_acks = dict(lost_acks or {})  # command -> how many of its final acks are lost (it is obeyed)
        self.send_heartbeat, self.send_positions = send_heartbeat, send_positions
        self.on_request_only, self.latency_s = on_request_only, latency_s
        self.params = dict(params or {})
        self.foreign_acks, self.other_system, self.key = foreign_acks, other_system, key
        self.deny_text, self.ack_delay_s = deny_text, ack_delay_s
        self.sensors_present = sensors_present
        self.texts: list[tuple[int, bytes]] = []  # STATUSTEXTs to send once, (severity, text)
        self.unacked: dict[int, int] = {}  # command -> received but not yet answered
        self.overlaps: list[int] = []  # commands received while one of the same kind was still unanswered
        self.requested: set[int] = set()
        self.armed = False
        self.custom_mode = 0
        self.received: list = []
        self.received_at: list[float] = []
        self.bad_packets = 0
        self.connections = 0
        self._outbox: list[tuple[float, object]] = []
        self._drop = threading.Event()
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def stop(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self._server.close()

    def drop_connection(self):
        """Close the client's TCP connection (it may connect again)."""
        self._drop.set()

    def of_type(self, mtype):
        return [m for m in list(self.received) if m.get_type() == mtype]

    def commands(self, command):
        return [m for m in self.of_type("COMMAND_LONG") if m.command == command]

    def _run(self):
        self._server.settimeout(0.1)
        while not self._stop.is_set():
            try:
                sock, _ = self._server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            self._drop.clear()
            self._outbox.clear()  # what was queued for the old connection is lost with it
            out = sock.makefile("wb", buffering=0)
            enc = mavlink.MAVLink(out, srcSystem=self.sysid, srcComponent=1)
            self._other = mavlink.MAVLink(out, srcSystem=self.other_system or 0, srcComponent=1)
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            if self.key is not None:
                for m in (enc, parser):
                    m.signing.secret_key, m.signing.sign_outgoing, m.signing.link_id = self.key, True, 7
                    m.signing.timestamp = int((time.time() - 1420070400) * 1e5)
            with sock:
                try:
                    self._serve(sock, enc, parser)
                    sock.shutdown(socket.SHUT_RDWR)  # the makefile() writer would keep it open otherwise
                except OSError:  # the client closed the connection
                    pass
                out.close()

    def _send(self, enc, msg, delay_s=0.0):
        self._outbox.append((time.monotonic() + self.latency_s + delay_s, msg, enc))

    def _flush(self, enc):
        now = time.monotonic()
        due = [(m, e) for t, m, e in self._outbox if t <= now]
        self._outbox = [(t, m, e) for t, m, e in self._outbox if t > now]
        for msg, sender in due:
            if msg.get_type() == "COMMAND_ACK" and msg.result != mavlink.MAV_RESULT_IN_PROGRESS \
                    and (msg.target_system, msg.target_component) != (255, 190):
                self.unacked[msg.command] = max(self.unacked.get(msg.command, 0) - 1, 0)
            sender.send(msg)

    def _serve(self, sock, enc, parser):
        next_tx = 0.0
        while not self._stop.is_set() and not self._drop.is_set():
            if time.monotonic() >= next_tx:
                next_tx = time.monotonic() + 0.05
                self._telemetry(enc)
            self._flush(enc)
            if select.select([sock], [], [], 0.01)[0]:
                data = sock.recv(4096)
                if not data:
                    return
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() == "BAD_DATA":
                        self.bad_packets += 1
                        continue
                    self.received.append(msg)
                    self.received_at.append(time.monotonic())
                    self._handle(enc, msg)

    def _telemetry(self, enc):
        while self.texts:
            severity, text = self.texts.pop(0)
            self._send(enc, mavlink.MAVLink_statustext_message(severity, text))
        if self.send_heartbeat:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED
                                                                if self.armed else 0)
            self._send(enc, mavlink.MAVLink_heartbeat_message(self.mav_type, self.autopilot, base, self.custom_mode,
                                                              mavlink.MAV_STATE_STANDBY, 3))
        if self.other_system is not None:  # another vehicle on the same link
            self._send(self._other, mavlink.MAVLink_heartbeat_message(self.mav_type, self.autopilot, 0, 0,
                                                                      mavlink.MAV_STATE_STANDBY, 3))
        if self.send_positions:
            self._send(enc, mavlink.MAVLink_global_position_int_message(1000, 377924800, -1223974500, 0, 0, 0, 0, 0,
                                                                        0))
            if not self.on_request_only or mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED in self.requested:
                self._send(enc, mavlink.MAVLink_local_position_ned_message(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            self._send(enc, mavlink.MAVLink_extended_sys_state_message(0, mavlink.MAV_LANDED_STATE_ON_GROUND))
            present = self.sensors_present
            self._send(enc, mavlink.MAVLink_sys_status_message(present, present, present, 0, 12600, -1, 90,
                                                               0, 0, 0, 0, 0, 0))

    def _ack(self, enc, msg, result, delay_s=0.0):
        self._send(enc, mavlink.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(),
                                                            msg.get_srcComponent()), delay_s)

    def _handle(self, enc, msg):
        kind = msg.get_type()
        if kind == "TIMESYNC" and msg.tc1 == 0:
            self._send(enc, mavlink.MAVLink_timesync_message(time.monotonic_ns(), msg.ts1))
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id
            if name in self.params:
                value, ptype = self.params[name]
                if ptype != mavlink.MAV_PARAM_TYPE_REAL32:  # PX4: the integer's bytes in the float field
                    value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
                self._send(enc, mavlink.MAVLink_param_value_message(name.encode(), value, ptype, len(self.params), 0))
        elif kind == "COMMAND_LONG":
            self._command(enc, msg)

    def _command(self, enc, msg):
        cmd = msg.command
        if self.silent.get(cmd, 0) > 0:
            self.silent[cmd] -= 1
            return
        if self.unacked.get(cmd, 0) > 0:
            self.overlaps.append(cmd)
        self.unacked[cmd] = self.unacked.get(cmd, 0) + 1
        if self.foreign_acks:  # another ground station's ack, on the same link, right away
            self._send(enc, mavlink.MAVLink_command_ack_message(cmd, mavlink.MAV_RESULT_DENIED, 0, 0, 255, 190))
        for table, result in ((self.deny, mavlink.MAV_RESULT_DENIED),
                              (self.temporary, mavlink.MAV_RESULT_TEMPORARILY_REJECTED)):
            if table.get(cmd, 0) > 0:
                table[cmd] -= 1
                self._send(enc, mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL, self.deny_text))
                self._ack(enc, msg, result)
                return
        delay = self.ack_delay_s
        for _ in range(self.in_progress.pop(cmd, 0)):
            self._ack(enc, msg, mavlink.MAV_RESULT_IN_PROGRESS, delay)
            delay += 0.4
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 == 1
        elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
            if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
                self.custom_mode = (int(msg.param2) << 16) | (int(msg.param3) << 24)
            else:
                self.custom_mode = int(msg.param2)
        elif cmd == mavlink.MAV_CMD_NAV_LAND and self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            self.custom_mode = (4 << 16) | (6 << 24)  # AUTO.LAND, as PX4's navigator takes the command
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.requested.add(int(msg.param1))
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | (
                mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE if self.autopilot == mavlink.MAV_AUTOPILOT_PX4
                else 0)
            self._send(enc, mavlink.MAVLink_autopilot_version_message(caps, 0, 0, 0, 0, bytes(8), bytes(8), bytes(8),
                                                                      0, 0, 0), delay)
        if self.lost_acks.get(cmd, 0) > 0:  # obeyed, but the answer never arrives (a lossy radio link)
            self.lost_acks[cmd] -= 1
            self.unacked[cmd] -= 1
            return
        self._ack(enc, msg, mavlink.MAV_RESULT_ACCEPTED, delay)


@pytest.fixture
def fake():
    autopilots = []

    def make(*args, **kwargs):
        ap = FakeAutopilot(*args, **kwargs)
        autopilots.append(ap)
        return ap

    yield make
    for ap in autopilots:
        ap.stop()


@pytest.fixture
def connect():
    vehicles = []

    def make(port, **kwargs):
        kwargs.setdefault("heartbeat_timeout_s", 3.0)
        kwargs.setdefault("command_timeout_s", 0.3)
        v = vh.MavlinkVehicle(f"tcp:127.0.0.1:{port}", **kwargs)
        vehicles.append(v)
        return v

    yield make
    for v in vehicles:
        v.close()


def wait_until(predicate, timeout_s=3.0, step_s=0.02):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(step_s)
    return True


# ------------------------------------------------------------------------------------------ identity, streams
def test_connect_detects_px4_and_requests_telemetry_as_a_companion_ground_station(fake, connect):
    ap = fake()
    v = connect(ap.port)
    assert v.autopilot is vh.Autopilot.PX4
    t = v.wait_for(lambda t: t.has_global and t.has_local, 2.0, "positions")
    assert t.lat_deg == pytest.approx(37.79248)
    wanted = {mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
              mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
              mavlink.MAVLINK_MSG_ID_SYS_STATUS}
    assert wait_until(lambda: wanted <= {int(m.param1) for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)})
    assert wait_until(lambda: mavlink.MAVLINK_MSG_ID_HOME_POSITION in {
        int(m.param1) for m in ap.commands(mavlink.MAV_CMD_REQUEST_MESSAGE)})
    ours = ap.of_type("HEARTBEAT")
    assert ours and ours[0].type == mavlink.MAV_TYPE_GCS  # PX4 reports refusals only to a ground station
    assert (ours[0].get_srcSystem(), ours[0].get_srcComponent()) == (255, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)
    assert ap.received[0].get_msgbuf()[0] == 253  # MAVLink 2 from the first packet


def test_distance_sensor_is_asked_for_only_from_an_autopilot_that_reports_a_range_sensor(fake, connect):
    def asked_for_distance(ap) -> bool:
        return mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR in {
            int(m.param1) for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)}

    without = fake(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)  # ArduCopter SITL's defaults: no proximity, no rangefinder
    connect(without.port)
    assert wait_until(lambda: mavlink.MAVLINK_MSG_ID_SYS_STATUS in {
        int(m.param1) for m in without.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)})
    time.sleep(0.5)  # a few of the link's keeper rounds (0.25 s) with SYS_STATUS in hand
    assert not asked_for_distance(without)
    ranging = fake(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, sensors_present=mavlink.MAV_SYS_STATUS_SENSOR_PROXIMITY)
    connect(ranging.port)
    assert wait_until(lambda: asked_for_distance(ranging))


def test_one_command_of_a_kind_in_flight_at_a_time(fake, connect):
    ap = fake(ack_delay_s=0.1)  # a slow autopilot: a client that did not wait would send the next one meanwhile
    connect(ap.port)
    assert wait_until(lambda: len(ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)) >= 5)
    assert ap.overlaps == []  # each waited for the previous one's ack
    assert len({int(m.param1) for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)[:5]}) == 5


def test_a_stream_that_does_not_arrive_is_asked_for_again(fake, connect):
    # the first SET_MESSAGE_INTERVAL for LOCAL_POSITION_NED is lost (never answered); it streams only once asked
    ap = fake(on_request_only=True)
    original = ap._command

    def lose_the_first_local_request(enc, msg):
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and int(msg.param1) == 32 and not getattr(ap, "lost", 0):
            ap.lost = 1
            return
        original(enc, msg)

    ap._command = lose_the_first_local_request
    v = connect(ap.port)
    t = v.wait_for(lambda t: t.has_local, 8.0, "LOCAL_POSITION_NED")  # came, because it was asked again
    asks = [m for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL) if int(m.param1) == 32]
    assert t.has_local and len(asks) >= 2


def test_the_target_system_is_chosen_when_two_vehicles_heartbeat(fake, connect):
    ap = fake(sysid=2, other_system=1)
    v = connect(ap.port, target_system=2)
    assert v.target == (2, 1)
    v.arm()
    assert all(m.target_system == 2 for m in ap.of_type("COMMAND_LONG"))


def test_a_missing_target_system_says_which_systems_were_heard(fake):
    ap = fake(sysid=1)
    with pytest.raises(vh.ConnectionTimeout, match=r"system 7: heard systems \[1\]"):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.5, target_system=7)


# --------------------------------------------------------------------------------------------------- commands
def test_arm_accepted(fake, connect):
    ap = fake()
    v = connect(ap.port)
    v.arm()
    assert v.telemetry.armed
    v.disarm()
    assert not v.telemetry.armed and not ap.armed


def test_arm_denied_quotes_the_autopilot(fake, connect):
    ap = fake(deny={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 1})
    v = connect(ap.port)
    with pytest.raises(vh.CommandRejected) as err:
        v.arm()
    assert err.value.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
    assert err.value.result == mavlink.MAV_RESULT_DENIED and err.value.permanent
    assert err.value.reason == "Preflight Fail: GPS not ready"
    assert "MAV_CMD_COMPONENT_ARM_DISARM" in str(err.value) and "GPS not ready" in str(err.value)
    v.arm()  # the second attempt is accepted
    assert v.telemetry.armed


def test_a_chunked_refusal_is_quoted_whole(fake, connect):
    ap = fake(deny={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 1})
    original = ap._send

    def chunked(enc, msg, delay_s=0.0):  # PX4 sends its 51-byte refusal in two STATUSTEXT chunks
        if msg.get_type() == "STATUSTEXT":
            original(enc, mavlink.MAVLink_statustext_message(2, b"Arming denied: Resolve system health failures firs",
                                                             3, 0))
            original(enc, mavlink.MAVLink_statustext_message(2, b"t\t", 3, 1))
            return
        original(enc, msg, delay_s)

    ap._send = chunked
    v = connect(ap.port)
    with pytest.raises(vh.CommandRejected) as err:
        v.arm()
    assert err.value.reason == "Arming denied: Resolve system health failures first"


def test_an_ack_for_another_ground_station_is_not_taken_for_ours(fake, connect):
    ap = fake(foreign_acks=True)  # QGroundControl (255/190) on the same link gets a DENIED first
    v = connect(ap.port)
    v.arm()  # ours (255/191) was accepted
    assert v.telemetry.armed


def test_in_progress_waits_for_the_final_ack_without_resending(fake, connect):
    ap = fake(in_progress={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 3})  # final ack 1.2 s later: 4 x our timeout
    v = connect(ap.port, command_timeout_s=0.3)
    v.arm()
    assert len(ap.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)) == 1 and v.telemetry.armed


def test_temporarily_rejected_is_retried_when_asked(fake, connect):
    ap = fake(temporary={mavlink.MAV_CMD_DO_SET_MODE: 2})  # PX4: OFFBOARD only once setpoints stream
    v = connect(ap.port)
    v.set_mode("OFFBOARD", retry_temporary_s=3.0)
    assert len(ap.commands(mavlink.MAV_CMD_DO_SET_MODE)) == 3 and v.telemetry.mode == "OFFBOARD"
    ap.temporary[mavlink.MAV_CMD_DO_SET_MODE] = 1
    with pytest.raises(vh.CommandRejected) as err:  # not asked to retry: the caller decides
        v.set_mode("LOITER")
    assert err.value.temporary and not err.value.permanent


def test_command_retried_with_confirmation(fake, connect):
    ap = fake(silent={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 2})
    v = connect(ap.port)
    v.arm()
    assert [m.confirmation for m in ap.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)] == [0, 1, 2]


@pytest.mark.parametrize("action", ["arm", "set_mode", "land"])
def test_a_command_obeyed_but_unanswered_is_taken_from_the_next_heartbeat_not_resent_or_failed(fake, connect, action):
    # a lossy radio link: the autopilot switched mode (armed) but its COMMAND_ACK was lost, every time
    command = {"arm": mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "set_mode": mavlink.MAV_CMD_DO_SET_MODE,
               "land": mavlink.MAV_CMD_NAV_LAND}[action]
    ap = fake(lost_acks={command: 99})
    v = connect(ap.port, command_retries=2)
    assert wait_until(lambda: v.telemetry.mode != "")
    {"arm": v.arm, "set_mode": lambda: v.set_mode("LOITER", confirm_s=0.0), "land": v.land}[action]()
    assert len(ap.commands(command)) == 1
    assert wait_until(lambda: (v.telemetry.armed if action == "arm" else
                               v.telemetry.mode == ("LOITER" if action == "set_mode" else "LAND")))


def test_a_stale_heartbeat_does_not_answer_a_command(fake, connect):
    # the heartbeat already says LOITER, but none comes after the request (the autopilot ignores it): no answer
    ap = fake(silent={mavlink.MAV_CMD_DO_SET_MODE: 99})
    ap.custom_mode = (4 << 16) | (3 << 24)  # AUTO.LOITER
    v = connect(ap.port, command_retries=1, link_floor_s=5.0)
    assert wait_until(lambda: v.telemetry.mode == "LOITER")
    ap.send_heartbeat = False  # positions keep the link alive
    time.sleep(0.1)
    with pytest.raises(vh.CommandTimeout):
        v.set_mode("LOITER", confirm_s=0.0)
    assert len(ap.commands(mavlink.MAV_CMD_DO_SET_MODE)) == 2


def test_command_timeout_after_bounded_retries(fake, connect):
    ap = fake(silent={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 99})
    v = connect(ap.port, command_retries=2)
    with pytest.raises(vh.CommandTimeout) as err:
        v.arm()
    assert err.value.attempts == 3 and len(ap.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)) == 3
    assert isinstance(err.value, vh.VehicleError)


# --------------------------------------------------------------------------------------------- parameters
def px4_params(**given):
    """Every parameter :func:`flight_limits` reads from PX4, at its default (as PX4 has them all: none is waited
    for), with ``given`` {name: (value, MAV_PARAM_TYPE)} instead where named. Integers for the actions."""
    real = {"COM_OF_LOSS_T", "MPC_XY_VEL_MAX", "MPC_ACC_HOR", "MPC_XY_P", "MPC_TILTMAX_AIR", "GF_MAX_HOR_DIST",
            "GF_MAX_VER_DIST", "RTL_RETURN_ALT"}
    out = {name: (limits.DEFAULTS[name], mavlink.MAV_PARAM_TYPE_REAL32) if name in real
           else (int(limits.DEFAULTS[name]), mavlink.MAV_PARAM_TYPE_INT32) for name in limits.PX4_PARAMETERS}
    return {**out, **given}


def test_parameters_are_read_with_px4s_integer_encoding(fake, connect):
    ap = fake(params=px4_params(COM_OF_LOSS_T=(1.0, mavlink.MAV_PARAM_TYPE_REAL32),
                                NAV_DLL_ACT=(3, mavlink.MAV_PARAM_TYPE_INT32),
                                COM_OBL_RC_ACT=(4, mavlink.MAV_PARAM_TYPE_INT32)))
    v = connect(ap.port)
    assert v.read_params(["COM_OF_LOSS_T", "NAV_DLL_ACT", "COM_OBL_RC_ACT", "NO_SUCH_PARAM"], timeout_s=0.5) == {
        "COM_OF_LOSS_T": 1.0, "NAV_DLL_ACT": 3.0, "COM_OBL_RC_ACT": 4.0}
    limits = v.flight_limits()
    assert not limits.leaves_flying and "Land" in limits.link_loss  # COM_OBL_RC_ACT = 4 lands


# ------------------------------------------------------------------------------------ liveness, round trips
def test_the_link_lives_on_any_message_not_only_heartbeats(fake, connect):
    ap = fake()
    v = connect(ap.port, link_floor_s=0.5)
    ap.send_heartbeat = False  # positions keep coming at 20 Hz
    time.sleep(1.5)
    assert v.link_ok
    ap.send_positions = False
    assert wait_until(lambda: not v.link_ok, 2.0)
    with pytest.raises(vh.LinkLost):
        v.check_link()
    with pytest.raises(vh.LinkLost):
        v.arm()


def test_a_silence_shorter_than_a_lost_link_explains_a_failsafe_mode_change(fake, connect):
    # a short outage: PX4 leaves OFFBOARD after COM_OF_LOSS_T (1 s), its "Failsafe activated" lost with the link;
    # the silence, not a pilot, explains the mode the vehicle comes back in
    ap = fake()
    v = connect(ap.port, link_floor_s=5.0)  # lost only after 5 s of silence: far from this 1.2 s one
    assert wait_until(lambda: v.telemetry.has_local)
    assert v.failsafe_hint() is None
    ap.send_heartbeat = ap.send_positions = False
    time.sleep(1.2)
    ap.send_heartbeat = ap.send_positions = True
    assert wait_until(lambda: v.health.silent_s() < 0.2)
    assert v.link_ok and not v.link_silent_within(5.0)  # never counted as lost
    hint = v.failsafe_hint()
    assert hint is not None and "heard nothing from the autopilot for" in hint


def test_a_silence_shorter_than_the_autopilots_own_failsafe_timeout_explains_nothing(fake, connect):
    ap = fake(params=px4_params(COM_OF_LOSS_T=(3.0, mavlink.MAV_PARAM_TYPE_REAL32)))  # PX4 waits 3 s for setpoints
    v = connect(ap.port, link_floor_s=5.0)
    v.flight_limits()
    ap.send_heartbeat = ap.send_positions = False
    time.sleep(1.2)
    ap.send_heartbeat = ap.send_positions = True
    assert wait_until(lambda: v.health.silent_s() < 0.2)
    assert v.failsafe_hint() is None  # a pilot's mode after this is a pilot's


def test_a_failsafe_the_autopilot_names_as_its_own_is_not_counted_as_ours(fake, connect):
    # ArduCopter SITL's battery failsafe (measured): both texts at MAV_SEVERITY_WARNING, then RTL
    ap = fake(autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    v = connect(ap.port)
    assert wait_until(lambda: v.telemetry.has_local)
    assert v.own_failsafe() is None
    ap.texts += [(mavlink.MAV_SEVERITY_WARNING, b"Battery 1 is low 10.00V used 177 mAh"),
                 (mavlink.MAV_SEVERITY_WARNING, b"Battery Failsafe")]
    assert wait_until(lambda: v.own_failsafe() == "Battery Failsafe")
    assert v.failsafe_hint() is None  # nothing on our side explains the mode it chose


def test_a_failsafe_about_our_link_is_ours_and_a_generic_one_only_with_texts(fake, connect):
    ap = fake()
    v = connect(ap.port)
    assert wait_until(lambda: v.telemetry.has_local)
    ap.texts.append((mavlink.MAV_SEVERITY_WARNING, b"Failsafe activated\t"))  # PX4's, for any cause
    assert wait_until(lambda: v.failsafe_hint() == "the autopilot said 'Failsafe activated'")
    assert v.own_failsafe() is None and v.failsafe_hint(texts=False) is None
    ap.texts.append((mavlink.MAV_SEVERITY_WARNING, b"GCS Failsafe"))  # ArduCopter's, about our heartbeats
    assert wait_until(lambda: v.failsafe_hint(texts=False) == "the autopilot said 'GCS Failsafe'")
    assert v.own_failsafe() is None


def test_the_round_trip_is_measured_and_sizes_the_link_timeout(fake, connect):
    ap = fake(latency_s=0.25)  # everything the autopilot sends arrives 250 ms late
    v = connect(ap.port, link_floor_s=0.5)
    assert wait_until(lambda: v.round_trip_s > 0.2, 4.0)
    assert 0.2 < v.round_trip_s < 0.5
    assert v.health.timeout_s >= 4 * 0.25  # at least four round trips: latency never reads as an outage


def test_a_dropped_tcp_connection_is_reopened(fake, connect):
    ap = fake()
    v = connect(ap.port, link_floor_s=0.5)
    v.arm()
    ap.drop_connection()
    assert wait_until(lambda: ap.connections >= 2, 5.0)  # the client came back by itself
    assert wait_until(lambda: v.link_ok, 3.0)
    v.disarm()  # and commands work again
    assert not ap.armed and v.transport.reconnects >= 1


# ------------------------------------------------------------------------------------------------- signing
def test_with_a_key_every_packet_is_signed_and_unsigned_packets_are_dropped(fake, connect):
    key = vh.signing_key("correct horse battery staple")
    ap = fake(key=key)  # its parser rejects anything not signed with the key
    v = connect(ap.port, signing_key=key)
    v.arm()
    assert ap.armed and ap.bad_packets == 0 and ap.received  # it understood everything we sent
    assert all(m.get_signed() for m in ap.received)


def test_without_the_right_key_nothing_gets_through(fake):
    ap = fake(key=vh.signing_key("the vehicle's key"))
    with pytest.raises(vh.ConnectionTimeout):  # its signed heartbeats fail our signature check
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.8, signing_key=vh.signing_key("other"))


# -------------------------------------------------------------------------------------------- flight actions
def sent_ne(v, north_m: float, east_m: float):
    """What the client sends for a local point: true metres in the autopilot's own local metres."""
    scale_n, scale_e = local_scale(v.telemetry)
    return pytest.approx(north_m * scale_n, abs=1e-4), pytest.approx(east_m * scale_e, abs=1e-4)


def test_px4_prepare_flight_streams_setpoints_before_the_mode_switch(fake, connect):
    ap = fake()
    v = connect(ap.port)
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.prepare_flight()
    assert v.telemetry.mode == "OFFBOARD"
    mode_cmd = ap.commands(mavlink.MAV_CMD_DO_SET_MODE)[0]
    assert (mode_cmd.param1, mode_cmd.param2, mode_cmd.param3) == (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    first_mode = ap.received.index(mode_cmd)
    assert len([m for m in ap.received[:first_mode] if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]) >= 5
    v.goto_local(10.0, -5.0, -20.0, yaw_rad=1.0)
    first = len(ap.received)

    def recent():
        return [m for m in list(ap.received)[first:] if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]

    assert wait_until(lambda: len(recent()) >= 11, 10.0)
    # >= 10 Hz by the client's own send stamps (time_boot_ms), the typical gap: a busy machine delays a few
    stamps_ms = [m.time_boot_ms for m in recent()]
    assert sorted(b - a for a, b in zip(stamps_ms, stamps_ms[1:]))[len(stamps_ms) // 2 - 1] <= 100
    sp = recent()[-1]
    assert (sp.x, sp.y, sp.z, sp.yaw) == (*sent_ne(v, 10.0, -5.0), -20.0, pytest.approx(1.0))
    assert sp.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED and sp.type_mask == vh.TYPE_MASK_POSITION_YAW
    v.land()
    assert ap.commands(mavlink.MAV_CMD_NAV_LAND)
    time.sleep(0.2)
    after = len(ap.of_type("SET_POSITION_TARGET_LOCAL_NED"))
    time.sleep(0.3)
    assert len(ap.of_type("SET_POSITION_TARGET_LOCAL_NED")) == after  # streaming stopped


def test_velocity_feed_forward_is_sent_then_dropped_when_not_renewed(fake, connect):
    ap = fake()
    v = connect(ap.port, feedforward_timeout_s=0.3)
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.prepare_flight()
    v.goto_local(10.0, -5.0, -20.0, yaw_rad=1.0, velocity_ned=(3.0, 4.0, -1.0))

    def new_target():
        return [m for m in ap.of_type("SET_POSITION_TARGET_LOCAL_NED") if m.x == sent_ne(v, 10.0, 0.0)[0]]

    assert wait_until(lambda: new_target(), 5.0)
    sp = new_target()[0]  # the first send after goto_local: its velocity is fresh
    first_ms = sp.time_boot_ms
    assert sp.type_mask == vh.TYPE_MASK_POSITION_VELOCITY_YAW
    assert (sp.x, sp.y, sp.z, sp.vx, sp.vy, sp.vz) == (*sent_ne(v, 10.0, -5.0), -20.0, 3.0, 4.0, -1.0)
    # a stalled client: a setpoint the client sent (by its own stamp) more than the 0.3 s after that first one
    # keeps the position, loses the velocity
    assert wait_until(lambda: new_target()[-1].time_boot_ms > first_ms + 350, 5.0)
    sp = new_target()[-1]
    assert sp.type_mask == vh.TYPE_MASK_POSITION_YAW
    assert (sp.x, sp.y, sp.z, sp.vx, sp.vy, sp.vz) == (*sent_ne(v, 10.0, -5.0), -20.0, 0.0, 0.0, 0.0)


def test_acceleration_feed_forward_goes_with_the_velocity_and_is_dropped_with_it(fake, connect):
    ap = fake()
    v = connect(ap.port, feedforward_timeout_s=0.3)
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.prepare_flight()
    v.goto_local(12.0, -5.0, -20.0, yaw_rad=1.0, velocity_ned=(3.0, 4.0, 0.0), accel_ned=(2.5, 3.25, 0.0))

    def new_target():
        return [m for m in ap.of_type("SET_POSITION_TARGET_LOCAL_NED") if m.x == sent_ne(v, 12.0, 0.0)[0]]

    assert wait_until(lambda: new_target(), 5.0)
    sp = new_target()[0]
    first_ms = sp.time_boot_ms
    assert sp.type_mask == vh.TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW == mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
    assert (sp.vx, sp.vy, sp.vz, sp.afx, sp.afy, sp.afz) == (3.0, 4.0, 0.0, 2.5, 3.25, 0.0)  # float32-exact
    assert wait_until(lambda: new_target()[-1].time_boot_ms > first_ms + 350, 5.0)
    sp = new_target()[-1]  # stale: position only, no velocity and no acceleration to carry the vehicle on
    assert sp.type_mask == vh.TYPE_MASK_POSITION_YAW
    assert (sp.vx, sp.vy, sp.afx, sp.afy) == (0.0, 0.0, 0.0, 0.0)
    v.goto_local(13.0, -5.0, -20.0, yaw_rad=1.0, accel_ned=(2.4, 3.2, 0.0))  # no velocity: no acceleration either
    at_13 = sent_ne(v, 13.0, 0.0)[0]
    assert wait_until(lambda: [m for m in ap.of_type("SET_POSITION_TARGET_LOCAL_NED") if m.x == at_13], 5.0)
    sp = [m for m in ap.of_type("SET_POSITION_TARGET_LOCAL_NED") if m.x == at_13][0]
    assert sp.type_mask == vh.TYPE_MASK_POSITION_YAW and (sp.afx, sp.afy) == (0.0, 0.0)


def test_local_position_is_requested_at_the_steering_rate(fake, connect):
    ap = fake()
    connect(ap.port, telemetry_rate_hz=10.0, local_position_rate_hz=50.0)
    assert wait_until(lambda: {32, 33} <= {int(m.param1) for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)})
    asks = {int(m.param1): m.param2 for m in ap.commands(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)}
    assert asks[mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED] == pytest.approx(1e6 / 50.0)
    assert asks[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == pytest.approx(1e6 / 10.0)


def test_ardupilot_is_put_in_guided_before_arming_then_takes_off_with_nav_takeoff(fake, connect):
    ap = fake(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    ap.custom_mode = 9  # left in LAND by the previous mission: not armable there
    v = connect(ap.port)
    v.wait_for(lambda t: t.has_local and t.mode == "LAND", 2.0, "local position")
    v.prepare_flight()
    v.arm()
    v.takeoff(15.0)
    order = [(m.command, m.param2) for m in ap.of_type("COMMAND_LONG")
             if m.command in (mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                              mavlink.MAV_CMD_NAV_TAKEOFF)]
    assert [c for c, _ in order] == [mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                     mavlink.MAV_CMD_NAV_TAKEOFF]
    assert order[0][1] == 4  # GUIDED
    assert ap.commands(mavlink.MAV_CMD_NAV_TAKEOFF)[-1].param7 == 15.0
    after_takeoff = ap.received.index(ap.commands(mavlink.MAV_CMD_NAV_TAKEOFF)[-1])
    time.sleep(0.3)
    assert not [m for m in ap.received[after_takeoff:] if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    v.land()
    assert ap.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1].param2 == 9  # LAND


def test_hold_uses_the_hold_modes(fake, connect):
    ap = fake()
    connect(ap.port).hold()
    assert (ap.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1].param2, ap.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1].param3) \
        == (4, 3)  # PX4 AUTO.LOITER (Hold)
    ardu = fake(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    connect(ardu.port).hold()
    assert ardu.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1].param2 == 17  # ArduCopter BRAKE


def test_no_heartbeat_raises_connection_timeout(fake):
    ap = fake(send_heartbeat=False, send_positions=False)
    start = time.monotonic()
    with pytest.raises(vh.ConnectionTimeout, match="within 0.5 s"):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.5)
    assert time.monotonic() - start < 2.5


def test_gcs_heartbeats_are_ignored(fake):
    ap = fake(mavlink.MAV_AUTOPILOT_INVALID, mav_type=mavlink.MAV_TYPE_GCS)
    with pytest.raises(vh.ConnectionTimeout):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.5)


def test_nothing_listening_raises_connection_timeout():
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]
    with pytest.raises(vh.ConnectionTimeout, match="refused"):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{port}", heartbeat_timeout_s=0.5)


def test_tlog_holds_both_directions(fake, connect, tmp_path):
    ap = fake()
    path = tmp_path / "flight.tlog"
    v = connect(ap.port, tlog_path=path)
    v.arm()
    v.close()
    log = mavutil.mavlink_connection(str(path))
    seen = set()
    while (m := log.recv_msg()) is not None:
        seen.add((m.get_type(), m.get_srcSystem()))
    log.close()
    assert {("HEARTBEAT", 1), ("HEARTBEAT", 255), ("COMMAND_LONG", 255), ("COMMAND_ACK", 1)} <= seen


# ------------------------------------------------------------------------------ flights against sim/
@pytest.mark.flight
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_fly_against_sim(sim_start, autopilot):
    sim = sim_start(strict=True, autopilot=autopilot)
    with vh.MavlinkVehicle(f"tcp:127.0.0.1:{sim.port}", heartbeat_timeout_s=5.0) as v:
        assert v.autopilot is vh.Autopilot(autopilot)
        t = v.wait_for(lambda t: t.has_local and t.home is not None, 5.0, "position and home")
        assert t.on_ground and not t.armed
        v.prepare_flight()
        v.arm()
        target = v.takeoff(8.0)
        v.wait_for(lambda t: t.down_m < target.down_m + 0.5, 20.0, "takeoff altitude")
        assert v.in_control or v.wait_for(lambda t: t.mode in ("OFFBOARD", "GUIDED"), 2.0, "control mode")
        v.goto_local(target.north_m - 10.0, target.east_m + 5.0, target.down_m, yaw_rad=math.pi)
        v.wait_for(lambda t: math.hypot(t.north_m - target.north_m + 10, t.east_m - target.east_m - 5) < 0.3
                   and abs(t.heading_rad - math.pi) < 0.1, 20.0, "goto")
        v.land()
        v.wait_for(lambda t: t.on_ground, 30.0, "touchdown")
        if v.telemetry.armed:
            v.disarm()
        assert not v.telemetry.armed
    report = sim.stop()
    assert report["landed"]["north_m"] == pytest.approx(-10.0, abs=0.3)
    assert report["landed"]["east_m"] == pytest.approx(5.0, abs=0.3)
    assert not report["collisions"]
    flight = [c for c in report["commands"]
              if c["name"] not in ("MAV_CMD_SET_MESSAGE_INTERVAL", "MAV_CMD_REQUEST_MESSAGE")]
    assert all(c["result_name"] == "MAV_RESULT_ACCEPTED" for c in flight)
