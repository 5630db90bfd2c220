"""What the tilt limit leaves once the wind's drag is held (skyroute.flight.tilt), and the path's speeds fitted to
it (SmoothPath.rescheduled)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyroute.flight import path as fp
from skyroute.flight import tilt as tl
from skyroute.flight.preflight import Speeds
from skyroute.vehicle import Autopilot, flight_limits
from tests.test_drag import lean_for

GRAVITY = 9.80665

ARDUCOPTER = Speeds(10.0, 2.25, 1.5, 1.5)  # WPNAV_SPEED, 0.9 and 0.6 x WPNAV_ACCEL
PX4 = Speeds(12.0, 2.7, 2.7, 1.5)  # MPC_XY_VEL_MAX, 0.9 x MPC_ACC_HOR


def flown(budget: tl.TiltBudget, wind_ne, drag_1_s: float, velocities, *, learnt: float | None = None,
          heading_rad: float = 0.3, dt_s: float = 0.1, noise: float = 0.0, seed: int = 0) -> None:
    """Feed ``budget`` level flight through ``velocities`` ((n, e) m/s, one per sample) in a wind: the thrust holds
    the drag ``drag_1_s * (v - wind)`` and makes each change of velocity."""
    rng = np.random.default_rng(seed)
    previous = np.asarray(velocities[0], float)
    for v in velocities:
        v = np.asarray(v, float)
        thrust = drag_1_s * (v - np.asarray(wind_ne, float)) + (v - previous) / dt_s + rng.normal(0.0, noise, 2)
        budget.update(*lean_for(*thrust, heading_rad), heading_rad, (v[0], v[1], 0.0), dt_s, drag_1_s=learnt)
        previous = v


def test_the_winds_lean_is_read_hovering_and_flying_once_the_drag_is_known():
    b = tl.TiltBudget(math.radians(30.0))
    assert b.plan(ARDUCOPTER) is None  # nothing seen yet
    flown(b, (0.0, 12.0), 0.3, [(0.0, 0.0)] * 40, noise=0.2)  # hovering in 12 m/s blowing east
    assert b.wind_lean_ne == pytest.approx((0.0, 3.6), abs=0.2)
    across = [(min(0.4 * i, 8.0), 0.0) for i in range(200)]  # then north, speeding up to 8 m/s
    flown(b, (0.0, 12.0), 0.3, across, learnt=0.3, noise=0.2, seed=1)
    assert b.wind_lean_ne == pytest.approx((0.0, 3.6), abs=0.2)


def test_a_guessed_drag_does_not_pass_a_lean_at_speed_for_a_wind():
    # calm air, drag 0.5/s not yet learnt (0.5 is also the guess, but a guess is not used at speed either way):
    # 10 m/s north leans 5 m/s^2; were it taken for the wind's it would look like a gale from the north
    b = tl.TiltBudget(math.radians(30.0))
    flown(b, (0.0, 0.0), 0.5, [(0.0, 0.0)] * 20 + [(min(0.25 * i, 10.0), 0.0) for i in range(200)])
    b_true = tl.TiltBudget(math.radians(30.0))
    flown(b_true, (0.0, 0.0), 0.8, [(0.0, 0.0)] * 20 + [(min(0.25 * i, 10.0), 0.0) for i in range(200)])
    assert b.wind_lean_ne == pytest.approx((0.0, 0.0), abs=0.05)
    assert b_true.wind_lean_ne == pytest.approx((0.0, 0.0), abs=0.25)  # at most the slow part's share of a wrong guess


def test_intervals_where_the_acceleration_changes_are_left_out():
    b = tl.TiltBudget(math.radians(30.0))
    flown(b, (0.0, 0.0), 0.3, [(0.0, 0.0)] * 30, learnt=0.3)
    before = b.wind_lean_ne
    # the attitude of one instant against a velocity change of another: braking starts between the two samples
    b.update(*lean_for(0.0, 0.0, 0.0), 0.0, (0.0, -0.5, 0.0), 0.1, drag_1_s=0.3)
    assert b.wind_lean_ne == pytest.approx(before)


def test_calm_air_leaves_the_schedule_as_planned():
    for tilt_deg, speeds, drag in ((30.0, ARDUCOPTER, 0.3), (30.0, ARDUCOPTER, 0.0), (45.0, PX4, 0.3)):
        b = tl.TiltBudget(math.radians(tilt_deg))
        flown(b, (0.0, 0.0), drag, [(0.0, 0.0)] * 30, learnt=drag, noise=0.1)
        plan = b.plan(speeds)
        assert plan.speeds == speeds
        assert not plan.binds(speeds.cruise_mps)


def test_a_drag_that_takes_the_whole_tilt_at_cruise_is_capped_below_it():
    # PX4 SIH: drag 1/s, MPC_TILTMAX_AIR 45: 10 m/s takes the whole 9.8 m/s^2; 2.7 m/s^2 stays in reserve
    b = tl.TiltBudget(math.radians(45.0))
    flown(b, (0.0, 0.0), 1.0, [(0.0, 0.0)] * 30, learnt=1.0)
    plan = b.plan(PX4)
    assert plan.speeds == PX4
    caps = plan.caps_mps(np.array([[1.0, 0.0], [0.0, -1.0]]))
    assert caps == pytest.approx([math.sqrt((0.95 * GRAVITY) ** 2 - 2.7**2)] * 2, abs=0.05)  # 8.9 m/s


@pytest.mark.parametrize("wind_ne", [(0.0, 15.0), (-15.0, 0.0), (9.0, -9.0), (5.0, 3.0)])
def test_every_capped_direction_keeps_the_reserve_across_the_track_within_the_limit(wind_ne):
    b = tl.TiltBudget(math.radians(30.0))
    flown(b, wind_ne, 0.3, [(0.0, 0.0)] * 30, learnt=0.3)
    plan = b.plan(ARDUCOPTER)
    limit = 0.95 * GRAVITY * math.tan(math.radians(30.0))
    c = np.array(plan.wind_lean_ne)
    spare = limit - float(np.hypot(*c))
    assert plan.speeds.accel_mps2 == pytest.approx(min(2.25, max(spare / 2, tl.MIN_ACCEL_MPS2)))
    assert plan.speeds.lateral_accel_mps2 == pytest.approx(min(1.5, max(spare / 2, tl.MIN_ACCEL_MPS2)))
    turns = np.linspace(0.0, 2 * math.pi, 360, endpoint=False)
    u = np.column_stack([np.cos(turns), np.sin(turns)])
    caps = plan.caps_mps(u)
    for direction, cap in zip(u, caps, strict=True):
        if cap <= tl.MIN_SPEED_MPS:
            continue
        lean = 0.3 * cap * direction - c  # the steady lean at the cap, plus the reserve across the track
        across = abs(direction[0] * lean[1] - direction[1] * lean[0])
        along = float(direction @ lean)
        assert math.hypot(along, across + plan.reserve_mps2) <= limit + 1e-6
        assert math.hypot(0.3 * (cap + 0.2) - float(direction @ c), across + plan.reserve_mps2) > limit  # the most
    # across and against a 15 m/s wind it is slow; with it, cruise
    if wind_ne == (0.0, 15.0):
        assert plan.binds(10.0)
        north, east, west = plan.caps_mps(np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]))
        assert 4.0 < north < 8.0 and east > 10.0 and 1.0 < west < 4.0


def test_a_wind_beyond_the_reserve_across_the_track_leaves_the_least_speed():
    plan = tl.TiltPlan(ARDUCOPTER, lean_max_mps2=5.0, reserve_mps2=1.0, drag_1_s=0.3, wind_lean_ne=(0.0, 4.5))
    assert plan.caps_mps(np.array([[1.0, 0.0]])) == pytest.approx([tl.MIN_SPEED_MPS])


def test_the_autopilots_tilt_limit_is_read_from_its_parameter():
    assert flight_limits(Autopilot.ARDUPILOT, {"ANGLE_MAX": 2500.0}, our_system=255).max_tilt_deg == 25.0
    assert flight_limits(Autopilot.ARDUPILOT, {}, our_system=255).max_tilt_deg == 30.0  # ArduCopter's default
    assert flight_limits(Autopilot.PX4, {"MPC_TILTMAX_AIR": 35.0}, our_system=255).max_tilt_deg == 35.0
    assert flight_limits(Autopilot.PX4, {}, our_system=255).max_tilt_deg == 45.0


def test_a_rescheduled_path_keeps_its_geometry_and_brakes_before_a_capped_leg():
    waypoints = np.array([[0.0, 0.0, 5.0], [100.0, 0.0, 5.0], [100.0, 100.0, 5.0]])
    path = fp.smooth_path(waypoints, corner_cut_m=1.0, cruise_mps=10.0, accel_mps2=2.0, lateral_accel_mps2=2.0)

    def east_slow(u):  # 3 m/s along the east-west legs, cruise north-south
        return np.where(np.abs(u[:, 1]) > 0.9, 3.0, 50.0)

    slow = path.rescheduled(cruise_mps=10.0, accel_mps2=1.0, lateral_accel_mps2=2.0, vertical_mps=1.5,
                            speed_cap_fn=east_slow)
    assert slow.points is path.points and slow.s_m is path.s_m
    assert slow.waypoint_s_m == pytest.approx(path.waypoint_s_m)
    assert slow.speed_at(10.0) == pytest.approx(10.0)
    assert slow.speed_at(150.0) == pytest.approx(3.0)
    turn_start = float(path.s_m[np.argmax(np.isfinite(path.radius_m))])
    # braking at the new 1 m/s^2 to reach the east leg's 3 m/s: 45.5 m before the corner it is still cruise
    assert path.speed_at(turn_start - 30.0) == pytest.approx(10.0)
    assert slow.speed_at(turn_start - 30.0) < 10.0
    same = path.rescheduled(cruise_mps=10.0, accel_mps2=2.0, lateral_accel_mps2=2.0, vertical_mps=1.5)
    assert same.segment_speed_mps == pytest.approx(path.segment_speed_mps)
    assert same.point_speed_mps == pytest.approx(path.point_speed_mps)
