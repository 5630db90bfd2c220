"""The drag learnt from attitude and velocity (skyroute.flight.drag) and the follower's acceleration feed-forward."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyroute.flight import drag as dg
from skyroute.flight import follower as fw
from skyroute.flight import path as fp

G = dg.GRAVITY_MPS2


def lean_for(accel_n: float, accel_e: float, yaw_rad: float) -> tuple[float, float]:
    """Roll and pitch (rad) that give this horizontal thrust acceleration at this heading (level flight)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    forward, right = c * accel_n + s * accel_e, -s * accel_n + c * accel_e
    pitch = -math.atan(forward / G)
    return math.atan(right / G * math.cos(pitch)), pitch


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, 200.0])
def test_thrust_acceleration_inverts_the_lean_at_any_heading(yaw_deg):
    roll, pitch = lean_for(3.0, -4.0, math.radians(yaw_deg))
    assert dg.thrust_accel_ne(roll, pitch, math.radians(yaw_deg)) == pytest.approx((3.0, -4.0))


def test_drag_is_fitted_through_turns_speed_changes_and_noise():
    rng = np.random.default_rng(3)
    d = dg.DragEstimate()
    v = np.array([0.0, 0.0])
    for step in range(600):  # 60 s: speeding up, then round a circle at 9 m/s, nose wherever
        t = step * 0.1
        want = 9.0 * np.array([math.cos(t / 8.0), math.sin(t / 8.0)]) * min(1.0, t / 10.0)
        accel = (want - v) / 0.1
        thrust = accel + 0.7 * v + rng.normal(0.0, 0.5, 2)  # drag 0.7/s, noisy attitude
        yaw = rng.uniform(0, 2 * math.pi)
        roll, pitch = lean_for(*thrust, yaw)
        v = want
        d.update(roll, pitch, yaw, (v[0], v[1], 0.0), 0.1)
    assert d.k_1_s == pytest.approx(0.7, abs=0.03)


def test_no_drag_is_claimed_before_enough_level_flight_at_varied_speeds():
    d = dg.DragEstimate(min_time_s=3.0)
    for _ in range(100):
        d.update(*lean_for(0.5, 0.0, 0.0), 0.0, (0.5, 0.0, 0.0), 0.1)  # too slow: the lean is mostly noise there
        d.update(*lean_for(8.0, 0.0, 0.0), 0.0, (8.0, 0.0, 2.5), 0.1)  # climbing: the thrust is not holding it level
        d.update(math.nan, 0.0, 0.0, (8.0, 0.0, 0.0), 0.1)  # no attitude
    assert d.k_1_s == 0.0
    for _ in range(100):  # 10 s at one speed: a drag of 1/s, or a headwind of 8 m/s and a drag of 0.5/s ...
        d.update(*lean_for(8.0, 0.0, 0.0), 0.0, (8.0, 0.0, 0.0), 0.1)
    assert d.k_1_s == 0.0
    roll, pitch = lean_for(4.0, 0.0, 0.0)
    d.update(roll, pitch, 0.0, (4.0, 0.0, 0.0), 0.0)  # a gap: no change of velocity to take from the lean
    for _ in range(12):  # ... until the speed changes: 1.2 s at 4 m/s, leaning half as much (spread 16)
        d.update(roll, pitch, 0.0, (4.0, 0.0, 0.0), 0.1)
    assert d.k_1_s == 0.0
    for _ in range(6):
        d.update(roll, pitch, 0.0, (4.0, 0.0, 0.0), 0.1)
    assert d.k_1_s == pytest.approx(1.0)


def test_a_vehicle_leaning_backwards_claims_no_negative_drag():
    d = dg.DragEstimate()
    for speed in (8.0, 4.0, 8.0, 4.0):
        roll, pitch = lean_for(-0.25 * speed, 0.0, 0.0)
        d.update(roll, pitch, 0.0, (speed, 0.0, 0.0), 0.0)  # a gap between the speeds
        for _ in range(30):
            d.update(roll, pitch, 0.0, (speed, 0.0, 0.0), 0.1)
    assert d.k_1_s == 0.0


def test_a_strong_wind_along_the_only_leg_flown_does_not_pass_for_drag():
    # drag 0.3/s, a 15 m/s wind from the east; flown east into it, speeding up to 4 m/s at 1 m/s^2 and holding it:
    # the lean is mostly the wind's (a fit pulled towards no wind claimed 1.65/s from such a leg in our sim)
    rng = np.random.default_rng(7)
    d = dg.DragEstimate()
    wind, v = np.array([0.0, -15.0]), np.zeros(2)
    for step in range(400):
        dv = np.array([0.0, min(0.1, 4.0 - v[1])])
        thrust = 0.3 * (v + dv - wind) + dv / 0.1 + rng.normal(0.0, 0.3, 2)
        v = v + dv
        d.update(*lean_for(*thrust, math.pi / 2), math.pi / 2, (v[0], v[1], 0.0), 0.1)
        assert d.k_1_s == 0.0 or d.k_1_s == pytest.approx(0.3, abs=0.1), step


def test_steer_sends_the_drag_lean_along_the_feedforward_velocity():
    path = fp.smooth_path(np.array([[0.0, 0.0, 10.0], [100.0, 100.0, 10.0]]), cruise_mps=10.0, accel_mps2=3.0)
    kwargs = dict(s_m=30.0, ref_s_m=0.0, position=(21.0, 21.0, 10.0), velocity=(6.0, 6.0, 0.0), accel_mps2=3.0,
                  velocity_lag_s=0.0, heading_rad=0.0, ahead_s=0.2)
    without = fw.steer(path, **kwargs)
    with_drag = fw.steer(path, drag_1_s=0.8, **kwargs)
    assert without.acceleration is None
    assert with_drag.velocity == pytest.approx(without.velocity)  # the schedule is unchanged
    assert with_drag.acceleration == pytest.approx([0.8 * without.velocity[0], 0.8 * without.velocity[1], 0.0])
    at_goal = fw.steer(path, drag_1_s=0.8, **{**kwargs, "s_m": path.length_m - 0.5,
                                                "position": (99.6, 99.6, 10.0)})
    assert at_goal.velocity is None and at_goal.acceleration is None  # a plain position: nothing to lean into


def test_a_wind_does_not_pass_for_drag():
    # drag 0.3/s against the air, a 6 m/s wind blowing east; flown mostly east (downwind), with jogs north and
    # south: the lean into the air is 0.3 x (v - wind); the wind's part is the autopilot's integrator's to hold
    rng = np.random.default_rng(5)
    d = dg.DragEstimate()
    wind = np.array([0.0, 6.0])
    legs = [((0.0, 8.0), 20.0), ((6.0, 0.0), 5.0), ((0.0, 8.0), 20.0), ((-6.0, 0.0), 5.0), ((0.0, 8.0), 10.0)]
    v = np.array(legs[0][0])
    for velocity, seconds in legs:
        for _ in range(int(seconds / 0.1)):  # turning onto the leg at 4 m/s^2 at most
            step = np.array(velocity) - v
            step *= min(1.0, 0.4 / max(np.linalg.norm(step), 1e-9))
            thrust = 0.3 * (v + step - wind) + step / 0.1 + rng.normal(0.0, 0.3, 2)
            v = v + step
            yaw = math.atan2(v[1], v[0])
            d.update(*lean_for(*thrust, yaw), yaw, (v[0], v[1], 0.0), 0.1)
    assert d.k_1_s == pytest.approx(0.3, abs=0.03)
