"""Auto-disarm, repeated missions, home at arming, GUIDED's timeout and link-loss failsafes, against SITL.

The numbers the tests expect were measured on ArduCopter V4.7.0-dev SITL and PX4 v1.15.4 SITL (SIH) and are
typed here as the oracle; all in simulated seconds.
"""

from __future__ import annotations

import contextlib
import math
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from tests.conftest import wait_ready, wait_sim
from tests.test_sim_mavlink import streaming

M = mavlink
NAN = math.nan
ACM = {v: k for k, v in mavutil.mode_mapping_acm.items()}
PX4_OFFBOARD, PX4_AUTO, PX4_LOITER = 6, 4, 3


def _guided_takeoff(sim, c, up_m: float) -> None:
    """ArduCopter: wait until ready, select GUIDED, arm, and take off to ``up_m`` (not waiting for it)."""
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, up_m).result == 0


@contextlib.contextmanager
def _px4_offboard_until_failsafe(sim, c):
    """PX4: wait until ready, stream a hover setpoint 5 m up at 50 Hz, take OFFBOARD, arm, and wait for "Failsafe
    activated"; the stream goes on inside the block."""
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    with streaming(c, lambda: (0.0, 0.0, -5.0), hz=50.0):
        time.sleep(0.1)
        assert c.set_mode_px4(PX4_OFFBOARD).result == 0
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        c.wait_for("STATUSTEXT", lambda m: m.text == "Failsafe activated\t", timeout_s=10)
        yield


def _event_time(sim, kind: str, fragment: str = "") -> float:
    return [e["sim_time_s"] for e in sim.report()["events"] if e["kind"] == kind and fragment in e["text"]][-1]


@pytest.mark.parametrize("autopilot, text", [("ardupilot", "Disarming motors"),
                                             ("px4", "Disarmed by auto preflight disarming\t")])
def test_armed_on_the_ground_without_takeoff_disarms_after_10_s(sim_start, sim_connect, autopilot, text):
    """DISARM_DELAY (ArduCopter) and COM_DISARM_PRFLT (PX4) both default to 10 s: SITL disarmed at 10 s."""
    sim = sim_start(autopilot=autopilot, speedup=10.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    if autopilot == "ardupilot":
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0  # arms without setpoints
    since = c.mark()
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    sim.wait_until(lambda s: not s["armed"], 5)
    held = _event_time(sim, "disarmed") - _event_time(sim, "armed")
    assert held == pytest.approx(10.0, abs=0.03)
    c.wait_for("STATUSTEXT", lambda m: m.text == text, since=since)


@pytest.mark.flight
def test_ardupilot_flies_three_missions_on_one_running_sim(sim_start, sim_connect):
    """After a landing in LAND, arming is refused ("Arm: LAND mode not armable", FAILED) until the client
    selects GUIDED; then the next mission flies. Home moves to where the vehicle arms; the EKF origin stays."""
    sim = sim_start(autopilot="ardupilot", speedup=20.0, origin="boot")
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    for mission in range(3):  # east along the map, clear of its one building
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0
        since = c.mark()
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        home = c.wait_for("HOME_POSITION", since=since)  # ArduCopter sends home when it moves
        assert home.y == pytest.approx(20.0 * mission, abs=0.2)  # where it armed, in the EKF's frame
        assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 5).result == 0
        sim.wait_until(lambda s: s["position"]["up_m"] > 4.9, 10)
        c.setpoint_local(0.0, 20.0 * (mission + 1), -5.0)
        sim.wait_until(lambda s, m=mission: abs(s["position"]["east_m"] - 20.0 * (m + 1)) < 0.1
                       and math.hypot(*s["velocity_neu_m_s"][:2]) < 0.2, 15)  # there and stopped, not overshooting
        assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, 0, 0, 0).result == 0
        sim.wait_until(lambda s: not s["armed"], 20)
        since = c.mark()
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_FAILED
        refusals = [m.text for m in c.of_type("STATUSTEXT", since) if m.text.startswith("Arm")]
        assert refusals == ["Arm: LAND mode not armable"]
    since = c.mark()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN).result == 0
    origin = c.wait_for("GPS_GLOBAL_ORIGIN", since=since)
    assert (origin.latitude, origin.longitude) == (377924800, -1223974500)  # still where it booted
    assert [round(entry["east_m"]) for entry in sim.report()["landings"]] == [20, 40, 60]


@pytest.mark.flight
def test_px4_flies_three_offboard_missions_on_one_running_sim(sim_start, sim_connect):
    """After NAV_LAND and "Disarmed by landing" PX4 is back in OFFBOARD (the user's last mode); arming there needs
    the setpoint stream first, then each mission flies. Landing: ON_GROUND ~1 s after touchdown, disarm 2 s later.
    (Local frame at the EKF origin, as the real PX4's: with ``origin="home"`` it would move with home at arming.)"""
    sim = sim_start(strict=True, speedup=10.0, origin="boot")
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    target = [0.0, 0.0, -5.0]
    for mission in range(3):
        since = c.mark()
        with streaming(c, lambda: tuple(target), hz=50.0):  # 5 Hz of simulated time
            time.sleep(0.1)
            assert c.set_mode_px4(PX4_OFFBOARD).result == 0
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
            target[:] = [0.0, 20.0 * mission, -5.0]
            sim.wait_until(lambda s: s["position"]["up_m"] > 4.9, 10)
            target[:] = [0.0, 20.0 * (mission + 1), -5.0]
            sim.wait_until(lambda s, m=mission: abs(s["position"]["east_m"] - 20.0 * (m + 1)) < 0.1, 15)
            assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
            state = sim.wait_until(lambda s: not s["armed"], 30)
        assert state["mode"] == "OFFBOARD"
        landed = sim.report()["landings"][-1]["sim_time_s"]
        detected = _event_time(sim, "disarmed") - 2.0  # COM_DISARM_LAND after the land detector
        assert detected - landed == pytest.approx(1.0, abs=0.05)
        for text in ("Landing at current position\t", "Landing detected\t", "Disarmed by landing\t"):
            c.wait_for("STATUSTEXT", lambda m, t=text: m.text == t, since=since)  # may trail the sim's state
        since = c.mark()
        wait_sim(sim, 2.0)  # without setpoints
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_TEMPORARILY_REJECTED
        target[:] = [0.0, 20.0 * (mission + 1), -5.0]
    assert len(sim.report()["landings"]) == 3 and not sim.report()["collisions"]


@pytest.mark.flight
def test_landed_state_sequences(sim_start, sim_connect):
    """PX4 (NAV_TAKEOFF, then NAV_LAND): ON_GROUND, TAKEOFF while climbing, IN_AIR, LANDING, ON_GROUND."""
    sim = sim_start(speedup=5.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
    sim.wait_until(lambda s: s["mode"] == "LOITER" and not s["on_ground"], 10)  # takeoff done: Hold
    wait_sim(sim, 1.5)  # in the air
    assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
    sim.wait_until(lambda s: not s["armed"], 20)
    states = [m.landed_state for m in c.of_type("EXTENDED_SYS_STATE")]
    sequence = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert sequence == [M.MAV_LANDED_STATE_ON_GROUND, M.MAV_LANDED_STATE_TAKEOFF, M.MAV_LANDED_STATE_IN_AIR,
                        M.MAV_LANDED_STATE_LANDING, M.MAV_LANDED_STATE_ON_GROUND]
    assert any(m.text == "Using default takeoff altitude: 2.5 m\t" for m in c.of_type("STATUSTEXT"))


@pytest.mark.flight
@pytest.mark.parametrize("velocity_only", [False, True])
def test_ardupilot_guided_target_moves_on_for_guid_timeout_then_stops(sim_start, sim_connect, velocity_only):
    """SITL: a target 10 m ahead with 2 m/s feed-forward, then no more setpoints, ended 16 m out: the target
    moves along the velocity for GUID_TIMEOUT (3 s). A velocity-only target: 2 m/s for 3 s, then a stop."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0)
    c = sim_connect(sim)
    _guided_takeoff(sim, c, 10.0)
    state = sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.05, 15)
    north0 = state["position"]["north_m"]
    if velocity_only:
        mask = 0b0000_1101_1100_0111  # velocity only, yaw ignored
        x = 0.0
    else:
        mask = 0b0000_1101_1100_0000  # position + velocity
        x = north0 + 10.0
    c.send(M.MAVLink_set_position_target_local_ned_message(0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask, x, 0.0, -10.0,
                                                           2.0, 0.0, 0.0, 0, 0, 0, 0, 0))
    wait_sim(sim, 20.0)  # long after the timeout
    moved = sim.truth()["position"]["north_m"] - north0
    speed = math.hypot(*sim.truth()["velocity_neu_m_s"][:2])
    assert moved == pytest.approx(6.0 if velocity_only else 16.0, abs=0.6 if velocity_only else 0.3)
    assert speed < 0.05  # stopped


@pytest.mark.flight
@pytest.mark.parametrize("fs_gcs_enable, mode", [(0, "GUIDED"), (1, "RTL"), (5, "LAND")])
def test_ardupilot_gcs_heartbeat_loss(sim_start, sim_connect, fs_gcs_enable, mode):
    """FS_GCS_ENABLE 0 (default): SITL stayed GUIDED and armed; enabled: "GCS Failsafe" after FS_GCS_TIMEOUT."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0, params={"FS_GCS_ENABLE": fs_gcs_enable})
    c = sim_connect(sim)  # heartbeats at 1 Hz simulated, from system 255
    _guided_takeoff(sim, c, 10.0)
    sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.1, 15)
    since = c.mark()
    c.stop_heartbeats()
    wait_sim(sim, 10.0)
    state = sim.truth()
    assert state["mode"] == mode and state["armed"]
    texts = [m.text for m in c.of_type("STATUSTEXT", since)]
    if fs_gcs_enable:
        assert "GCS Failsafe" in texts
        last_heartbeat = sim.report()["last_gcs_heartbeat_sim_time_s"]
        assert _event_time(sim, "failsafe") - last_heartbeat == pytest.approx(5.0, abs=0.021)  # FS_GCS_TIMEOUT
        c.start_heartbeats(10.0)
        c.wait_for("STATUSTEXT", lambda m: m.text == "GCS Failsafe Cleared", since=since)
        assert sim.truth()["mode"] == mode  # the mode stays
    else:
        assert "GCS Failsafe" not in texts


@pytest.mark.flight
@pytest.mark.parametrize("batt_fs_low_act, mode", [(0, "GUIDED"), (2, "RTL"), (1, "LAND")])
def test_ardupilot_low_battery_warns_then_takes_batt_fs_low_act_once_airborne(sim_start, sim_connect,
                                                                              batt_fs_low_act, mode):
    """SITL with BATT_FS_LOW_ACT 2: "Battery 1 is low 10.00V used 177 mAh", "Battery Failsafe", RTL; 0 (the
    default) only warns. The battery reads low from 3 s on, the vehicle may not be flying yet: the failsafe waits
    for it to fly."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0, params={"BATT_FS_LOW_ACT": batt_fs_low_act},
                    faults={"battery_low_s": 3.0})
    c = sim_connect(sim)
    _guided_takeoff(sim, c, 10.0)
    if batt_fs_low_act:
        c.wait_for("STATUSTEXT", lambda m: m.text == "Battery Failsafe", timeout_s=5)
    else:
        sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.1, 15)
        assert "Battery Failsafe" not in [m.text for m in c.of_type("STATUSTEXT")]
    c.wait_for("STATUSTEXT", lambda m: m.text == "Battery 1 is low 10.00V used 177 mAh", timeout_s=5)
    assert [m.text for m in c.of_type("STATUSTEXT")].count("Battery 1 is low 10.00V used 177 mAh") == 1
    assert sim.truth()["mode"] == mode
    assert len([e for e in sim.report()["events"] if e["kind"] == "failsafe" and "battery low" in e["text"]]) == 1


def test_px4_low_battery_warns_and_stays_in_offboard(sim_start, sim_connect):
    """PX4 1.15 SITL, COM_LOW_BAT_ACT 3, battery drained in OFFBOARD flight: "Low battery level", "Failsafe
    activated", and it flew on in OFFBOARD (at the low level PX4 only warns)."""
    sim = sim_start(speedup=10.0, strict=True, faults={"battery_low_s": 3.0}, params={"COM_LOW_BAT_ACT": 3})
    c = sim_connect(sim)
    with _px4_offboard_until_failsafe(sim, c):
        assert "Low battery level\t" in [m.text for m in c.of_type("STATUSTEXT")]
        wait_sim(sim, 2.0)
        assert sim.truth()["mode"] == "OFFBOARD" and sim.truth()["armed"]


@pytest.mark.flight
def test_ardupilot_fence_breach_announces_and_returns_then_clears(sim_start, sim_connect):
    """SITL, FENCE_ENABLE 1, FENCE_ACTION 1: "Circle fence breached" (NOTICE) and RTL at once; "Fence breach
    cleared" once back inside, the mode staying RTL. Here the altitude fence, the same way."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0, params={"FENCE_ENABLE": 1, "FENCE_ALT_MAX": 6})
    c = sim_connect(sim)
    _guided_takeoff(sim, c, 10.0)
    breach = c.wait_for("STATUSTEXT", lambda m: m.text == "Altitude fence breached", timeout_s=10)
    assert breach.severity == M.MAV_SEVERITY_NOTICE
    sim.wait_until(lambda s: s["mode"] == "RTL", 2)
    assert len([e for e in sim.report()["events"] if e["kind"] == "failsafe"]) == 1  # once, until cleared


def test_px4_geofence_breach_in_offboard_only_announces(sim_start, sim_connect):
    """PX4 1.15 SITL, GF_MAX_HOR_DIST 60, GF_ACTION 3, flying out in OFFBOARD: "Failsafe activated", and it stayed
    in OFFBOARD (measured). Outside OFFBOARD it takes GF_ACTION: here the takeoff mode, vertically."""
    sim = sim_start(speedup=10.0, params={"GF_MAX_VER_DIST": 2, "GF_ACTION": 3})
    c = sim_connect(sim)
    c.start_heartbeats(10.0)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    since = c.mark()
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
    c.wait_for("STATUSTEXT", lambda m: m.text == "Failsafe activated\t", since=since, timeout_s=5)
    sim.wait_until(lambda s: s["mode"] == "RTL", 2)


def test_px4_datalink_loss_announces_and_takes_nav_dll_act(sim_start, sim_connect):
    sim = sim_start(speedup=10.0, params={"NAV_DLL_ACT": 2})
    c = sim_connect(sim)
    c.start_heartbeats(10.0)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN).result == 0
    sim.wait_until(lambda s: s["mode"] == "LOITER" and not s["on_ground"], 10)
    since = c.mark()
    c.stop_heartbeats()
    c.wait_for("STATUSTEXT", lambda m: m.text == "Connection to ground station lost\t", since=since, timeout_s=3)
    assert sim.truth()["mode"] == "RTL"
    c.start_heartbeats(10.0)
    c.wait_for("STATUSTEXT", lambda m: m.text == "GCS connection regained\t", since=since, timeout_s=3)


def test_scaled_timeouts_follow_px4s_sitl_convention(sim_start, sim_connect):
    """scale_timeouts: link-loss timeouts x speedup, as PX4's rcS does with PX4_SIM_SPEED_FACTOR (read back)."""
    sim = sim_start(speedup=8.0, scale_timeouts=True)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    c.send(M.MAVLink_param_request_read_message(1, 1, b"COM_OF_LOSS_T", -1))
    assert c.wait_for("PARAM_VALUE", since=since).param_value == 8.0
    assert sim.autopilot.params["COM_DL_LOSS_T"] == 80 and sim.autopilot.params["MPC_XY_VEL_MAX"] == 12.0


def _step_response(sim, c, autopilot: str) -> tuple[float, float]:
    """Peak horizontal acceleration (m/s^2, over 0.25 s) and speed of a 40 m position step at 10 m."""
    state = sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.05, 15)
    north0 = state["position"]["north_m"]
    samples = []
    c.setpoint_local(north0 + 40.0, 0.0, -10.0)
    end = time.monotonic() + 12.0 / sim.config.speedup
    while time.monotonic() < end:
        if autopilot == "px4":
            c.setpoint_local(north0 + 40.0, 0.0, -10.0)
        s = sim.truth()
        samples.append((s["sim_time_s"], s["velocity_neu_m_s"][0]))
        time.sleep(0.01)
    accel = []
    j = 0
    for t0, v0 in samples:  # over 0.25 s windows, as measured on SITL
        while j < len(samples) and samples[j][0] < t0 + 0.25:
            j += 1
        if j < len(samples):
            accel.append((samples[j][1] - v0) / (samples[j][0] - t0))
    return max(accel), max(v for _, v in samples)


@pytest.mark.flight
@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_horizontal_acceleration_follows_the_measured_step_response(sim_start, sim_connect, autopilot):
    """SITL, 40 m position step at 10 m: ArduCopter GUIDED peaked at ~2.6 m/s^2 (WPNAV_ACCEL 2.5) and 7.7 m/s;
    PX4 OFFBOARD at ~5-7 m/s^2 (not MPC_ACC_HOR's 3) and ~9 m/s."""
    sim = sim_start(autopilot=autopilot, strict=True, speedup=5.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    if autopilot == "ardupilot":
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == 0
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 10).result == 0
        peak_accel, peak_speed = _step_response(sim, c, autopilot)
        assert peak_accel == pytest.approx(2.5, abs=0.3) and 7.0 <= peak_speed <= 10.0
    else:
        with streaming(c, lambda: (0.0, 0.0, -10.0), hz=20.0):
            time.sleep(0.1)
            assert c.set_mode_px4(PX4_OFFBOARD).result == 0
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            sim.wait_until(lambda s: abs(s["position"]["up_m"] - 10) < 0.05, 15)
        peak_accel, peak_speed = _step_response(sim, c, autopilot)
        assert 4.0 <= peak_accel <= 7.5 and 8.0 <= peak_speed <= 12.0


def test_px4_without_gps_descends_blind_in_altitude_mode_and_refuses_the_modes_that_need_a_position(
        sim_start, sim_connect):
    """PX4 1.15 SITL, GPS fusion switched off in OFFBOARD flight: "Failsafe activated" 6.5 s after, Altitude mode,
    a blind descent to the landing disarm; OFFBOARD and Land refused (TEMPORARILY_REJECTED, "Switching to Land is
    currently not available"), GLOBAL_POSITION_INT stopped and LOCAL_POSITION_NED went on."""
    sim = sim_start(speedup=10.0, strict=True, faults={"gps_loss_start_s": 8.0})
    c = sim_connect(sim)
    with _px4_offboard_until_failsafe(sim, c):
        assert _event_time(sim, "failsafe", "no position") - _event_time(sim, "gps", "lost") == pytest.approx(
            6.5, abs=0.05)
        assert sim.truth()["mode"] == "ALTCTL"
        assert c.wait_for("GPS_RAW_INT", since=c.mark()).fix_type == M.GPS_FIX_TYPE_NO_FIX
        assert c.set_mode_px4(PX4_OFFBOARD).result == M.MAV_RESULT_TEMPORARILY_REJECTED
        since = c.mark()
        assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN).result == \
            M.MAV_RESULT_TEMPORARILY_REJECTED
        c.wait_for("STATUSTEXT", lambda m: m.text == "Switching to Land is currently not available\t", since=since)
        since = c.mark()
        wait_sim(sim, 1.0)
        assert c.of_type("LOCAL_POSITION_NED", since) and not c.of_type("GLOBAL_POSITION_INT", since)
        sim.wait_until(lambda s: not s["armed"], 15)
    assert sim.truth()["on_ground"] and sim.report()["collisions"] == []


def test_ardupilot_without_gps_lands_on_its_ekf_failsafe_and_refuses_guided(sim_start, sim_connect):
    """ArduCopter 4.7 SITL, SIM_GPS1_ENABLE 0 in flight: GPS_RAW_INT NO_FIX, then "EKF variance" and "EKF Failsafe:
    changed to LAND Mode" (CRITICAL; "EKF Failsafe" when landing already) 7.3 s after, LAND; a position mode is
    refused: FAILED, "Mode change to GUIDED failed: requires position"."""
    sim = sim_start(autopilot="ardupilot", speedup=10.0, faults={"gps_loss_start_s": 12.0})
    c = sim_connect(sim)
    _guided_takeoff(sim, c, 10.0)
    variance = c.wait_for("STATUSTEXT", lambda m: m.text == "EKF variance", timeout_s=10)
    assert variance.severity == M.MAV_SEVERITY_CRITICAL
    c.wait_for("STATUSTEXT", lambda m: m.text == "EKF Failsafe: changed to LAND Mode", timeout_s=2)
    assert _event_time(sim, "failsafe", "EKF") - _event_time(sim, "gps", "lost") == pytest.approx(7.3, abs=0.05)
    assert sim.truth()["mode"] == "LAND"
    since = c.mark()
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM["GUIDED"]).result == M.MAV_RESULT_FAILED
    c.wait_for("STATUSTEXT", lambda m: m.text == "Mode change to GUIDED failed: requires position", since=since)
    sim.wait_until(lambda s: not s["armed"], 20)
    assert sim.truth()["on_ground"] and sim.truth()["mode"] == "LAND"
