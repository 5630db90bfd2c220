"""Vehicle behaviour over MAVLink: several clients, RTL, wind and GPS noise, the big SF map."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim.world import CityMap
from tests import shared
from tests.conftest import wait_ready, wait_sim

M = mavlink


def _takeoff_offboard(c, sim, north=0.0, east=0.0, altitude_m=5.0):
    wait_ready(sim)
    c.setpoint_local(north, east, -altitude_m)
    assert c.set_mode_px4(6).result == 0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    sim.wait_until(lambda s: abs(s["position"]["up_m"] - altitude_m) < 0.05, 10)


def test_two_clients_each_get_telemetry_and_their_own_acks(sim_start, sim_connect):
    sim = sim_start()
    gcs = sim_connect(sim, system=255, component=190)
    mission = sim_connect(sim, system=254, component=191)
    gcs.wait_for("HEARTBEAT")
    mission.wait_for("HEARTBEAT")
    assert sim.clients() == 2
    wait_ready(sim)
    since = gcs.mark()
    ack = mission.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert (ack.result, ack.target_system) == (M.MAV_RESULT_ACCEPTED, 254)
    gcs.wait_for("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, since=since)
    assert gcs.of_type("COMMAND_ACK", since) == []  # the ack goes to the sender only


@pytest.mark.flight
def test_rtl_returns_home_and_lands(sim_start, sim_connect):
    sim = sim_start(speedup=20.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    since = c.mark()
    c.send(M.MAVLink_param_set_message(1, 1, b"RTL_RETURN_ALT", 8.0, M.MAV_PARAM_TYPE_REAL32))
    c.wait_for("PARAM_VALUE", lambda m: m.param_id == "RTL_RETURN_ALT", since=since)
    _takeoff_offboard(c, sim)
    c.setpoint_local(-20.0, 10.0, -5.0)
    sim.wait_until(lambda s: abs(s["position"]["north_m"] + 20) < 0.05, 10)
    assert c.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
    state = sim.wait_until(lambda s: s["on_ground"] and not s["armed"], 30)
    # Disarmed after the landing, PX4 goes back to the last mode the user chose that allows arming.
    assert state["mode"] == "OFFBOARD"
    assert [e["text"] for e in sim.report()["events"] if e["kind"] == "mode"][-2:] == ["mode RTL", "mode OFFBOARD"]
    report = sim.report()
    assert report["max_altitude_m"] == pytest.approx(8.0, abs=0.15)  # climbed to RTL_RETURN_ALT first
    assert (report["landed"]["north_m"], report["landed"]["east_m"]) == pytest.approx((0.0, 0.0), abs=0.1)


@pytest.mark.flight
def test_wind_pushes_but_the_controller_learns_it_and_holds(sim_start, sim_connect):
    sim = sim_start(speedup=20.0, wind_m_s=(0.0, 5.0))
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    _takeoff_offboard(c, sim, altitude_m=5.0)
    time.sleep(0.5)  # 10 s simulated hover: the velocity loop's integrator has learnt the drag
    pos = sim.truth()["position"]
    assert abs(pos["east_m"]) < 0.1 and abs(pos["north_m"]) < 0.05


@pytest.mark.flight
def test_the_tilt_limit_is_the_autopilots_parameter_and_bounds_the_wind_it_holds_against(sim_start, sim_connect):
    # 20 m/s of wind drags 6 m/s^2 at a standstill: PX4's 45 degrees (MPC_TILTMAX_AIR) lean 9.8 m/s^2 against
    # it and hold; set to ArduCopter's 30 degrees (5.7 m/s^2) the vehicle is carried off downwind
    sim = sim_start(speedup=20.0, wind_m_s=(0.0, 20.0))
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    _takeoff_offboard(c, sim)
    wait_sim(sim, 10.0, timeout_s=5.0)
    assert abs(sim.truth()["position"]["east_m"]) < 0.3
    since = c.mark()
    c.send(M.MAVLink_param_set_message(1, 1, b"MPC_TILTMAX_AIR", 30.0, M.MAV_PARAM_TYPE_REAL32))
    c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MPC_TILTMAX_AIR", since=since)
    state = sim.wait_until(lambda s: s["position"]["east_m"] > 5.0, 5)
    assert state["position"]["east_m"] > 5.0


def test_gps_noise_moves_reports_not_truth(sim_start, sim_connect):
    sim = sim_start(gps_noise_m=2.0, seed=7)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    time.sleep(1.0)
    xs = [m.x for m in c.of_type("LOCAL_POSITION_NED")]
    assert len(set(xs)) > 3 and max(abs(x) for x in xs) < 10
    assert all(m.z == 0.0 for m in c.of_type("LOCAL_POSITION_NED"))  # on the ground z stays exactly 0
    truth = sim.truth()["position"]
    assert (truth["north_m"], truth["east_m"]) == (0.0, 0.0)


@pytest.mark.flight
def test_with_gps_noise_the_autopilot_holds_its_estimate_and_the_truth_wanders(sim_start, sim_connect):
    """A real autopilot flies its position estimate to the setpoint, so the vehicle itself ends up off it by the
    estimate's error: the reported position stays on the setpoint while the true one moves with the noise. Height
    comes from the barometer (PX4's EKF2_HGT_REF, ArduPilot's EK3_SRC1_POSZ): the GPS's vertical error is in
    neither the altitude flown nor the one reported (reported with it, a hovering vehicle's altitude wandered
    metres and a client dropped most scans as taken below its altitude)."""
    sim = sim_start(speedup=50.0, gps_noise_m=2.0, seed=7)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    _takeoff_offboard(c, sim, altitude_m=5.0)
    truths, reported, downs = [], [], []
    for _ in range(60):  # 300 s simulated, five times the noise's correlation time
        c.setpoint_local(0.0, 0.0, -5.0)
        time.sleep(0.1)
        pos = sim.truth()["position"]
        truths.append((pos["north_m"], pos["east_m"]))
        last = c.of_type("LOCAL_POSITION_NED")[-1]
        reported.append((last.x, last.y))
        downs.append(last.z)
    truths, reported = np.array(truths), np.array(reported)
    spread_truth, spread_reported = truths.std(axis=0).mean(), reported.std(axis=0).mean()
    assert spread_truth > 0.8  # the vehicle moved with the estimate's error (2 m standard deviation)
    assert spread_reported < 0.5 * spread_truth  # the estimate stayed on the setpoint, less the loop's lag
    assert max(abs(z + 5.0) for z in downs) < 0.3


@pytest.mark.flight
@shared.needs_sf_map  # the one rule (tests/shared.py), counted in the closing summary
def test_sf_map_flight_keeps_up_with_speedup(sim_start, sim_connect):
    """3845 boxes: the per-step truth check must not slow the simulation down."""
    sim = sim_start(map_path=shared.sf_map(), speedup=20.0)
    c = sim_connect(sim)
    c.wait_for("HEARTBEAT")
    _takeoff_offboard(c, sim, altitude_m=120.0)  # above the tallest building (106 m)
    c.setpoint_local(150.0, 150.0, -120.0)  # PX4's local metres (its 6371 km sphere): map (149.73, 150.36)
    scale_n, scale_e = CityMap(37.792480, -122.397450, np.zeros((0, 6))).local_scale("px4")
    north, east = 150.0 / scale_n, 150.0 / scale_e
    sim.wait_until(lambda s: math.hypot(s["position"]["north_m"] - north, s["position"]["east_m"] - east) < 0.1, 20)
    report = sim.report()
    assert report["collisions"] == [] and 0 < report["min_clearance_m"] < 50
    assert sim.behind_s < 0.5
