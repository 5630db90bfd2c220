"""The vehicle package: pure MAVLink -> SI translation, and the link/command logic against a tiny fake autopilot.

Messages are encoded to real MAVLink 2 bytes with ``mavlink.MAVLink(io.BytesIO())`` and decoded again, so the
translation functions see exactly what the wire delivers. Expected values are worked out from the MAVLink spec
(degE7, mm, cm/s, cdeg; PX4 main mode in bits 16-23), not copied from the code.
"""

from __future__ import annotations

import io
import math
import select
import socket
import threading
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute import vehicle as vh
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic

MAP_ORIGIN = Geodetic(37.792480, -122.397450, 0.0)


def roundtrip(make):
    """Encode with a sender (system 1, component 1), pack to bytes, decode with a fresh parser."""
    sender = mavlink.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=1)
    buf = make(sender).pack(sender)
    return mavlink.MAVLink(io.BytesIO()).decode(bytearray(buf))


def px4_heartbeat(enc, main_mode=6, sub_mode=0, armed=True):
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
                                (main_mode << 16) | (sub_mode << 24), mavlink.MAV_STATE_ACTIVE)


# ------------------------------------------------------------------------------------------- translation
def test_heartbeat_px4_offboard_armed():
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), roundtrip(px4_heartbeat), now_s=12.5)
    assert t.autopilot is vh.Autopilot.PX4
    assert t.armed is True
    assert t.mode == "OFFBOARD"
    assert t.last_heartbeat_s == 12.5


def test_heartbeat_px4_auto_land_disarmed():
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), roundtrip(lambda e: px4_heartbeat(e, 4, 6, armed=False)), 0.0)
    assert (t.mode, t.armed) == ("LAND", False)


def test_heartbeat_ardupilot_guided():
    msg = roundtrip(lambda e: e.heartbeat_encode(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, mavlink.MAV_STATE_STANDBY))
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0)
    assert (t.autopilot, t.mode, t.armed) == (vh.Autopilot.ARDUPILOT, "GUIDED", False)


def test_gcs_heartbeat_is_not_an_autopilot():
    gcs = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    assert not vh.is_autopilot_heartbeat(gcs)
    assert vh.is_autopilot_heartbeat(roundtrip(px4_heartbeat))


def test_global_position_int_units():
    # 37.7924801 deg, 25.5 m AMSL, 10.25 m above home, 1 m/s N, -2 m/s E, 0.5 m/s down, heading 90 deg
    msg = roundtrip(lambda e: e.global_position_int_encode(4200, 377924801, -1223974500, 25500, 10250,
                                                           100, -200, 50, 9000))
    t = vh.telemetry_from_global_position_int(vh.Telemetry(), msg, 0.0)
    assert t.lat_deg == pytest.approx(37.7924801, abs=1e-9)
    assert t.lon_deg == pytest.approx(-122.39745, abs=1e-9)
    assert (t.alt_amsl_m, t.relative_alt_m) == (pytest.approx(25.5), pytest.approx(10.25))
    assert (t.v_north_mps, t.v_east_mps, t.v_down_mps) == (pytest.approx(1.0), pytest.approx(-2.0),
                                                           pytest.approx(0.5))
    assert t.global_time_s == pytest.approx(4.2)
    assert t.heading_rad == pytest.approx(math.pi / 2)


def test_global_position_int_unknown_heading_stays_nan():
    msg = roundtrip(lambda e: e.global_position_int_encode(0, 0, 0, 0, 0, 0, 0, 0, 65535))
    assert math.isnan(vh.telemetry_from_global_position_int(vh.Telemetry(), msg, 0.0).heading_rad)


def test_local_position_ned():
    msg = roundtrip(lambda e: e.local_position_ned_encode(1500, 3.0, -4.0, -12.0, 0.5, 0.25, -1.0))
    t = vh.telemetry_from_local_position_ned(vh.Telemetry(), msg, 0.0)
    assert t.local == LocalNED(3.0, -4.0, -12.0)
    assert (t.local_v_north_mps, t.local_v_east_mps, t.local_v_down_mps) == (0.5, 0.25, -1.0)
    assert t.local_time_s == pytest.approx(1.5)
    assert t.ground_speed_mps == pytest.approx(math.hypot(0.5, 0.25))


def test_attitude_heading_wraps_to_positive():
    msg = roundtrip(lambda e: e.attitude_encode(0, 0.1, -0.2, -math.pi / 2, 0, 0, 0))
    t = vh.telemetry_from_attitude(vh.Telemetry(), msg, 0.0)
    assert t.heading_rad == pytest.approx(3 * math.pi / 2)
    assert t.roll_rad == pytest.approx(0.1)


@pytest.mark.parametrize("raw, expected", [(1, vh.LandedState.ON_GROUND), (2, vh.LandedState.IN_AIR),
                                           (4, vh.LandedState.LANDING), (0, vh.LandedState.UNDEFINED)])
def test_extended_sys_state(raw, expected):
    msg = roundtrip(lambda e: e.extended_sys_state_encode(0, raw))
    assert vh.telemetry_from_extended_sys_state(vh.Telemetry(), msg, 0.0).landed_state is expected


def test_sys_status_battery_and_prearm():
    pre = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    msg = roundtrip(lambda e: e.sys_status_encode(pre, pre, pre, 0, 12600, -1, 87, 0, 0, 0, 0, 0, 0))
    t = vh.telemetry_from_sys_status(vh.Telemetry(), msg, 0.0)
    assert (t.battery_voltage_v, t.battery_remaining_pct, t.prearm_ok) == (pytest.approx(12.6), 87.0, True)
    msg = roundtrip(lambda e: e.sys_status_encode(0, 0, 0, 0, 65535, -1, -1, 0, 0, 0, 0, 0, 0))
    t = vh.telemetry_from_sys_status(vh.Telemetry(), msg, 0.0)
    assert math.isnan(t.battery_voltage_v) and math.isnan(t.battery_remaining_pct) and t.prearm_ok is None


def test_home_position():
    msg = roundtrip(lambda e: e.home_position_encode(377924800, -1223974500, 3500, 0, 0, 0, [1, 0, 0, 0],
                                                     0, 0, 0))
    home = vh.telemetry_from_home_position(vh.Telemetry(), msg, 0.0).home
    assert home == (pytest.approx(37.79248), pytest.approx(-122.39745), pytest.approx(3.5))


def test_statustext_keeps_the_latest():
    t = vh.Telemetry()
    for i in range(vh.STATUSTEXT_KEEP + 3):
        t = vh.update_telemetry(t, roundtrip(lambda e, i=i: e.statustext_encode(4, f"msg {i}".encode())), float(i))
    assert len(t.statustexts) == vh.STATUSTEXT_KEEP
    assert t.statustexts[-1] == vh.StatusText(4, f"msg {vh.STATUSTEXT_KEEP + 2}", float(vh.STATUSTEXT_KEEP + 2))


def test_update_telemetry_ignores_other_messages():
    t = vh.Telemetry(lat_deg=1.0)
    assert vh.update_telemetry(t, roundtrip(lambda e: e.ping_encode(0, 0, 0, 0)), 0.0) is t


# -------------------------------------------------------------------------------------------- modes, frames
@pytest.mark.parametrize("autopilot, mode, expected", [
    (vh.Autopilot.PX4, "OFFBOARD", (6, 0)),  # px4_custom_mode.h: MAIN_MODE_OFFBOARD = 6
    (vh.Autopilot.PX4, "LAND", (4, 6)),  # AUTO = 4, SUB_MODE_AUTO_LAND = 6
    (vh.Autopilot.PX4, "LOITER", (4, 3)),
    (vh.Autopilot.GENERIC, "offboard", (6, 0)),
    (vh.Autopilot.ARDUPILOT, "GUIDED", (4, 0)),  # ArduCopter mode numbers
    (vh.Autopilot.ARDUPILOT, "LAND", (9, 0)),
    (vh.Autopilot.ARDUPILOT, "LOITER", (5, 0)),
])
def test_mode_numbers(autopilot, mode, expected):
    assert vh.mode_numbers(autopilot, mode) == expected


def test_unknown_mode_raises():
    with pytest.raises(vh.UnsupportedMode, match="GUIDED"):
        vh.mode_numbers(vh.Autopilot.PX4, "GUIDED")


def test_type_mask_position_and_yaw_only():
    # bits: vx vy vz (8 16 32), ax ay az (64 128 256), yaw rate (2048); x y z and yaw (1024) not ignored
    assert vh.TYPE_MASK_POSITION_YAW == 8 + 16 + 32 + 64 + 128 + 256 + 2048


def test_type_mask_position_velocity_and_yaw():
    # bits: ax ay az (64 128 256), yaw rate (2048); position, velocity (feed-forward) and yaw used
    assert vh.TYPE_MASK_POSITION_VELOCITY_YAW == 64 + 128 + 256 + 2048


def test_map_offset_when_autopilot_origin_is_elsewhere():
    # The vehicle stands 120 m north, 40 m west of the map origin, 2 m above home; the EKF booted there.
    where = ned_to_geodetic(LocalNED(120.0, -40.0, 0.0), MAP_ORIGIN)
    t = vh.Telemetry(lat_deg=where.lat_deg, lon_deg=where.lon_deg, relative_alt_m=2.0, global_time_s=5.0,
                     north_m=0.0, east_m=0.0, down_m=-2.0, local_v_north_mps=0.0, local_v_east_mps=0.0,
                     local_v_down_mps=0.0, local_time_s=5.0)
    offset = vh.map_offset(t, MAP_ORIGIN)
    assert offset == (pytest.approx(120.0, abs=1e-3), pytest.approx(-40.0, abs=1e-3), pytest.approx(0.0))
    assert vh.map_position(t, MAP_ORIGIN) == (pytest.approx(120.0, abs=1e-3), pytest.approx(-40.0, abs=1e-3),
                                              pytest.approx(-2.0))


def test_map_offset_needs_both_samples():
    with pytest.raises(ValueError):
        vh.map_offset(vh.Telemetry(lat_deg=1.0, lon_deg=1.0), MAP_ORIGIN)


# ------------------------------------------------------------------------------------- fake autopilot link
class FakeAutopilot:
    """A few dozen lines of autopilot on 127.0.0.1: heartbeat and positions at 20 Hz, acks by script.

    ``deny``: {command: number of DENIED answers (with a STATUSTEXT reason) before accepting};
    ``silent``: {command: number of sends to ignore}; ``heartbeat``: stop sending it to simulate link loss.
    """

    def __init__(self, autopilot=mavlink.MAV_AUTOPILOT_PX4, *, deny=None, silent=None, mav_type=None,
                 send_heartbeat=True):
        self.autopilot = autopilot
        self.mav_type = mavlink.MAV_TYPE_QUADROTOR if mav_type is None else mav_type
        self.deny = dict(deny or {})
        self.silent = dict(silent or {})
        self.send_heartbeat = send_heartbeat
        self.armed = False
        self.custom_mode = 0
        self.received: list = []
        self.received_at: list[float] = []
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def stop(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self._server.close()

    def of_type(self, mtype):
        return [m for m in self.received if m.get_type() == mtype]

    def _run(self):
        self._server.settimeout(0.1)
        while not self._stop.is_set():
            try:
                sock, _ = self._server.accept()
                break
            except TimeoutError:
                continue
        else:
            return
        enc = mavlink.MAVLink(sock.makefile("wb", buffering=0), srcSystem=1, srcComponent=1)
        parser = mavlink.MAVLink(None)
        with sock:
            try:
                self._serve(sock, enc, parser)
            except OSError:  # the client closed the connection
                return

    def _serve(self, sock, enc, parser):
        next_tx = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_tx:
                next_tx = time.monotonic() + 0.05
                self._telemetry(enc)
            if select.select([sock], [], [], 0.01)[0]:
                data = sock.recv(4096)
                if not data:
                    return
                for msg in parser.parse_buffer(data) or []:
                    self.received.append(msg)
                    self.received_at.append(time.monotonic())
                    if msg.get_type() == "COMMAND_LONG":
                        self._command(enc, msg)

    def _telemetry(self, enc):
        if self.send_heartbeat:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED
                                                                if self.armed else 0)
            enc.send(enc.heartbeat_encode(self.mav_type, self.autopilot, base, self.custom_mode,
                                          mavlink.MAV_STATE_STANDBY))
        enc.send(enc.global_position_int_encode(1000, 377924800, -1223974500, 0, 0, 0, 0, 0, 0))
        enc.send(enc.local_position_ned_encode(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))

    def _command(self, enc, msg):
        cmd = msg.command
        if self.silent.get(cmd, 0) > 0:
            self.silent[cmd] -= 1
            return
        if self.deny.get(cmd, 0) > 0:
            self.deny[cmd] -= 1
            enc.send(enc.statustext_encode(mavlink.MAV_SEVERITY_CRITICAL, b"Preflight Fail: GPS not ready"))
            enc.send(enc.command_ack_encode(cmd, mavlink.MAV_RESULT_DENIED, 0, 0, 255, 190))
            return
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 == 1
        elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
            if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
                self.custom_mode = (int(msg.param2) << 16) | (int(msg.param3) << 24)
            else:
                self.custom_mode = int(msg.param2)
        enc.send(enc.command_ack_encode(cmd, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 190))


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


def test_connect_detects_px4_and_requests_telemetry(fake, connect):
    ap = fake()
    v = connect(ap.port)
    assert v.autopilot is vh.Autopilot.PX4
    t = v.wait_for(lambda t: t.has_global and t.has_local, 2.0, "positions")
    assert t.lat_deg == pytest.approx(37.79248)
    requested = {int(m.param1) for m in ap.of_type("COMMAND_LONG")
                 if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL}
    assert {mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
            mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS} <= requested
    home_requests = [m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_REQUEST_MESSAGE]
    assert int(home_requests[0].param1) == mavlink.MAVLINK_MSG_ID_HOME_POSITION
    ours = ap.of_type("HEARTBEAT")
    assert ours and ours[0].type == mavlink.MAV_TYPE_GCS and ours[0].get_srcSystem() == 255
    assert ap.received[0].get_msgbuf()[0] == 253  # MAVLink 2 from the first packet


def test_arm_accepted(fake, connect):
    ap = fake()
    v = connect(ap.port)
    v.arm()
    assert v.telemetry.armed
    v.disarm()
    assert not v.telemetry.armed


def test_arm_denied_quotes_the_autopilot(fake, connect):
    ap = fake(deny={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 1})
    v = connect(ap.port)
    with pytest.raises(vh.CommandRejected) as err:
        v.arm()
    assert err.value.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
    assert err.value.result == mavlink.MAV_RESULT_DENIED
    assert err.value.reason == "Preflight Fail: GPS not ready"
    assert "MAV_CMD_COMPONENT_ARM_DISARM" in str(err.value) and "GPS not ready" in str(err.value)
    v.arm()  # the second attempt is accepted
    assert v.telemetry.armed


def test_command_retried_with_confirmation(fake, connect):
    ap = fake(silent={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 2})
    v = connect(ap.port)
    v.arm()
    arms = [m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM]
    assert [m.confirmation for m in arms] == [0, 1, 2]


def test_command_timeout_after_bounded_retries(fake, connect):
    ap = fake(silent={mavlink.MAV_CMD_COMPONENT_ARM_DISARM: 99})
    v = connect(ap.port, command_retries=2)
    with pytest.raises(vh.CommandTimeout) as err:
        v.arm()
    assert err.value.attempts == 3
    assert len([m for m in ap.of_type("COMMAND_LONG")
                if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM]) == 3
    assert isinstance(err.value, vh.VehicleError)


def test_px4_offboard_streams_setpoints_before_and_after_the_mode_switch(fake, connect):
    ap = fake()
    v = connect(ap.port)
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.start_offboard()
    assert v.telemetry.mode == "OFFBOARD" or v.wait_for(lambda t: t.mode == "OFFBOARD", 1.0, "OFFBOARD")
    mode_cmd = next(m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_DO_SET_MODE)
    assert (mode_cmd.param1, mode_cmd.param2, mode_cmd.param3) == (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    first_mode = ap.received.index(mode_cmd)
    assert len([m for m in ap.received[:first_mode] if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]) >= 5
    v.goto_local(10.0, -5.0, -20.0, yaw_rad=1.0)
    start = time.monotonic()
    time.sleep(1.0)
    recent = [m for m, at in zip(ap.received, ap.received_at, strict=True)
              if at >= start and m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert len(recent) >= 10  # >= 10 Hz
    sp = recent[-1]
    assert (sp.x, sp.y, sp.z, sp.yaw) == (10.0, -5.0, -20.0, pytest.approx(1.0))
    assert sp.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED
    assert sp.type_mask == vh.TYPE_MASK_POSITION_YAW
    v.land()
    land = [m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_NAV_LAND]
    assert land
    time.sleep(0.2)
    after = len(ap.of_type("SET_POSITION_TARGET_LOCAL_NED"))
    time.sleep(0.3)
    assert len(ap.of_type("SET_POSITION_TARGET_LOCAL_NED")) == after  # streaming stopped


def test_velocity_feed_forward_is_sent_then_dropped_when_not_renewed(fake, connect):
    ap = fake()
    v = connect(ap.port, feedforward_timeout_s=0.3)
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.start_offboard()
    v.goto_local(10.0, -5.0, -20.0, yaw_rad=1.0, velocity_ned=(3.0, 4.0, -1.0))
    time.sleep(0.15)
    sp = ap.of_type("SET_POSITION_TARGET_LOCAL_NED")[-1]
    assert sp.type_mask == vh.TYPE_MASK_POSITION_VELOCITY_YAW
    assert (sp.x, sp.y, sp.z, sp.vx, sp.vy, sp.vz) == (10.0, -5.0, -20.0, 3.0, 4.0, -1.0)
    time.sleep(0.5)  # a stalled client: the re-sent setpoint keeps the position, loses the velocity
    sp = ap.of_type("SET_POSITION_TARGET_LOCAL_NED")[-1]
    assert sp.type_mask == vh.TYPE_MASK_POSITION_YAW
    assert (sp.x, sp.y, sp.z, sp.vx, sp.vy, sp.vz) == (10.0, -5.0, -20.0, 0.0, 0.0, 0.0)


def test_local_position_is_requested_at_the_steering_rate(fake, connect):
    ap = fake()
    connect(ap.port, telemetry_rate_hz=10.0, local_position_rate_hz=50.0)
    asks = {int(m.param1): m.param2 for m in ap.of_type("COMMAND_LONG")
            if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL}
    assert asks[mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED] == pytest.approx(1e6 / 50.0)
    assert asks[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == pytest.approx(1e6 / 10.0)


def test_ardupilot_guided_takeoff(fake, connect):
    ap = fake(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    v = connect(ap.port)
    assert v.autopilot is vh.Autopilot.ARDUPILOT
    v.wait_for(lambda t: t.has_local, 2.0, "local position")
    v.arm()
    v.takeoff(15.0)
    cmds = [m for m in ap.of_type("COMMAND_LONG")
            if m.command in (mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_NAV_TAKEOFF)]
    assert [(m.command, m.param2) for m in cmds][:1] == [(mavlink.MAV_CMD_DO_SET_MODE, 4.0)]  # GUIDED
    assert cmds[-1].command == mavlink.MAV_CMD_NAV_TAKEOFF and cmds[-1].param7 == 15.0
    assert not ap.of_type("SET_POSITION_TARGET_LOCAL_NED")  # nothing that would cut the takeoff short
    v.land()
    last_mode = [m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_DO_SET_MODE][-1]
    assert last_mode.param2 == 9  # LAND


def test_no_heartbeat_raises_connection_timeout(fake):
    ap = fake(send_heartbeat=False)
    start = time.monotonic()
    with pytest.raises(vh.ConnectionTimeout, match="within 0.5 s"):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.5)
    assert time.monotonic() - start < 2.0


def test_gcs_heartbeats_are_ignored(fake):
    ap = fake(mavlink.MAV_AUTOPILOT_INVALID, mav_type=mavlink.MAV_TYPE_GCS)
    with pytest.raises(vh.ConnectionTimeout):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{ap.port}", heartbeat_timeout_s=0.5)


def test_nothing_listening_raises_connection_timeout():
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]
    with pytest.raises(vh.ConnectionTimeout, match="refused"):
        vh.MavlinkVehicle(f"tcp:127.0.0.1:{port}", heartbeat_timeout_s=0.5)


def test_link_lost(fake, connect):
    ap = fake()
    v = connect(ap.port, link_timeout_s=0.3)
    v.check_link()
    ap.send_heartbeat = False
    time.sleep(0.5)
    assert not v.link_ok
    with pytest.raises(vh.LinkLost):
        v.check_link()
    with pytest.raises(vh.LinkLost):
        v.arm()


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


def test_heartbeat_generic_autopilot_reads_px4_modes():
    msg = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC,
                                                 mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6 << 16, 0))
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0)
    assert (t.autopilot, t.mode) == (vh.Autopilot.GENERIC, "OFFBOARD")


def test_on_ground_from_landed_state_or_altitude():
    assert vh.Telemetry(landed_state=vh.LandedState.ON_GROUND, relative_alt_m=30.0).on_ground
    assert not vh.Telemetry(landed_state=vh.LandedState.IN_AIR, relative_alt_m=0.0).on_ground
    assert vh.Telemetry(relative_alt_m=0.1, v_down_mps=0.0).on_ground


def test_a_stale_on_ground_state_is_not_trusted_while_climbing():
    # Just after takeoff the last EXTENDED_SYS_STATE can still say ON_GROUND while the vehicle climbs at 3 m/s.
    assert not vh.Telemetry(landed_state=vh.LandedState.ON_GROUND, relative_alt_m=4.0, v_down_mps=-3.0).on_ground
    assert not vh.Telemetry(relative_alt_m=5.0, v_down_mps=0.0).on_ground
    assert not vh.Telemetry().on_ground  # nothing known yet


def test_hold_uses_loiter_mode(fake, connect):
    ap = fake()
    v = connect(ap.port)
    v.hold()
    mode_cmd = [m for m in ap.of_type("COMMAND_LONG") if m.command == mavlink.MAV_CMD_DO_SET_MODE][-1]
    assert (mode_cmd.param2, mode_cmd.param3) == (4, 3)  # AUTO.LOITER


# ------------------------------------------------------------------------------ flights against sim/
@pytest.mark.flight
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_fly_against_sim(sim_start, autopilot):
    sim = sim_start(strict=True, autopilot=autopilot)
    with vh.MavlinkVehicle(f"tcp:127.0.0.1:{sim.port}", heartbeat_timeout_s=5.0) as v:
        assert v.autopilot is vh.Autopilot(autopilot)
        t = v.wait_for(lambda t: t.has_local and t.home is not None, 5.0, "position and home")
        assert t.on_ground and not t.armed
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
    assert all(c["result_name"] == "MAV_RESULT_ACCEPTED" for c in report["commands"])
