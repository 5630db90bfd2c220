"""The boot model against the timelines measured on the real autopilots (sim/boot.py has the measurements).

Oracles are the SITL measurements, typed here: ArduCopter V4.7.0-dev (simulated seconds from the first
connection) and PX4 v1.15.4 SIH (seconds after launch).
"""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

M = mavlink
ACM_GUIDED = 4
#: ArduCopter SITL, measured: GPS fix, EKF origin + home, EKF using GPS (simulated s).
ARDU_FIX_S, ARDU_ORIGIN_S, ARDU_ESTIMATE_S = 10.1, 19.9, 41.5
#: PX4 SITL, measured: local position, home, global position, armable (s).
PX4_LOCAL_S, PX4_HOME_S, PX4_GLOBAL_S, PX4_ARMABLE_S = 0.4, 1.4, 35.0, 36.6  # home: 1.3-2.4 s over 5 runs


def _request(c, rates_hz: dict) -> None:
    for msg_id, hz in rates_hz.items():
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz).result == M.MAV_RESULT_ACCEPTED


def _arm_attempts(c, until_s: float, sim) -> list[tuple[float, int, str]]:
    """Ask to arm every ~2 simulated s until accepted or ``until_s``: (simulated time the autopilot handled the
    request, result, the refusal's STATUSTEXT) per attempt, from the report's command log."""
    while sim.truth()["sim_time_s"] < until_s:
        ack = c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if ack.result == M.MAV_RESULT_ACCEPTED:
            break
        time.sleep(0.1)
    return [(e["sim_time_s"], e["result"], e["reason"]) for e in sim.report()["commands"]
            if e["command"] == M.MAV_CMD_COMPONENT_ARM_DISARM]


@pytest.mark.flight
def test_arducopter_boot_timeline_and_prearm_texts(sim_start, sim_connect):
    sim = sim_start(autopilot="ardupilot", boot="arducopter", speedup=25.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    _request(c, {M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 5,
                 M.MAVLINK_MSG_ID_GPS_RAW_INT: 5})
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, ACM_GUIDED).result == 0  # accepted before the fix, as on SITL
    attempts = _arm_attempts(c, 60.0, sim)
    c.wait_for("LOCAL_POSITION_NED", timeout_s=5)
    # GLOBAL_POSITION_INT streams from boot but reads 0,0 until the fix; GPS_RAW_INT has no fix before it.
    gpi = c.of_type("GLOBAL_POSITION_INT")
    assert all(m.lat == m.lon == 0 for m in gpi if m.time_boot_ms < ARDU_FIX_S * 1000 - 20)
    assert all(m.lat != 0 for m in gpi if m.time_boot_ms > ARDU_FIX_S * 1000 + 20)
    assert any(m.time_boot_ms < 5000 for m in gpi)
    raw = c.of_type("GPS_RAW_INT")
    assert {m.fix_type for m in raw if m.time_usec < ARDU_FIX_S * 1e6 - 2e4} == {M.GPS_FIX_TYPE_NO_GPS}
    assert {m.fix_type for m in raw if m.time_usec > ARDU_FIX_S * 1e6 + 2e4} == {M.GPS_FIX_TYPE_RTK_FIXED}
    # Origin and home once set (volunteered), LOCAL_POSITION_NED only once the EKF uses GPS.
    origin = c.of_type("GPS_GLOBAL_ORIGIN")[0]
    home = c.of_type("HOME_POSITION")[0]
    assert origin.time_usec / 1e6 == pytest.approx(ARDU_ORIGIN_S, abs=0.05)
    assert home.time_usec / 1e6 == pytest.approx(ARDU_ORIGIN_S, abs=0.05)
    assert min(m.time_boot_ms for m in c.of_type("LOCAL_POSITION_NED")) / 1000 >= ARDU_ESTIMATE_S
    # Arming: FAILED with the reason of the moment, then accepted once the estimate is there.
    for t, result, text in attempts[:-1]:
        assert result == M.MAV_RESULT_FAILED and t < ARDU_ESTIMATE_S
        assert text == ("Arm: AHRS: waiting for home" if t < ARDU_ORIGIN_S else "Arm: Need Position Estimate")
    assert attempts[-1][1] == M.MAV_RESULT_ACCEPTED and attempts[-1][0] >= ARDU_ESTIMATE_S
    assert {text for _, _, text in attempts[:-1]} == {"Arm: AHRS: waiting for home", "Arm: Need Position Estimate"}
    refusals = [m.text for m in c.of_type("STATUSTEXT") if m.text.startswith("Arm:")]
    assert len(refusals) == len(attempts) - 1  # each refusal also told the client why
    texts = [m.text for m in c.of_type("STATUSTEXT")]
    assert "EKF3 IMU0 origin set" in texts and "EKF3 IMU0 is using GPS" in texts
    assert "PreArm: Need Position Estimate" in texts  # the 30 s periodic report


@pytest.mark.flight
def test_px4_stock_boot_timeline(sim_start, sim_connect):
    sim = sim_start(boot="px4", strict=True, speedup=25.0)
    c = sim_connect(sim)
    c.wait_for("LOCAL_POSITION_NED")
    attempts = _arm_attempts(c, 45.0, sim)
    c.wait_for("GLOBAL_POSITION_INT", timeout_s=5)
    assert min(m.time_boot_ms for m in c.of_type("GLOBAL_POSITION_INT")) / 1000 >= PX4_GLOBAL_S
    assert min(m.time_boot_ms for m in c.of_type("LOCAL_POSITION_NED")) / 1000 < PX4_GLOBAL_S  # long before
    assert min(m.time_usec for m in c.of_type("HOME_POSITION")) / 1e6 >= PX4_HOME_S
    for t, result, text in attempts[:-1]:
        assert result == M.MAV_RESULT_TEMPORARILY_REJECTED and t < PX4_ARMABLE_S
        assert text == "Arming denied: Resolve system health failures first"
    assert attempts[-1][1] == M.MAV_RESULT_ACCEPTED and attempts[-1][0] >= PX4_ARMABLE_S
    first_chunks = [m for m in c.of_type("STATUSTEXT") if m.text.startswith("Arming denied: ")]
    assert len(first_chunks) == len(attempts) - 1  # each refusal also told the client why (in two chunks)


def test_px4_heartbeat_starts_late_and_sys_status_reports_prearm_once_ready(sim_start, sim_connect):
    sim = sim_start(boot="px4-fast-align", speedup=4.0)
    c = sim_connect(sim)
    hb = c.wait_for("HEARTBEAT", timeout_s=5)
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4
    # PX4's local position streams from 0.4 s, its heartbeat only from ~1.4 s after launch.
    before = c.messages[: c.messages.index(hb)]
    early = [m.time_boot_ms for m in before if m.get_type() == "LOCAL_POSITION_NED"]
    assert early and 400 <= min(early) < 1000
    assert all(m.time_boot_ms <= 1420 for m in before if hasattr(m, "time_boot_ms"))
    unready = c.wait_for("SYS_STATUS")
    assert not unready.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    ready = c.wait_for("SYS_STATUS", lambda m: m.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK,
                       timeout_s=5)
    assert sim.truth()["sim_time_s"] >= 4.4 and ready is not None


def test_requests_for_what_is_not_there_yet_are_accepted_and_answered_later(sim_start, sim_connect):
    """ArduCopter before its EKF origin: REQUEST_MESSAGE GPS_GLOBAL_ORIGIN / HOME_POSITION ACCEPTED with nothing
    sent, GET_HOME_POSITION FAILED (measured); afterwards the same requests get the messages."""
    sim = sim_start(autopilot="ardupilot", boot="arducopter", speedup=20.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_GET_HOME_POSITION).result == M.MAV_RESULT_FAILED
    time.sleep(0.1)
    assert c.of_type("GPS_GLOBAL_ORIGIN", since) == [] and c.of_type("HOME_POSITION", since) == []
    sim.wait_until(lambda s: s["sim_time_s"] > ARDU_ORIGIN_S + 0.5, 10)
    since = c.mark()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN).result == M.MAV_RESULT_ACCEPTED
    origin = c.wait_for("GPS_GLOBAL_ORIGIN", since=since)
    assert (origin.latitude, origin.longitude) == (377924800, -1223974500)
