"""Each fault option behaves as documented (sim/faults.py)."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

M = mavlink


def _ping_rtts(c, count: int, gap_s: float, timeout_s: float = 1.0) -> list:
    """Round-trip times (s) of ``count`` pings; None for the unanswered ones."""
    rtts = []
    for seq in range(count):
        since = c.mark()
        t0 = time.monotonic()
        c.send(M.MAVLink_ping_message(int(t0 * 1e6), seq, 0, 0))
        try:
            pong = c.wait_for("PING", lambda m, s=seq: m.seq == s, timeout_s=timeout_s, since=since)
            rtts.append(pong.rx_wall_s - t0)
        except TimeoutError:
            rtts.append(None)
        time.sleep(gap_s)
    return rtts


def test_packet_loss_drops_both_directions(sim_start, sim_connect):
    sim = sim_start(faults={"packet_loss_pct": 30.0}, seed=3)
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT", timeout_s=5)
    since = c.mark()
    for seq in range(200):
        c.send(M.MAVLink_ping_message(seq, seq, 0, 0))
        time.sleep(0.002)
    time.sleep(0.5)
    answered = len({m.seq for m in c.of_type("PING", since)}) / 200
    # Both directions lose 30 %: 0.7 * 0.7 = 0.49 of pings come back.
    assert 0.25 < answered < 0.75


def test_no_faults_by_default(sim_start, sim_connect):
    sim = sim_start()
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    rtts = _ping_rtts(c, 10, 0.0)
    assert all(r is not None and r < 0.1 for r in rtts)


def test_latency_delays_each_direction(sim_start, sim_connect):
    sim = sim_start(faults={"latency_ms": 150.0})
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT", timeout_s=3)
    rtts = _ping_rtts(c, 4, 0.0, timeout_s=2.0)
    assert all(r is not None and 0.3 <= r < 0.6 for r in rtts), rtts


def test_outage_silences_the_link_then_recovers(sim_start, sim_connect):
    sim = sim_start(faults={"outage_start_s": 0.6, "outage_duration_s": 1.0})
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    t0 = sim.started_wall_s  # the outage clock starts with the simulator
    c.wait_for("HEARTBEAT", timeout_s=4, since=c.mark())  # first heartbeat after the outage (t ~ 1.6 s)
    times = [m.rx_wall_s - t0 for m in c.messages]
    assert any(t < 0.6 for t in times)
    assert not any(0.65 < t < 1.55 for t in times)
    assert any(t > 1.6 for t in times)
    # A command sent inside an outage is lost; after it, commands work again.
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED


def test_outage_drops_commands(sim_start, sim_connect):
    sim = sim_start(faults={"outage_start_s": 0.0, "outage_duration_s": 1.0})
    c = sim_connect(sim.port)
    with pytest.raises(TimeoutError):
        c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=0.3)
    assert not sim.truth()["armed"]


def test_deny_first_n_arms(sim_start, sim_connect):
    sim = sim_start(faults={"deny_arm_count": 2})
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    results = [c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result for _ in range(3)]
    assert results == [M.MAV_RESULT_TEMPORARILY_REJECTED] * 2 + [M.MAV_RESULT_ACCEPTED]
    assert sum("arming denied" in m.text for m in c.of_type("STATUSTEXT", since)) == 2
    assert sim.truth()["armed"]


def test_deny_named_command(sim_start, sim_connect):
    sim = sim_start(faults={"deny_commands": ("NAV_TAKEOFF",)})
    c = sim_connect(sim.port)
    c.wait_for("HEARTBEAT")
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    nan = float("nan")
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan).result == M.MAV_RESULT_DENIED
    assert sim.truth()["on_ground"]
    entry = [e for e in sim.report()["commands"] if e["command"] == M.MAV_CMD_NAV_TAKEOFF][0]
    assert entry["result_name"] == "MAV_RESULT_DENIED" and "fault" in entry["reason"]
