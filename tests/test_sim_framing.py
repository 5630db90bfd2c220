"""Non-MAVLink bytes in a client's stream must not eat the packets after them (sim/framing.py).

The classic course's motion_planning.py ``send_waypoints()`` writes ``msgpack.dumps(waypoints)`` straight
into the MAVLink TCP stream. The bytes below are exactly what it writes for
``[[0, 0, 5, 0], [10, 0, 5, 0], [10, -3, 5, 0]]`` (checked against the real udacidrone client; msgpack
is not a dependency here): ``-3`` is encoded 0xFD, the MAVLink 2 start marker, so the would-be frame
``fd 05 00 ...`` used to swallow the first 14 bytes of whatever the client sent next.
"""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim.framing import FrameScanner

M = mavlink
WAYPOINTS_MSGPACK = bytes.fromhex("93" "9400000500" "940a000500" "940afd0500")
PX4_MAIN_OFFBOARD = 6


def _packed(*msgs, mav=None) -> bytes:
    mav = mav or M.MAVLink(None, 255, 190)
    return b"".join(m.pack(mav) for m in msgs)


def _cmd(command=M.MAV_CMD_REQUEST_MESSAGE, p1=148.0):
    return M.MAVLink_command_long_message(1, 1, command, 0, p1, 0, 0, 0, 0, 0, 0)


def _hb():
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3)


def test_scanner_recovers_the_packet_after_waypoint_msgpack():
    s = FrameScanner(M.MAVLink(None, 1, 1))
    msgs, junk = s.feed(_packed(_hb()) + WAYPOINTS_MSGPACK + _packed(_cmd(), _hb()))
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "COMMAND_LONG", "HEARTBEAT"]
    assert junk == len(WAYPOINTS_MSGPACK) and s.buf == bytearray()


@pytest.mark.parametrize("chunk", [1, 3, 7, 64])
def test_scanner_byte_by_byte_with_junk_between_frames(chunk):
    mav = M.MAVLink(None, 255, 190)
    stream = (b"junk\xfe\x01" + _packed(_hb(), mav=mav) + WAYPOINTS_MSGPACK + _packed(_cmd(), mav=mav)
              + b"\xfd\xff\x00" + _packed(_cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0), mav=mav))
    s = FrameScanner(M.MAVLink(None, 1, 1))
    got = []
    for i in range(0, len(stream), chunk):
        got += s.feed(stream[i:i + chunk])[0]
    assert [m.get_type() for m in got] == ["HEARTBEAT", "COMMAND_LONG", "COMMAND_LONG"]
    assert [m.command for m in got[1:]] == [M.MAV_CMD_REQUEST_MESSAGE, M.MAV_CMD_COMPONENT_ARM_DISARM]


def test_scanner_keeps_an_incomplete_real_frame_and_reads_mavlink1():
    data = _cmd().pack(M.MAVLink(None, 255, 190), force_mavlink1=True)
    assert data[0] == M.PROTOCOL_MARKER_V1
    s = FrameScanner(M.MAVLink(None, 1, 1))
    assert s.feed(data[:-1]) == ([], 0)  # waits for the rest
    msgs, junk = s.feed(data[-1:])
    assert [m.get_type() for m in msgs] == ["COMMAND_LONG"] and junk == 0


@pytest.mark.flight
def test_classic_motion_planning_send_waypoints_then_takeoff(sim_start, sim_connect):
    """motion_planning.py: arm, take_control, set home, send_waypoints (raw msgpack), takeoff, fly, land.

    The takeoff setpoint goes out in the same TCP write as the msgpack (worst case); a command sent
    after junk whose fake header announces 255 payload bytes is answered at once, not held back.
    """
    sim = sim_start(speedup=20.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    assert c.arm().result == M.MAV_RESULT_ACCEPTED  # arm(), once the vehicle has booted
    assert c.set_mode_px4(PX4_MAIN_OFFBOARD).result == M.MAV_RESULT_ACCEPTED  # take_control()
    assert c.command(M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 37.792480, -122.397450, 0).result == 0
    takeoff_mask = 0x1000 | 0x800 | 0x400 | 0x1C0 | 0x038
    takeoff = M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, takeoff_mask, 0, 0, 5.0, 0, 0, 0, 0, 0, 0, 0, 0)
    with c._send_lock:
        c.sock.sendall(WAYPOINTS_MSGPACK + takeoff.pack(c.mav))
    sim.wait_until(lambda s: s["position"]["up_m"] > 4.9, 10)
    with c._send_lock:
        c.sock.sendall(b"\x92\xfd\xff\x00")  # more junk: a fake MAVLink 2 header with length 255
    t0 = time.monotonic()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == 0
    assert time.monotonic() - t0 < 1.0
    c.setpoint_local(10.0, -3.0, 5.0, type_mask=0x800 | 0x1C0 | 0x038)  # cmd_position(n, e, altitude, 0)
    lpn = c.wait_for("LOCAL_POSITION_NED", lambda m: abs(m.x - 10) < 0.05 and abs(m.y + 3) < 0.05, 10)
    assert lpn.z == pytest.approx(-5.0, abs=0.05)
    c.setpoint_local(10.0, -3.0, 0.0, type_mask=0x2000 | 0x800 | 0x400 | 0x1C0 | 0x038)  # land(n, e)
    sim.wait_until(lambda s: s["on_ground"], 20)
    assert c.wait_for("LOCAL_POSITION_NED", since=c.mark()).z == 0.0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == M.MAV_RESULT_ACCEPTED
    report = sim.report()
    assert not report["collisions"]
    ignored = [e["text"] for e in report["events"] if "not MAVLink" in e["text"]]
    assert ignored and sum(int(t.split("ignored ")[1].split()[0]) for t in ignored) == len(WAYPOINTS_MSGPACK) + 4
