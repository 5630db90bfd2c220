"""Protocol tests against the sim with a raw MAVLink 2 client (tests/conftest.py SimClient)."""

from __future__ import annotations

import contextlib
import math
import threading
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

M = mavlink
PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD, PX4_SUB_LOITER = 4, 6, 3


def px4_mode_name(hb) -> str:
    return mavutil.interpret_px4_mode(hb.base_mode, hb.custom_mode)


@contextlib.contextmanager
def streaming(client, target, hz: float = 20.0):
    """Send ``target()`` -> (n, e, z) as LOCAL_NED position setpoints at ``hz`` (wall clock)."""
    stop = threading.Event()

    def run():
        while not stop.is_set():
            client.setpoint_local(*target())
            stop.wait(1.0 / hz)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(2)


def test_identity_first_messages_and_ground_truth(sim_start, sim_connect):
    sim = sim_start()
    c = sim_connect(sim.port)
    hb = c.wait_for("HEARTBEAT", timeout_s=3)
    first = [m.get_type() for m in c.messages[: c.messages.index(hb)]]
    assert {"HOME_POSITION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"} <= set(first)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.get_msgbuf()[0] == 0xFD  # MAVLink 2 framing
    assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert px4_mode_name(hb) == "LOITER"
    assert (hb.custom_mode >> 16) & 0xFF == PX4_MAIN_AUTO and (hb.custom_mode >> 24) == PX4_SUB_LOITER
    lpn = c.wait_for("LOCAL_POSITION_NED")
    assert (lpn.x, lpn.y, lpn.z) == (0.0, 0.0, 0.0)
    gpi = c.wait_for("GLOBAL_POSITION_INT")
    home = c.wait_for("HOME_POSITION")
    assert gpi.alt == home.altitude == 0 and gpi.relative_alt == 0
    assert (gpi.lat, gpi.lon) == (home.latitude, home.longitude) == (377924800, -1223974500)
    ss = c.wait_for("SYS_STATUS")
    for bit in (M.MAV_SYS_STATUS_SENSOR_GPS, M.MAV_SYS_STATUS_PREARM_CHECK, M.MAV_SYS_STATUS_SENSOR_3D_GYRO):
        assert ss.onboard_control_sensors_present & bit and ss.onboard_control_sensors_health & bit
    for kind in ("ATTITUDE", "GPS_RAW_INT", "EXTENDED_SYS_STATE"):
        c.wait_for(kind)
    assert c.wait_for("EXTENDED_SYS_STATE").landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert c.wait_for("GPS_RAW_INT").fix_type >= M.GPS_FIX_TYPE_3D_FIX


def test_every_command_acked_and_unknown_unsupported(sim_start, sim_connect):
    sim = sim_start()
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    expected = {
        M.MAV_CMD_REQUEST_MESSAGE: ((M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,), M.MAV_RESULT_ACCEPTED),
        M.MAV_CMD_NAV_TAKEOFF: ((0, 0, 0, math.nan, math.nan, math.nan, math.nan), M.MAV_RESULT_DENIED),
        M.MAV_CMD_DO_SET_HOME: ((0, 0, 0, 0, 0.0, 0.0, 0.0), M.MAV_RESULT_DENIED),
        M.MAV_CMD_NAV_LOITER_TIME: ((10,), M.MAV_RESULT_UNSUPPORTED),
        31999: ((1, 2, 3), M.MAV_RESULT_UNSUPPORTED),
        M.MAV_CMD_DO_SET_MODE: ((1, 4, 4), M.MAV_RESULT_DENIED),  # AUTO.MISSION: no mission support
    }
    since = c.mark()
    for command, (params, result) in expected.items():
        ack = c.command(command, *params)
        assert ack.result == result, (command, ack.result)
        assert (ack.target_system, ack.target_component) == (255, 190)
    # Denials carry a reason in STATUSTEXT.
    texts = [m.text for m in c.of_type("STATUSTEXT", since)]
    assert any("not armed" in t for t in texts) and any("0,0" in t for t in texts)
    c.wait_for("AUTOPILOT_VERSION", since=since)
    # COMMAND_INT is acked too.
    since = c.mark()
    c.send(M.MAVLink_command_int_message(1, 1, 0, 4242, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert c.wait_for("COMMAND_ACK", lambda m: m.command == 4242, since=since).result == M.MAV_RESULT_UNSUPPORTED
    logged = {(e["command"], e["result"]) for e in sim.report()["commands"]}
    for command, (_p, result) in expected.items():
        assert (command, result) in logged
    assert (4242, M.MAV_RESULT_UNSUPPORTED) in logged


def test_params_ping_intervals(sim_start, sim_connect):
    sim = sim_start(speedup=1.0)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    c.send(M.MAVLink_param_request_list_message(1, 1))
    values = {c.wait_for("PARAM_VALUE", lambda m, name=name: m.param_id == name, since=since).param_id
              for name in ("MIS_TAKEOFF_ALT", "RTL_RETURN_ALT", "COM_OF_LOSS_T")}
    assert len(values) == 3
    since = c.mark()
    c.send(M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 7.5, M.MAV_PARAM_TYPE_REAL32))
    assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MIS_TAKEOFF_ALT", since=since).param_value == 7.5
    since = c.mark()
    c.send(M.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    assert c.wait_for("PARAM_VALUE", since=since).param_value == 7.5
    since = c.mark()
    c.send(M.MAVLink_ping_message(123456, 7, 0, 0))
    pong = c.wait_for("PING", since=since)
    assert (pong.seq, pong.time_usec, pong.target_system, pong.target_component) == (7, 123456, 255, 190)
    # SET_MESSAGE_INTERVAL: GPS_RAW_INT at 20 Hz wall clock, then off.
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GPS_RAW_INT, 50_000).result == 0
    time.sleep(0.05)
    since = c.mark()
    time.sleep(0.5)
    assert 6 <= len(c.of_type("GPS_RAW_INT", since)) <= 14
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GPS_RAW_INT, -1).result == 0
    time.sleep(0.05)
    since = c.mark()
    time.sleep(0.6)
    assert c.of_type("GPS_RAW_INT", since) == []
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result == 0
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000).result == M.MAV_RESULT_UNSUPPORTED


def test_set_home_moves_local_origin(sim_start, sim_connect):
    sim = sim_start(origin="home")
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    # 0.0001 deg of latitude north of the map origin is ~11.1 m; the vehicle is at the origin.
    since = c.mark()
    ack = c.command(M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 37.792580, -122.397450, 0.0)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    home = c.wait_for("HOME_POSITION", since=since)
    assert abs(home.latitude - 377925800) <= 40  # COMMAND_LONG params are float32 (~4e-6 deg here)
    lpn = c.wait_for("LOCAL_POSITION_NED", since=c.mark())
    assert lpn.x == pytest.approx(-11.1, abs=0.1) and lpn.z == 0.0


@pytest.mark.parametrize("origin", ["home", "boot"])
def test_start_position_and_origin(sim_start, sim_connect, origin):
    # Start 20 m east of the map origin (~0.000227 deg of longitude at 37.79 N).
    sim = sim_start(start=(37.792480, -122.397223), origin=origin)
    c = sim_connect(sim.port)
    lpn = c.wait_for("LOCAL_POSITION_NED")
    home = c.wait_for("HOME_POSITION")
    assert home.latitude == 377924800 and home.longitude == -1223974500  # home stays at lat0/lon0
    if origin == "home":
        assert lpn.y == pytest.approx(20.0, abs=0.1) and lpn.x == pytest.approx(0.0, abs=0.01)
    else:
        assert (lpn.x, lpn.y, lpn.z) == (0.0, 0.0, 0.0)
        assert home.y == pytest.approx(-20.0, abs=0.1)


@pytest.mark.flight
def test_classic_udacidrone_dialect(sim_start, sim_connect):
    """The udacidrone PX4=False sequence: offboard + arm before any setpoint, z as positive altitude."""
    sim = sim_start(speedup=20.0)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    assert c.command(M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 37.792480, -122.397450, 0).result == 0
    assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == M.MAV_RESULT_ACCEPTED  # take_control()
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    hb = c.wait_for("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, since=c.mark())
    assert (hb.custom_mode >> 16) & 0xF == 6  # udacidrone's "guided" test
    takeoff_mask = 0x1000 | 0x800 | 0x400 | 0x1C0 | 0x038
    c.setpoint_local(0.0, 0.0, 5.0, type_mask=takeoff_mask)  # takeoff(n, e, altitude)
    sim.wait_until(lambda s: s["position"]["up_m"] > 4.9, 10)
    c.setpoint_local(10.0, 0.0, 5.0, type_mask=0x800 | 0x1C0 | 0x038)  # cmd_position(n, e, altitude, heading)
    state = sim.wait_until(lambda s: abs(s["position"]["north_m"] - 10) < 0.05, 10)
    assert state["position"]["up_m"] == pytest.approx(5.0, abs=0.05)
    lpn = c.wait_for("LOCAL_POSITION_NED", since=c.mark())
    assert lpn.z == pytest.approx(-5.0, abs=0.05)  # telemetry stays NED
    c.setpoint_local(10.0, 0.0, 0.0, type_mask=0x2000 | 0x800 | 0x400 | 0x1C0 | 0x038)  # land(n, e)
    sim.wait_until(lambda s: s["on_ground"], 20)
    lpn = c.wait_for("LOCAL_POSITION_NED", since=c.mark())
    assert lpn.z == 0.0  # the classic landed test needs exactly 0
    gpi = c.wait_for("GLOBAL_POSITION_INT", since=c.mark())
    assert gpi.alt == 0 and gpi.relative_alt == 0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == M.MAV_RESULT_ACCEPTED
    assert c.set_mode_px4(1).result == M.MAV_RESULT_ACCEPTED  # release_control(): MANUAL
    report = sim.report()
    assert not report["collisions"] and report["landed"]["north_m"] == pytest.approx(10.0, abs=0.1)
    assert any(e["kind"] == "dialect" for e in report["events"])


def test_strict_refuses_offboard_without_stream_and_ignores_classic_bits(sim_start, sim_connect):
    sim = sim_start(strict=True, speedup=20.0)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == M.MAV_RESULT_DENIED
    assert any("setpoint" in m.text for m in c.of_type("STATUSTEXT", since))
    with streaming(c, lambda: (0.0, 0.0, 5.0)):  # classic-style positive z: NED 5 m *below* ground
        time.sleep(0.1)
        assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == M.MAV_RESULT_ACCEPTED
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        time.sleep(0.3)
        assert sim.truth()["on_ground"]  # a positive z never lifts off in strict mode
        c.setpoint_local(0.0, 0.0, 5.0, type_mask=0x1000 | 0xDF8)
        time.sleep(0.2)
        assert sim.truth()["on_ground"]
    texts = [m.text for m in c.of_type("STATUSTEXT")]
    assert any("0x1000" in t for t in texts)


@pytest.mark.flight
def test_strict_offboard_loss_falls_back_to_hold(sim_start, sim_connect):
    sim = sim_start(strict=True, speedup=20.0)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    with streaming(c, lambda: (0.0, 0.0, -5.0)):
        time.sleep(0.1)
        assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == 0
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        sim.wait_until(lambda s: s["position"]["up_m"] > 4.5, 10)
        since = c.mark()
    t_stop = time.monotonic()
    state = sim.wait_until(lambda s: s["mode"] == "LOITER", 3)
    elapsed = time.monotonic() - t_stop
    assert 0.4 < elapsed < 1.5  # COM_OF_LOSS_T = 0.5 s wall clock
    assert not state["on_ground"] and state["armed"]
    assert any("offboard" in m.text for m in c.of_type("STATUSTEXT", since))


def _offboard_takeoff(c, sim, altitude_m: float = 5.0) -> None:
    c.setpoint_local(0.0, 0.0, -altitude_m)
    assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == 0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    sim.wait_until(lambda s: abs(s["position"]["up_m"] - altitude_m) < 0.05, 10)


@pytest.mark.flight
def test_flying_through_a_building_is_a_collision(sim_start, sim_connect):
    sim = sim_start(speedup=20.0)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    _offboard_takeoff(c, sim)
    since = c.mark()
    c.setpoint_local(60.0, 0.0, -5.0)
    state = sim.wait_until(lambda s: s["crashed"], 10)
    assert not state["armed"] and state["on_ground"]
    crit = c.wait_for("STATUSTEXT", lambda m: m.severity == M.MAV_SEVERITY_CRITICAL, since=since)
    assert "COLLISION" in crit.text
    report = sim.report()
    assert report["crashed"] and len(report["collisions"]) == 1
    hit = report["collisions"][0]
    # Wall at north 25 m, sphere radius 0.3 m: contact when the position passes north 24.7 m.
    assert 24.69 <= hit["north_m"] <= 24.95 and hit["up_m"] == pytest.approx(5.0, abs=0.1)
    assert hit["box"]["north_m"] == 30.0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED


@pytest.mark.flight
def test_flying_around_a_building_reports_clearance(sim_start, sim_connect, tmp_path):
    sim = sim_start(speedup=20.0, report_path=tmp_path / "report.json")
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    _offboard_takeoff(c, sim)
    c.setpoint_local(0.0, 15.0, -5.0)
    sim.wait_until(lambda s: abs(s["position"]["east_m"] - 15.0) < 0.02, 10)
    c.setpoint_local(60.0, 15.0, -5.0)
    sim.wait_until(lambda s: abs(s["position"]["north_m"] - 60.0) < 0.05, 15)
    assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan).result == 0
    sim.wait_until(lambda s: not s["armed"], 20)
    report = sim.report()
    assert report["collisions"] == [] and not report["crashed"]
    # Path at east 15 m, building's east face at 5 m, sphere radius 0.3 m -> 9.7 m.
    assert 9.5 <= report["min_clearance_m"] <= 9.7 + 0.02  # + the 0.02 m waypoint tolerance above
    assert report["landed"]["north_m"] == pytest.approx(60.0, abs=0.1)
    assert report["max_altitude_m"] == pytest.approx(5.0, abs=0.1)
    assert report["distance_flown_m"] == pytest.approx(5 + 15 + 60 + 5, abs=1.5)
    assert report["armed_time_s"] > 0


@pytest.mark.flight
def test_ardupilot_personality(sim_start, sim_connect):
    sim = sim_start(autopilot="ardupilot", speedup=20.0)
    c = sim_connect(sim.port)
    hb = c.wait_for("HEARTBEAT")
    assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == M.MAV_TYPE_QUADROTOR
    acm = {v: k for k, v in mavutil.mode_mapping_acm.items()}
    assert hb.custom_mode == acm["STABILIZE"]
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10).result == M.MAV_RESULT_DENIED  # not GUIDED
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, acm["GUIDED"]).result == 0
    c.wait_for("HEARTBEAT", lambda m: m.custom_mode == acm["GUIDED"], since=c.mark())
    c.setpoint_local(10.0, 0.0, -10.0)  # ignored on the ground, as ArduCopter does
    time.sleep(0.2)
    assert sim.truth()["on_ground"]
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10).result == 0  # param7 relative (m)
    sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.1, 10)
    c.setpoint_local(10.0, 0.0, -10.0)
    sim.wait_until(lambda s: abs(s["position"]["north_m"] - 10) < 0.05, 10)
    since = c.mark()
    c.send(M.MAVLink_set_mode_message(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, acm["LAND"]))
    assert c.wait_for("COMMAND_ACK", lambda m: m.command == M.MAVLINK_MSG_ID_SET_MODE, since=since).result == 0
    c.wait_for("HEARTBEAT", lambda m: m.custom_mode == acm["LAND"], since=since)
    sim.wait_until(lambda s: s["on_ground"] and not s["armed"], 30)
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, acm["AUTO"]).result == M.MAV_RESULT_DENIED
    assert sim.report()["landed"]["north_m"] == pytest.approx(10.0, abs=0.1)


def test_tlog_is_readable_by_pymavlink(sim_start, sim_connect, tmp_path):
    path = tmp_path / "flight.tlog"
    sim = sim_start(tlog_path=path)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    time.sleep(1.1)
    sim.stop()
    log = mavutil.mavlink_connection(str(path))
    kinds = {}
    while True:
        m = log.recv_match()
        if m is None:
            break
        kinds[m.get_type()] = kinds.get(m.get_type(), 0) + 1
        assert 0 < m._timestamp - time.time() + 60 < 120
    assert kinds.get("HEARTBEAT", 0) >= 1 and kinds.get("GLOBAL_POSITION_INT", 0) >= 5
    assert kinds.get("COMMAND_ACK", 0) >= 1 and kinds.get("COMMAND_LONG", 0) >= 1
