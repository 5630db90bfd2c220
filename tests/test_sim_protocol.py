"""What each personality streams, answers and encodes, against what the real autopilots did on a fresh link.

Oracles are the SITL measurements (ArduCopter V4.7.0-dev SITL, PX4 v1.15.4 SITL with SIH), typed here.
"""

from __future__ import annotations

import math
import statistics
import struct
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.conftest import wait_ready

M = mavlink
NAN = math.nan

#: Measured with PARAM_REQUEST_READ: name -> (value, MAV_PARAM_TYPE).
ARDUCOPTER_PARAMS = {
    "FS_GCS_ENABLE": (0, M.MAV_PARAM_TYPE_INT8), "FS_GCS_TIMEOUT": (5.0, M.MAV_PARAM_TYPE_REAL32),
    "GUID_TIMEOUT": (3.0, M.MAV_PARAM_TYPE_REAL32), "WPNAV_SPEED": (1000.0, M.MAV_PARAM_TYPE_REAL32),
    "WPNAV_ACCEL": (250.0, M.MAV_PARAM_TYPE_REAL32), "WPNAV_SPEED_UP": (250.0, M.MAV_PARAM_TYPE_REAL32),
    "WPNAV_SPEED_DN": (150.0, M.MAV_PARAM_TYPE_REAL32), "LAND_SPEED": (50, M.MAV_PARAM_TYPE_INT16),
    "DISARM_DELAY": (10, M.MAV_PARAM_TYPE_INT8), "PILOT_TKOFF_ALT": (0.0, M.MAV_PARAM_TYPE_REAL32),
    "RTL_ALT": (1500, M.MAV_PARAM_TYPE_INT32), "MAV_GCS_SYSID": (255, M.MAV_PARAM_TYPE_INT16),
    "ANGLE_MAX": (3000, M.MAV_PARAM_TYPE_INT16),
}
PX4_PARAMS = {
    "COM_OF_LOSS_T": (1.0, M.MAV_PARAM_TYPE_REAL32), "COM_OBL_RC_ACT": (0, M.MAV_PARAM_TYPE_INT32),
    "NAV_DLL_ACT": (0, M.MAV_PARAM_TYPE_INT32), "COM_DL_LOSS_T": (10, M.MAV_PARAM_TYPE_INT32),
    "COM_DISARM_PRFLT": (10.0, M.MAV_PARAM_TYPE_REAL32), "COM_DISARM_LAND": (2.0, M.MAV_PARAM_TYPE_REAL32),
    "MPC_XY_VEL_MAX": (12.0, M.MAV_PARAM_TYPE_REAL32), "MPC_ACC_HOR": (3.0, M.MAV_PARAM_TYPE_REAL32),
    "MPC_ACC_HOR_MAX": (5.0, M.MAV_PARAM_TYPE_REAL32),
    "MPC_Z_VEL_MAX_UP": (3.0, M.MAV_PARAM_TYPE_REAL32), "MPC_Z_VEL_MAX_DN": (1.5, M.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_SPEED": (0.7, M.MAV_PARAM_TYPE_REAL32), "MIS_TAKEOFF_ALT": (2.5, M.MAV_PARAM_TYPE_REAL32),
    "RTL_RETURN_ALT": (30.0, M.MAV_PARAM_TYPE_REAL32), "MPC_TILTMAX_AIR": (45.0, M.MAV_PARAM_TYPE_REAL32),
}
#: PX4's onboard (API) link streams these without being asked (those the sim builds), measured Hz.
PX4_ONBOARD_HZ = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 5.0, "EXTENDED_SYS_STATE": 5.0, "GPS_RAW_INT": 7.9, "GLOBAL_POSITION_INT": 49.5,
    "LOCAL_POSITION_NED": 29.7, "ATTITUDE_QUATERNION": 49.5, "VFR_HUD": 9.9, "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5, "SYSTEM_TIME": 1.0,
}


def _int32_bits(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def _read_param(c, name: str):
    since = c.mark()
    c.send(M.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
    return c.wait_for("PARAM_VALUE", lambda m: m.param_id == name, since=since)


@pytest.mark.parametrize("autopilot, table", [("ardupilot", ARDUCOPTER_PARAMS), ("px4", PX4_PARAMS)])
def test_parameter_names_defaults_and_types_are_the_real_ones(sim_start, sim_connect, autopilot, table):
    sim = sim_start(autopilot=autopilot)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    for name, (value, ptype) in table.items():
        pv = _read_param(c, name)
        assert pv.param_type == ptype, name
        if autopilot == "px4" and ptype == M.MAV_PARAM_TYPE_INT32:
            assert _int32_bits(pv.param_value) == value, name  # PX4 sends int32 bytewise
        else:
            assert pv.param_value == pytest.approx(value), name  # ArduPilot: the number as a float
        # ArduPilot answers a read by name with index 65535, PX4 with the parameter's index.
        assert (pv.param_index == 65535) == (autopilot == "ardupilot")
    since = c.mark()
    c.send(M.MAVLink_param_request_read_message(1, 1, b"", 0))
    by_index = c.wait_for("PARAM_VALUE", since=since)
    assert by_index.param_index == 0 and by_index.param_count == len(sim.autopilot.params.names)
    since = c.mark()
    c.send(M.MAVLink_param_request_read_message(1, 1, b"NOT_A_PARAM", -1))
    c.send(M.MAVLink_param_set_message(1, 1, b"NOT_A_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32))
    time.sleep(0.2)
    assert c.of_type("PARAM_VALUE", since) == []  # silence, as both
    assert not any("NOT_A_PARAM" in m.text for m in c.of_type("STATUSTEXT", since))


@pytest.mark.parametrize("autopilot, capabilities", [("px4", 0xE8FF), ("ardupilot", 0xFBEF)])
def test_autopilot_version_capabilities_are_the_measured_ones(sim_start, sim_connect, autopilot, capabilities):
    # measured on PX4 1.15.4 and ArduCopter 4.7.0-dev SITL: only PX4 says PARAM_ENCODE_BYTEWISE, which is how a
    # client knows to read its INT32 parameters' bits instead of their float value
    sim = sim_start(autopilot=autopilot)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == M.MAV_RESULT_ACCEPTED
    version = c.wait_for("AUTOPILOT_VERSION", since=since)
    assert version.capabilities == capabilities
    bytewise = bool(version.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    assert bytewise == (autopilot == "px4")


def test_px4_int32_param_set_is_bytewise_and_changes_behaviour(sim_start, sim_connect):
    sim = sim_start(strict=True, speedup=5.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wire = struct.unpack("<f", struct.pack("<i", 5))[0]
    since = c.mark()
    c.send(M.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT", wire, M.MAV_PARAM_TYPE_INT32))
    echo = c.wait_for("PARAM_VALUE", lambda m: m.param_id == "COM_OBL_RC_ACT", since=since)
    assert _int32_bits(echo.param_value) == 5 and sim.autopilot.params["COM_OBL_RC_ACT"] == 5


def test_ardupilot_param_set_changes_behaviour(sim_start, sim_connect):
    """DISARM_DELAY = 3: armed on the ground, ArduCopter disarms after 3 s instead of 10 (simulated time)."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    c.send(M.MAVLink_param_set_message(1, 1, b"DISARM_DELAY", 3.0, M.MAV_PARAM_TYPE_INT8))
    echo = c.wait_for("PARAM_VALUE", lambda m: m.param_id == "DISARM_DELAY", since=since)
    assert (echo.param_value, echo.param_index) == (3.0, 65535)
    wait_ready(sim)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    sim.wait_until(lambda s: not s["armed"], 5)
    events = {e["kind"]: e["sim_time_s"] for e in sim.report()["events"] if e["kind"] in ("armed", "disarmed")}
    assert events["disarmed"] - events["armed"] == pytest.approx(3.0, abs=0.03)


def test_ardupilot_volunteers_only_heartbeats_until_asked(sim_start, sim_connect):
    """Fresh link, default SRx: HEARTBEAT at 1 Hz (simulated), plus home/origin once set and STATUSTEXT."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    time.sleep(0.5)  # 5 s simulated
    kinds = {m.get_type() for m in c.messages}
    assert kinds <= {"HEARTBEAT", "STATUSTEXT", "HOME_POSITION", "GPS_GLOBAL_ORIGIN"}, kinds
    heartbeats = c.of_type("HEARTBEAT")
    assert len(heartbeats) >= 5
    # REQUEST_DATA_STREAM POSITION at 2 Hz: GLOBAL_POSITION_INT and LOCAL_POSITION_NED, 2 Hz of simulated time.
    c.send(M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_POSITION, 2, 1))
    c.wait_for("LOCAL_POSITION_NED", timeout_s=2)
    since = c.mark()
    time.sleep(0.6)
    stamps = [m.time_boot_ms for m in c.of_type("GLOBAL_POSITION_INT", since)]
    gaps_ms = [b - a for a, b in zip(stamps, stamps[1:])]
    assert len(stamps) >= 5 and abs(statistics.median(gaps_ms) - 500) <= 21, stamps
    assert {m.get_type() for m in c.messages[since:]} >= {"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"}
    c.send(M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_POSITION, 0, 0))
    time.sleep(0.2)
    since = c.mark()
    time.sleep(0.4)
    assert c.of_type("GLOBAL_POSITION_INT", since) == []


def test_px4_streams_its_onboard_link_set_at_its_rates(sim_start, sim_connect):
    sim = sim_start(speedup=1.0, boot="instant")
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    time.sleep(0.3)
    since = c.mark()
    time.sleep(2.0)
    window_s = 2.0
    counts: dict = {}
    for m in c.messages[since:]:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    assert set(PX4_ONBOARD_HZ) <= set(counts) | {"HOME_POSITION", "BATTERY_STATUS"}  # 0.5 Hz: maybe 1 in 2 s
    for kind, hz in PX4_ONBOARD_HZ.items():
        if hz >= 5:
            assert counts[kind] / window_s == pytest.approx(hz, rel=0.3), kind  # wall time = simulated here


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_command_results_match_the_real_autopilot(sim_start, sim_connect, autopilot):
    sim = sim_start(autopilot=autopilot, strict=True)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    px4 = autopilot == "px4"
    mode_px4 = (1, 4, 3) if px4 else (1, 5)  # LOITER either way
    expected = [
        ((M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 10), M.MAV_RESULT_ACCEPTED if px4 else M.MAV_RESULT_FAILED),
        ((M.MAV_CMD_DO_SET_MODE, 1, *mode_px4[1:]), M.MAV_RESULT_ACCEPTED),
        ((M.MAV_CMD_DO_SET_MODE, 0, *mode_px4[1:]), M.MAV_RESULT_ACCEPTED if px4 else M.MAV_RESULT_DENIED),
        ((M.MAV_CMD_REQUEST_MESSAGE, 9999), M.MAV_RESULT_DENIED if px4 else M.MAV_RESULT_FAILED),
        ((M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000), M.MAV_RESULT_FAILED if px4 else M.MAV_RESULT_DENIED),
        ((M.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 37.7926, -122.3973, 5), M.MAV_RESULT_UNSUPPORTED),
        ((M.MAV_CMD_DO_CHANGE_SPEED, 1, 3, -1), M.MAV_RESULT_ACCEPTED),
        ((31999, 1), M.MAV_RESULT_UNSUPPORTED),
    ]
    for (command, *params), result in expected:
        ack = c.command(command, *params)
        assert ack.result == result, (command, params, ack.result)
        if command == M.MAV_CMD_NAV_TAKEOFF:  # PX4 takes NAV_TAKEOFF while disarmed as a mode change
            assert (sim.truth()["mode"] == "TAKEOFF") == px4 and not sim.truth()["armed"]


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_requested_messages_come_in_the_real_order_around_the_ack(sim_start, sim_connect, autopilot):
    """REQUEST_MESSAGE GPS_GLOBAL_ORIGIN: ArduCopter acks first, PX4 sends the message first (measured)."""
    sim = sim_start(autopilot=autopilot)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    since = c.mark()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN).result == M.MAV_RESULT_ACCEPTED
    origin = c.wait_for("GPS_GLOBAL_ORIGIN", since=since)
    assert (origin.latitude, origin.longitude) == (377924800, -1223974500)
    order = [m.get_type() for m in c.messages[since:] if m.get_type() in ("COMMAND_ACK", "GPS_GLOBAL_ORIGIN")]
    assert order[:2] == (["GPS_GLOBAL_ORIGIN", "COMMAND_ACK"] if autopilot == "px4"
                         else ["COMMAND_ACK", "GPS_GLOBAL_ORIGIN"])


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_set_mode_message_ack_ping_and_timesync(sim_start, sim_connect, autopilot):
    sim = sim_start(autopilot=autopilot)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    custom = (4 << 16) | (3 << 24) if autopilot == "px4" else 5  # LOITER
    since = c.mark()
    c.send(M.MAVLink_set_mode_message(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom))
    c.send(M.MAVLink_ping_message(42, 9, 0, 0))
    c.send(M.MAVLink_timesync_message(0, 777))
    sync = c.wait_for("TIMESYNC", lambda m: m.ts1 == 777, since=since)
    assert sync.tc1 == pytest.approx(sim.truth()["sim_time_s"] * 1e9, abs=2e9)  # the autopilot's boot time, ns
    time.sleep(0.2)
    acks = c.of_type("COMMAND_ACK", since)
    pings = [m for m in c.of_type("PING", since) if m.seq == 9]
    assert sim.truth()["mode"] == "LOITER"
    if autopilot == "px4":  # PX4 acks SET_MODE as the DO_SET_MODE it becomes, and answers pings
        assert [a.command for a in acks] == [M.MAV_CMD_DO_SET_MODE] and len(pings) == 1
    else:  # ArduCopter 4.7: neither
        assert acks == [] and pings == []
