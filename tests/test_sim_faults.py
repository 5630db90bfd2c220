"""Each fault option behaves as documented (sim/faults.py): link faults in simulated time."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.conftest import wait_ready

M = mavlink


def _ping_rtts(c, count: int, gap_s: float, timeout_s: float = 1.0) -> list:
    """Round-trip times (wall s) of ``count`` pings; None for the unanswered ones."""
    rtts = []
    for seq in range(count):
        since = c.mark()
        t0 = time.monotonic()
        c.send(M.MAVLink_ping_message(int(t0 * 1e6), seq, 0, 0))
        try:
            pong = c.wait_for("PING", lambda m, s=seq: m.seq == s and m.target_system == 255, timeout_s=timeout_s,
                              since=since)
            rtts.append(pong.rx_wall_s - t0)
        except TimeoutError:
            rtts.append(None)
        time.sleep(gap_s)
    return rtts


def wait_delivered(sim, c, ready, timeout_s: float = 20.0) -> dict:
    """Wait until ``ready(link)`` holds for the sim's link counts, then until the client has received every
    packet the sim had sent it by then less those the faults dropped; return those counts."""
    deadline = time.monotonic() + timeout_s
    while not ready(link := sim.report()["links"][0]):
        assert time.monotonic() < deadline, f"the sim's link never got there: {link}"
        time.sleep(0.01)
    expected = link["packets_out"] - link["dropped_out"]
    with c.cond:
        while len(c.messages) < expected:
            assert c.cond.wait(max(0.0, deadline - time.monotonic())), (len(c.messages), expected)
    return link


def test_packet_loss_drops_both_directions(sim_start, sim_connect):
    sim = sim_start(faults={"packet_loss_pct": 30.0}, seed=3)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT", timeout_s=5)
    since = c.mark()
    before = sim.report()["links"][0]["packets_in"]
    for seq in range(200):
        c.send(M.MAVLink_ping_message(seq, seq, 0, 0))
        time.sleep(0.002)
    # events, not a wall-clock guess: the sim has read all 200 (lost ones included), and the client has every
    # packet the sim sent it by then that the fault did not drop
    wait_delivered(sim, c, lambda link: link["packets_in"] >= before + 200)
    answered = len({m.seq for m in c.of_type("PING", since) if m.target_system == 255}) / 200
    # Both directions lose 30 %: 0.7 * 0.7 = 0.49 of pings come back.
    assert 0.25 < answered < 0.75
    link = sim.report()["links"][0]
    assert link["dropped_in"] > 20 and link["dropped_out"] > 20


def test_no_faults_by_default(sim_start, sim_connect):
    sim = sim_start()
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    rtts = _ping_rtts(c, 10, 0.0, timeout_s=5.0)
    assert all(r is not None for r in rtts)  # every ping answered
    link = wait_delivered(sim, c, lambda link: True)
    assert link["dropped_in"] == link["dropped_out"] == 0
    # no latency: the 300 ms one below is 150 ms of wall time at this speed-up; a busy machine can delay a few
    # round trips, not the median
    assert sorted(rtts)[len(rtts) // 2] < 0.1, rtts


@pytest.mark.parametrize("speedup", [1.0, 4.0])
def test_latency_is_in_simulated_milliseconds(sim_start, sim_connect, speedup):
    """300 ms of simulated latency each way: a 600 ms simulated round trip, i.e. 600 / speedup ms of wall time."""
    sim = sim_start(speedup=speedup, faults={"latency_ms": 300.0})
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT", timeout_s=3)
    rtts = _ping_rtts(c, 4, 0.0, timeout_s=2.0)
    expected = 0.6 / speedup
    # Never faster than the latency, less the 20 ms physics step each way that quantises simulated time.
    assert all(r is not None and r >= (0.6 - 0.04) / speedup - 0.005 for r in rtts), rtts
    assert sorted(rtts)[1] < expected + 0.3, rtts  # and (most of the time) not much slower


@pytest.mark.parametrize("speedup", [3.0, 10.0])
def test_outage_in_simulated_seconds_is_the_same_at_any_speedup(sim_start, sim_connect, speedup):
    """An outage from 3 s to 6 s of simulated time: no packet stamped inside it arrives, the link then recovers."""
    sim = sim_start(speedup=speedup, faults={"outage_start_s": 3.0, "outage_duration_s": 3.0})
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    c.wait_for("ATTITUDE", lambda m: m.time_boot_ms > 7_000, timeout_s=5)
    stamps_s = [m.time_boot_ms / 1000 for m in c.messages if hasattr(m, "time_boot_ms")]
    assert any(t < 2.9 for t in stamps_s) and any(t > 6.1 for t in stamps_s)
    assert not any(3.0 <= t < 6.0 for t in stamps_s)
    # A command sent after the outage works again.
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED


def test_outage_drops_commands(sim_start, sim_connect):
    sim = sim_start(faults={"outage_start_s": 0.0, "outage_duration_s": 10.0})
    c = sim_connect(sim)
    with pytest.raises(TimeoutError):
        c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=0.3)
    assert not sim.truth()["armed"]


def test_deny_first_n_arms(sim_start, sim_connect):
    sim = sim_start(faults={"deny_arm_count": 2})
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    wait_ready(sim)
    since = c.mark()
    results = [c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result for _ in range(3)]
    assert results == [M.MAV_RESULT_TEMPORARILY_REJECTED] * 2 + [M.MAV_RESULT_ACCEPTED]
    assert sum("arming denied" in m.text for m in c.of_type("STATUSTEXT", since)) == 2
    assert sim.truth()["armed"]


def test_deny_named_command(sim_start, sim_connect):
    sim = sim_start(faults={"deny_commands": ("NAV_TAKEOFF",)})
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    assert c.arm().result == M.MAV_RESULT_ACCEPTED
    nan = float("nan")
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan).result == M.MAV_RESULT_DENIED
    assert sim.truth()["on_ground"]
    entry = [e for e in sim.report()["commands"] if e["command"] == M.MAV_CMD_NAV_TAKEOFF][0]
    assert entry["result_name"] == "MAV_RESULT_DENIED" and "fault" in entry["reason"]


def test_fault_settings_out_of_range_are_refused():
    from sim import FaultConfig

    for kwargs in ({"packet_loss_pct": 150}, {"packet_loss_pct": -5}, {"latency_ms": -100},
                   {"deny_arm_count": -2}, {"outage_start_s": -1.0}, {"deny_commands": ("FLY_AWAY",)}):
        with pytest.raises(ValueError):
            FaultConfig(**kwargs)
