"""A ``.waypoints`` export flown by a real autopilot: MAVProxy's ``wp load`` puts it into ArduCopter SITL, which flies
it in AUTO from takeoff to the goal and lands there.

The plan comes from the command line as a user makes it (``--plan-only --export``) on the project's map. The SITL
binary is found by the tests' one rule (``tests/shared.py``): ``$SKYROUTE_SHARED/sitl/arducopter`` if
``SKYROUTE_SHARED`` is set, else ``../shared/sitl/arducopter`` next to the project root; without it (or without
MAVProxy) the test skips. The SITL instance is a free one picked at run time (its three TCP ports free), started in
its own process group and killed in ``finally``, as is MAVProxy. The test's own pymavlink client (on SITL's second
serial port) reads the mission back, arms, switches to AUTO and judges the flight from GLOBAL_POSITION_INT, with the
goal's lat/lon computed here independently of ``skyroute.frames``.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests import shared
from tests.geodesy import distance_m, ned_to_latlon

ROOT = Path(__file__).resolve().parents[1]
SHARED = shared.shared_dir()
ARDUCOPTER = SHARED / "sitl" / "arducopter"
MAVPROXY = shutil.which("mavproxy.py") or (shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)))

pytestmark = [
    *shared.needs_arducopter,
    pytest.mark.skipif(MAVPROXY is None, reason='no MAVProxy (pip install ".[sitl]")'),
]

LAT0, LON0 = 37.792480, -122.397450
GOAL_NE = (99.5, 50.5)  # ~120 m from home on the project map, two legs, free at 5 m with a 5 m margin
SPEEDUP = 5


def to_latlon(north_m: float, east_m: float) -> tuple[float, float]:
    """``(lat, lon)`` of a point north/east of the map origin (:mod:`tests.geodesy`, independent of ``frames``)."""
    return ned_to_latlon(north_m, east_m, LAT0, LON0)


def _free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_instance() -> int:
    """An ``-I`` whose SERIAL0..2 ports (5760/5762/5763 + 10 I) are free; 2 is kept for running by hand."""
    for instance in range(11, 60):
        if all(_free(5760 + 10 * instance + k) for k in (0, 2, 3)):
            return instance
    pytest.skip("no free ArduCopter SITL instance")


def _kill(proc: subprocess.Popen | None) -> None:
    if proc is not None and proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _wait_output(path: Path, text: str, proc: subprocess.Popen, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        out = path.read_text(errors="replace") if path.exists() else ""
        if text in out:
            return out
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    raise AssertionError(f"{text!r} not in MAVProxy's output within {timeout_s} s:\n{path.read_text()[-3000:]}")


def test_arducopter_sitl_flies_the_waypoints_export_loaded_by_mavproxy_to_the_goal(tmp_path):
    from pymavlink import mavutil

    # the plan, made and exported by the command line
    goal_lat, goal_lon = to_latlon(*GOAL_NE)
    mission_file = tmp_path / "mission.waypoints"
    subprocess.run([sys.executable, str(ROOT / "motion_planning.py"), "--plan-only", "--goal_lat", f"{goal_lat:.9f}",
                    "--goal_lon", f"{goal_lon:.9f}", "--alt", "5", "--export", str(mission_file)],
                   cwd=tmp_path, check=True, capture_output=True, timeout=120)
    lines = mission_file.read_text().splitlines()
    items = [line.split("\t") for line in lines[1:]]
    assert int(items[-1][3]) == mavutil.mavlink.MAV_CMD_NAV_LAND

    instance = free_instance()
    base = 5760 + 10 * instance
    sitl = mavproxy = link = None
    run_dir = tmp_path / "sitl"
    run_dir.mkdir()
    try:
        sitl = subprocess.Popen(
            [str(ARDUCOPTER), "--model", "+", "--speedup", str(SPEEDUP),
             "--defaults", str(SHARED / "sitl" / "copter.parm"), f"-I{instance}",
             "--home", f"{LAT0},{LON0},0,0", "--wipe"],
            cwd=run_dir, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        mavproxy_log = tmp_path / "mavproxy.txt"
        with open(mavproxy_log, "w") as log_file:
            mavproxy = subprocess.Popen(
                [MAVPROXY, f"--master=tcp:127.0.0.1:{base}", "--default-modules=wp"],
                cwd=tmp_path, stdout=log_file, stderr=subprocess.STDOUT, stdin=subprocess.PIPE, text=True,
                start_new_session=True)
        # once the autopilot has booted (its mission storage refuses uploads before: NO_SPACE), load the file
        _wait_output(mavproxy_log, "ArduPilot Ready", mavproxy, 120)
        mavproxy.stdin.write(f"wp load {mission_file}\n")
        mavproxy.stdin.flush()
        _wait_output(mavproxy_log, f"Loaded {len(items)} waypoints in", mavproxy, 60)  # uploaded, all requested

        deadline = time.monotonic() + 30
        while True:  # SERIAL1 listens once the autopilot has booted
            try:
                link = mavutil.mavlink_connection(f"tcp:127.0.0.1:{base + 2}", source_system=250, retries=0)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        assert link.wait_heartbeat(timeout=30) is not None
        link.mav.command_long_send(link.target_system, link.target_component,  # SERIAL1 streams little by default
                                   mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                   mavutil.mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 100_000, 0, 0, 0, 0, 0)

        # the autopilot holds the mission MAVProxy loaded: read it back
        link.mav.mission_request_list_send(link.target_system, link.target_component)
        count = link.recv_match(type="MISSION_COUNT", blocking=True, timeout=10)
        assert count is not None and count.count == len(items)
        for seq in range(1, count.count):
            link.mav.mission_request_int_send(link.target_system, link.target_component, seq)
            item = link.recv_match(type="MISSION_ITEM_INT", blocking=True, timeout=10)
            assert item is not None and item.seq == seq
            assert item.command == int(items[seq][3]) and item.frame == int(items[seq][2])
            if item.command != mavutil.mavlink.MAV_CMD_NAV_TAKEOFF:  # ArduCopter keeps takeoff's lat/lon at 0
                assert distance_m(item.x * 1e-7, item.y * 1e-7, float(items[seq][8]), float(items[seq][9])) < 0.05
        link.mav.mission_ack_send(link.target_system, link.target_component, mavutil.mavlink.MAV_MISSION_ACCEPTED)

        # take off in AUTO without a pilot's throttle: AUTO_OPTIONS bits 0 (arm in AUTO) and 1 (take off)
        link.mav.param_set_send(link.target_system, link.target_component, b"AUTO_OPTIONS", 3,
                                mavutil.mavlink.MAV_PARAM_TYPE_INT32)
        assert link.recv_match(type="PARAM_VALUE", blocking=True, timeout=10) is not None
        link.set_mode("GUIDED")
        deadline = time.monotonic() + 120  # a fresh SITL refuses to arm until its EKF uses GPS (~40 s sim time)
        while not link.motors_armed():
            assert time.monotonic() < deadline, "ArduCopter SITL did not arm"
            link.arducopter_arm()
            link.recv_match(type="HEARTBEAT", blocking=True, timeout=2)
        link.set_mode("AUTO")

        max_alt_m, landed_at, airborne = 0.0, None, False
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            msg = link.recv_match(type=["GLOBAL_POSITION_INT", "HEARTBEAT"], blocking=True, timeout=5)
            if msg is None:
                continue
            if msg.get_type() == "GLOBAL_POSITION_INT":
                alt = msg.relative_alt * 1e-3
                max_alt_m = max(max_alt_m, alt)
                airborne = airborne or alt > 3.0
                position = (msg.lat * 1e-7, msg.lon * 1e-7, alt)
            elif (airborne and msg.get_srcSystem() == link.target_system and msg.get_srcComponent() == 1
                  and not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED):
                landed_at = position  # ArduCopter disarms itself after the LAND item touches down
                break
        assert landed_at is not None, f"no landing within 180 s (max altitude {max_alt_m:.1f} m)"
        assert distance_m(landed_at[0], landed_at[1], goal_lat, goal_lon) < 3.0
        assert landed_at[2] < 0.5
        assert 4.0 < max_alt_m < 6.5  # the planned 5 m above home
    finally:
        if link is not None:
            link.close()
        _kill(mavproxy)
        _kill(sitl)
