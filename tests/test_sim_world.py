"""Unit tests of the sim's pieces: map, collision truth, dynamics, mode tables, fault names."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil

from sim.dynamics import ControlTarget, Limits, PointMassQuad
from sim.faults import command_id, command_name
from sim.modes import ArduCopter, Behaviour, Px4
from sim.report import TruthMonitor
from sim.world import CityMap, MapFormatError, write_colliders

# Two boxes: A north 0..10, east 0..10, up 0..20; B north 20..24, east 0..4, up 0..5.
BOXES = np.array([[5.0, 5.0, 10.0, 5.0, 5.0, 10.0], [22.0, 2.0, 2.5, 2.0, 2.0, 2.5]])


@pytest.fixture
def city():
    return CityMap(37.79248, -122.39745, BOXES)


def test_nearest_box_golden(city):
    assert city.nearest_box(np.array([-3.0, 5.0, 5.0])) == (3.0, 0)  # 3 m south of A's face
    assert city.nearest_box(np.array([5.0, 5.0, 5.0]))[0] == 0.0  # inside A
    d, i = city.nearest_box(np.array([22.0, 2.0, 9.0]))  # 4 m above B's roof, 10 m from A's north face
    assert (d, i) == (4.0, 1)
    d, i = city.nearest_box(np.array([13.0, 14.0, 25.0]))  # corner of A: (3, 4, 5) -> sqrt(50)
    assert d == pytest.approx(math.sqrt(50)) and i == 0
    assert city.nearest_box(np.array([500.0, 500.0, 5.0]), cap_m=50.0) == (50.0, -1)


def test_ground_is_the_roof_below(city):
    assert city.ground_up_m(5.0, 5.0, 100.0) == 20.0
    assert city.ground_up_m(5.0, 5.0, 10.0) == 0.0  # under the roof (inside): the map ground
    assert city.ground_up_m(22.0, 2.0, 6.0) == 5.0
    assert city.ground_up_m(-0.2, 5.0, 100.0, radius_m=0.3) == 20.0  # footprint grows by the radius
    assert city.ground_up_m(-0.4, 5.0, 100.0, radius_m=0.3) == 0.0


def test_map_file_round_trip_and_bad_header(tmp_path):
    path = write_colliders(tmp_path / "c.csv", 37.79248, -122.39745, BOXES)
    city = CityMap.from_csv(path)
    assert (city.lat0_deg, city.lon0_deg) == (37.79248, -122.39745) and len(city) == 2
    np.testing.assert_allclose(city.boxes, BOXES)
    bad = tmp_path / "bad.csv"
    bad.write_text("hello\nposX\n1,2,3,4,5,6\n")
    with pytest.raises(MapFormatError):
        CityMap.from_csv(bad)


def test_geodetic_round_trip(city):
    lat, lon, alt = city.map_to_geodetic(120.0, -80.0, 33.0)
    n, e, up = city.geodetic_to_map(lat, lon, alt)
    assert (n, e, up) == pytest.approx((120.0, -80.0, 33.0), abs=1e-6)
    # 0.001 deg of latitude is ~111 m north.
    assert city.geodetic_to_map(37.79348, -122.39745, 0.0)[0] == pytest.approx(111.0, abs=0.5)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.floats(-10, 35), st.floats(-10, 20), st.floats(0.5, 25)), min_size=2, max_size=6))
def test_lazy_truth_equals_exact_check(waypoints):
    """The triangle-inequality shortcut finds the same minimum clearance and collisions as brute force."""
    city = CityMap(37.79248, -122.39745, BOXES)
    r = 0.3
    monitor = TruthMonitor(city, r)
    exact_min, exact_hit, lazy_hit = math.inf, None, None
    pts = np.array(waypoints)
    step = 0
    for a, b in zip(pts[:-1], pts[1:]):
        for t in np.linspace(0.0, 1.0, 40):
            p = a + (b - a) * t
            step += 1
            centre = p + np.array([0.0, 0.0, r])
            gap = np.maximum(np.maximum(city.lo - centre, centre - city.hi), 0.0)
            d = float(np.sqrt((gap**2).sum(axis=1)).min())
            exact_min = min(exact_min, d - r)
            if exact_hit is None and d < r - 1e-9:
                exact_hit = step
            if monitor.check(p, True, step, 0.0) is not None and lazy_hit is None:
                lazy_hit = step
    assert lazy_hit == exact_hit
    assert monitor.min_clearance_m == pytest.approx(min(exact_min, 50.0), abs=1e-9)


def _fly(quad, target, seconds, ground=lambda n, e, u: 0.0):
    speeds = []
    for _ in range(int(seconds / 0.02)):
        quad.step(0.02, target, True, ground)
        v = quad.state.velocity_neu
        speeds.append((math.hypot(v[0], v[1]), v[2]))
    return speeds


def test_dynamics_respects_limits_and_arrives():
    lim = Limits()
    quad = PointMassQuad(lim, [0.0, 0.0, 0.0])
    speeds = _fly(quad, ControlTarget((0.0, 0.0, 20.0)), 15)
    assert max(vz for _h, vz in speeds) <= lim.max_climb_m_s + 1e-9
    assert quad.state.position_neu[2] == pytest.approx(20.0, abs=0.01)
    speeds = _fly(quad, ControlTarget((100.0, 0.0, 20.0)), 20)
    assert max(h for h, _vz in speeds) <= lim.max_horizontal_speed_m_s + 1e-9
    assert quad.state.position_neu[0] == pytest.approx(100.0, abs=0.01)
    speeds = _fly(quad, ControlTarget((100.0, 0.0, 0.0)), 20)
    assert min(vz for _h, vz in speeds) >= -lim.max_descent_m_s - 1e-9
    assert quad.state.on_ground and quad.state.position_neu[2] == 0.0


def _fly_in_wind(lim: Limits, target: ControlTarget, wind, seconds: float) -> PointMassQuad:
    quad = PointMassQuad(lim, [0.0, 0.0, 0.0])
    quad.state.on_ground, quad.state.position_neu[2] = False, 10.0
    for _ in range(int(seconds / 0.01)):
        quad.step(0.01, target, True, lambda n, e, u: 0.0, np.array(wind, float))
    return quad


def test_a_vehicle_holding_station_in_a_wind_leans_into_it():
    hover = _fly_in_wind(Limits(), ControlTarget((0.0, 0.0, 10.0)), (0.0, 8.0, 0.0), 20.0)
    roll, pitch, _ = hover.attitude()  # nose north, wind from the west blowing east: lean west (left wing down)
    assert math.tan(roll) * 9.80665 == pytest.approx(-0.3 * 8.0, abs=0.05) and abs(pitch) < 0.01


def _turn_drift_m(feedforward_1_s: float, drag: bool = True) -> float:
    """Fly north at 8 m/s in still air (drag 0.3/s; none without ``drag``), then turn east: how far north of the
    turn point the vehicle swings, with ``feedforward_1_s`` x the target velocity as a feed-forward acceleration."""
    lim = Limits()
    quad = PointMassQuad(lim, [0.0, 0.0, 10.0])
    quad.state.on_ground = False
    ground = lambda n, e, u: 0.0  # noqa: E731
    still = np.zeros(3) if drag else None
    north = (8.0 * feedforward_1_s, 0.0, math.nan)
    for k in range(1000):  # 10 s north: the integrator (or the feed-forward) carries the drag
        at = 8.0 * (k + 1) * 0.01
        quad.step(0.01, ControlTarget((at, 0.0, 10.0), (8.0, 0.0, math.nan), accel_neu=north), True, ground, still)
    turn_n, turn_e = quad.state.position_neu[:2]
    east = (0.0, 8.0 * feedforward_1_s, math.nan)
    worst = 0.0
    for k in range(800):
        target = ControlTarget((turn_n, turn_e + 8.0 * (k + 1) * 0.01, 10.0), (0.0, 8.0, math.nan), accel_neu=east)
        quad.step(0.01, target, True, ground, still)
        worst = max(worst, quad.state.position_neu[0] - turn_n)
    return worst


def test_a_feedforward_that_carries_the_drag_leaves_the_integrator_nothing_to_swing_round_at_a_turn():
    # the swing of braking from 8 m/s at 4 m/s^2, flown without drag (10.4 m), is the yardstick: the integrator
    # still leaning north adds 1.7 m to it; with the drag carried the drag only helps the braking (8.4 m)
    floor, without, carried = _turn_drift_m(0.0, drag=False), _turn_drift_m(0.0), _turn_drift_m(0.3)
    assert without > floor + 1.0 and carried < floor


def test_the_controller_leans_into_a_wind_its_trajectory_limit_could_not_hold():
    # ArduCopter's WPNAV_ACCEL 2.5 m/s^2 against the drag of an 8 m/s crosswind (0.3/s * 8 = 2.4 m/s^2) plus a
    # 10 m/s leg into a 6 m/s headwind (0.3/s * 16 = 4.8 m/s^2): the integrator learns the drag, the tilt holds it
    lim = Limits(max_horizontal_accel_m_s2=2.5)
    hover = _fly_in_wind(lim, ControlTarget((0.0, 0.0, 10.0)), (0.0, 8.0, 0.0), 20.0)
    assert np.hypot(*hover.state.position_neu[:2]) < 0.05  # no steady offset downwind
    leg = ControlTarget((math.nan, math.nan, 10.0), (10.0, 0.0, math.nan))
    upwind = _fly_in_wind(lim, leg, (-6.0, 0.0, 0.0), 20.0)
    assert upwind.state.velocity_neu[0] == pytest.approx(10.0, abs=0.1)
    assert np.hypot(*upwind.state.accel_neu[:2]) < 0.1


def test_a_wind_beyond_the_tilts_reach_carries_the_vehicle_off():
    lim = Limits()  # 30 degrees of tilt: 5.7 m/s^2; 25 m/s of wind drag 7.5 m/s^2 at a standstill
    quad = _fly_in_wind(lim, ControlTarget((0.0, 0.0, 10.0)), (0.0, 25.0, 0.0), 10.0)
    assert quad.state.position_neu[1] > 10.0


def test_disarmed_vehicle_stays_put():
    quad = PointMassQuad(Limits(), [1.0, 2.0, 0.0])
    quad.step(0.02, ControlTarget((50.0, 0.0, 10.0)), False, lambda n, e, u: 0.0)
    assert list(quad.state.position_neu) == [1.0, 2.0, 0.0]


def test_px4_modes_decode_with_pymavlink():
    px4 = Px4()
    for name, mode in px4.modes.items():
        assert mavutil.interpret_px4_mode(mode.base_flags, mode.custom_mode) == name
    assert px4.decode_set_mode(1, 6, 0)[0].behaviour == Behaviour.OFFBOARD
    assert px4.decode_set_mode(1, 4, 6)[0].name == "LAND"
    mission = px4.decode_set_mode(1, 4, 4)[0]  # MISSION: selectable, but no mission to arm for
    assert mission.name == "MISSION" and not mission.armable
    assert px4.decode_set_mode(1, 4, 7)[0] is None  # RTGS: not in the sim
    # PX4 without RC cannot arm in its manual modes, nor in the modes that prevent arming.
    assert {name for name, m in px4.modes.items() if m.armable} == {"LOITER", "TAKEOFF", "OFFBOARD"}


def test_ardupilot_modes_use_pymavlink_numbers():
    apm = ArduCopter()
    for number, mode in apm.by_custom.items():
        assert mavutil.mode_mapping_acm[number] == mode.name
    assert apm.by_custom[4].name == "GUIDED" and apm.by_custom[9].name == "LAND" and apm.by_custom[6].name == "RTL"
    # Refusal texts as ArduCopter SITL words them (its own mode names: SMARTRTL).
    assert apm.modes["LAND"].arm_refusal == "Arm: LAND mode not armable"
    assert apm.modes["SMART_RTL"].arm_refusal == "Arm: SMARTRTL mode not armable"
    assert apm.modes["AUTO"].arm_refusal == "Arm: Mode requires mission"
    assert apm.modes["GUIDED"].armable and apm.modes["STABILIZE"].armable
    # base_mode as SITL reports it: STABILIZE 81, GUIDED 89 (GUIDED_ENABLED), both + 128 when armed.
    assert (apm.modes["STABILIZE"].base_flags, apm.modes["GUIDED"].base_flags) == (81, 89)


def test_command_names():
    assert command_id("NAV_TAKEOFF") == 22 and command_id("MAV_CMD_COMPONENT_ARM_DISARM") == 400
    assert command_name(21) == "MAV_CMD_NAV_LAND"
    with pytest.raises(ValueError):
        command_id("FLY_TO_THE_MOON")


def test_docstring_examples():
    import doctest

    import sim.boot
    import sim.faults
    import sim.mapfile
    import sim.modes
    import sim.signing
    import sim.world

    for module in (sim.world, sim.modes, sim.faults, sim.boot, sim.mapfile, sim.signing):
        result = doctest.testmod(module)
        assert result.failed == 0 and result.attempted > 0, module.__name__
