"""End to end against a real PX4 (v1.15 SITL with SIH, ../shared/sitl/px4): a stock boot, a second mission, Ctrl-C,
a GPS lost in flight.

PX4 runs in real time. One test boots it stock (its estimator gives a global position only ~35 s after boot:
the client must wait, quoting PX4's reasons); the other uses PX4_EKF2_FAST_ALIGN=1. An independent monitor on
PX4's ground-station link checks the reported track against the map's boxes (tests/sitl_support.py). Skipped
where the binary is absent.
"""

from __future__ import annotations

import math
import re
import signal
import time

import pytest

import motion_planning as mp
from tests import shared
from tests.exit_codes import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK  # README's numbers, not the code's constants
from tests.sitl_support import (
    Monitor,
    Px4Sitl,
    fly_and_set_param_in_flight,
    held_out_goal,
    read_boxes,
    run_client,
    to_latlon,
)

pytestmark = shared.needs_px4  # the one rule for ../shared (tests/shared.py); counted in the summary

MAP = mp.DEFAULT_MAP
LAT0, LON0, BOXES = read_boxes(MAP)
ALT_M, SAFETY_M = 5.0, 5.0
GOAL_SHORT = (99.5, 50.5)  # ~120 m, two legs
HOME_GOAL = (0.5, 0.5)


def mission_args(px4, goal, tmp_path, *extra) -> list[str]:
    lat, lon = to_latlon(*goal, LAT0, LON0)
    return ["--goal_lat", f"{lat:.9f}", "--goal_lon", f"{lon:.9f}", "--alt", f"{ALT_M:g}", "--safety",
            f"{SAFETY_M:g}", "--connection", px4.client, "--timeout", "20", "--arm-timeout", "90", "--log-dir",
            str(tmp_path / "logs"), *extra]


def assert_landed_safely_at(monitor: Monitor, goal, since_s: float, within_m: float = 1.0) -> None:
    north, east, _ = monitor.landed_at()
    error_m = math.hypot(north - goal[0], east - goal[1])
    clearance_m = monitor.min_clearance_m(since_s)
    print(f"\nlanded {error_m:.2f} m from the goal, min clearance {clearance_m:.2f} m")
    # PX4's position loop overshoots the stop at the goal by up to 1.6 m (README's margin paragraph)
    assert error_m <= within_m and clearance_m >= SAFETY_M - 2.0


@pytest.fixture
def px4(request):
    """A PX4 just launched (``fast_align`` by indirect parametrisation), and a monitor on its GCS link."""
    with Px4Sitl((LAT0, LON0, 0.0), fast_align=getattr(request, "param", False)) as sitl:
        monitor = Monitor(sitl.gcs, MAP, ground_amsl_m=0.0)
        try:
            yield sitl, monitor
        finally:
            monitor.close()


def test_a_stock_boot_flies_a_held_out_mission_then_a_second_one(px4, tmp_path, capsys):
    sitl, monitor = px4
    goal = held_out_goal(MAP, seed=17)  # a goal no sim test flies to
    started = time.monotonic()
    code = mp.main(mission_args(sitl, goal, tmp_path))  # started right after boot
    out, err = capsys.readouterr()
    assert code == EXIT_OK, err
    lines = out.splitlines()
    waiting = [line for line in lines if line.startswith("waiting for a global position estimate")]
    assert len(waiting) >= 4  # ~35 s of waiting, one line every 5 s (with PX4's reasons when it sends them)
    # COM_OBL_RC_ACT 0 without RC lands the vehicle (measured): no warning that a lost link leaves it hovering
    assert not any("leaves the vehicle hovering" in line for line in lines)
    # a stock boot's estimate wanders during PX4's own LAND descent (below): this first landing measured 1.23 m
    # once (CI, 2026-12-07) with the vehicle within 0.3 m of the goal when LAND was commanded; held to 1.5 m too
    assert_landed_safely_at(monitor, goal, started, within_m=1.5)
    # a second mission on the same autopilot after a normal landing (PX4 refused this arming for 60 s once)
    started = time.monotonic()
    assert mp.main(mission_args(sitl, HOME_GOAL, tmp_path, "-q")) == EXIT_OK, capsys.readouterr().err
    # it flies; after a stock boot's first landing PX4's estimate of where it stands wanders: measured 0.98 m and
    # 1.09 m from home (0.2-0.4 m with fast alignment, the test below), so this one is held to 1.5 m
    assert_landed_safely_at(monitor, HOME_GOAL, started, within_m=1.5)


@pytest.mark.parametrize("px4", [True], indirect=True, ids=["fast-align"])
def test_ctrl_c_in_flight_lands_where_it_is_then_a_second_mission_flies(px4, tmp_path, capsys):
    sitl, monitor = px4
    proc = run_client(mission_args(sitl, GOAL_SHORT, tmp_path))
    try:
        at = monitor.wait(lambda s: s.armed and s.up_m > 3.0 and s.speed_mps > 2.0, 90.0, "a vehicle flying")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=90)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "interrupted: the vehicle was landed and disarmed first" in err
    north, east, _ = monitor.landed_at()
    assert math.hypot(north - at.north_m, east - at.east_m) < 15.0  # landed where it was
    # PX4 goes back to OFFBOARD (disarmed) after landing and refuses to arm without setpoints: we stream first
    started = time.monotonic()
    code = mp.main(mission_args(sitl, HOME_GOAL, tmp_path, "-q"))
    out, err = capsys.readouterr()
    assert code == EXIT_OK, err
    assert [line for line in out.splitlines() if line] == [line for line in out.splitlines()
                                                            if line.startswith("mission complete:")]  # -q
    assert_landed_safely_at(monitor, HOME_GOAL, started)


@pytest.mark.parametrize("px4", [True], indirect=True, ids=["fast-align"])
def test_a_gps_lost_in_flight_is_left_to_px4s_blind_landing_and_said_so(px4, tmp_path, capsys):
    # GPS fusion switched off mid-route (EKF2_GPS_CTRL 0, set from the monitor's ground station): PX4 says
    # "Failsafe activated", goes to Altitude mode and comes down blind, refusing OFFBOARD, Land and Hold. The
    # client may not fight it nor leave before it is down (it exited with the vehicle armed at 5 m, before)
    from pymavlink import mavutil

    sitl, monitor = px4
    goal = held_out_goal(MAP, seed=29, min_m=200.0, max_m=300.0)  # far enough to be on the way 7 s after the loss
    code, _, err = fly_and_set_param_in_flight(monitor, mission_args(sitl, goal, tmp_path), "EKF2_GPS_CTRL", 0.0,
                                               mavutil.mavlink.MAV_PARAM_TYPE_INT32)
    assert code == EXIT_FAILED, err
    assert re.search(r"left our flight mode for ALTCTL; (meanwhile the vehicle landed and disarmed at map"
                     r"|.*it landed at map .* and disarmed)", err), err
    assert "Disarmed by landing" in " ".join(monitor.texts)  # PX4's own word that it is down
