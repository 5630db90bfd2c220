"""The sim's obstacle sensors: exact sector minima against a brute-force ray fan, and the MAVLink each personality
streams (PX4 OBSTACLE_DISTANCE, ArduPilot DISTANCE_SENSOR per proximity sector, the downward rangefinder)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from sim import SimConfig
from sim.sensors import ObstacleSensor, SensorConfig, sector_minima
from sim.world import CityMap

from .conftest import SIM_LAT0, SIM_LON0, wait_sim


def _ray_entry(origin, bearings, lo, hi) -> np.ndarray:
    """Entry distance (m) of each ray into each rectangle by the slab method, shape (rays, boxes); inf if none."""
    d = np.stack([np.cos(bearings), np.sin(bearings)], axis=1)[:, None, :]  # (rays, 1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo[None] - np.asarray(origin, float)) / d
        t2 = (hi[None] - np.asarray(origin, float)) / d
    near = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf).max(axis=2)  # nan: a ray along a slab's edge line
    far = np.nan_to_num(np.maximum(t1, t2), nan=np.inf).min(axis=2)
    return np.where((near <= far) & (far >= 0), np.maximum(near, 0.0), np.inf)


def _brute_force(lo, hi, origin, sectors, first_centre, range_m, rays=400):
    """Minimum over a dense fan of rays in each sector (an upper bound of the exact minimum, converging to it)."""
    width = 2 * math.pi / sectors
    centres = first_centre + width * np.arange(sectors)
    bearings = (centres[:, None] + np.linspace(-width / 2, width / 2, rays)[None]).ravel()
    out = _ray_entry(origin, bearings, lo, hi).min(axis=1, initial=np.inf).reshape(sectors, rays).min(axis=1)
    out[out > range_m] = np.inf
    return out


@pytest.mark.parametrize("sectors,first_centre", [(72, 0.0), (8, 0.0), (8, math.radians(30.0))])
def test_sector_minima_match_a_dense_ray_fan_on_random_boxes(sectors, first_centre):
    rng = np.random.default_rng(sectors)
    centres = rng.uniform(-25, 25, size=(12, 2))
    halves = rng.uniform(0.5, 4, size=(12, 2))
    keep = np.all(np.abs(centres) > halves + 0.5, axis=1)  # the sensor at the origin is outside every box
    lo, hi = centres[keep] - halves[keep], centres[keep] + halves[keep]
    exact = sector_minima(lo, hi, 0.0, 0.0, sectors, first_centre, 30.0)
    dense = _brute_force(lo, hi, (0.0, 0.0), sectors, first_centre, 30.0)
    both = np.isfinite(dense)
    assert (np.isfinite(exact) == both).all() or np.all(exact[~both] <= 30.0)
    # The exact minimum is never above the fan's, and the fan (400 rays a sector) is within its chord error.
    assert np.all(exact[both] <= dense[both] + 1e-9)
    width = 2 * math.pi / sectors / 399
    assert np.all(dense[both] - exact[both] <= dense[both] * width * 2 + 1e-6)


def test_boxes_beyond_the_range_change_no_sector():
    near_lo, near_hi = np.array([[9.0, -1.0], [-5.0, 3.0]]), np.array([[11.0, 1.0], [-3.0, 6.0]])
    far_lo, far_hi = np.array([[40.0, -2.0], [-3.0, 31.0]]), np.array([[45.0, 2.0], [3.0, 35.0]])
    both = sector_minima(np.vstack([near_lo, far_lo]), np.vstack([near_hi, far_hi]), 0.0, 0.0, 72, 0.0, 30.0)
    assert both.tolist() == sector_minima(near_lo, near_hi, 0.0, 0.0, 72, 0.0, 30.0).tolist()
    assert np.isfinite(both).sum() >= 4
    assert np.isinf(sector_minima(far_lo, far_hi, 0.0, 0.0, 72, 0.0, 30.0)).all()


def test_sector_minima_see_the_nearest_face_point_between_two_edge_rays():
    # A long wall 10 m east, from north -50 to 50: the east 45 degree sector's nearest point is the wall's foot
    # (10 m), which neither of that sector's edge rays (at 67.5 and 112.5 degrees, 10.8 m) touches.
    lo, hi = np.array([[-50.0, 10.0]]), np.array([[50.0, 11.0]])
    d = sector_minima(lo, hi, 0.0, 0.0, 8, 0.0, 30.0)
    assert d[2] == pytest.approx(10.0)
    assert d[1] == pytest.approx(10.0 / math.sin(math.radians(67.5)))  # its lower edge ray at 22.5..67.5
    assert np.isinf(d[5]) and np.isinf(d[6])  # west: nothing


def _city(rows):
    return CityMap(SIM_LAT0, SIM_LON0, np.array(rows, float))


def test_sensor_ignores_boxes_below_or_above_the_sensor_plane_and_beyond_range():
    city = _city([[10, 0, 1, 1, 1, 1],      # 0..2 m tall: below a sensor at 5 m
                  [0, 10, 20, 1, 1, 5],     # 15..25 m: above
                  [0, -40, 5, 1, 1, 5],     # in the plane but 39 m away
                  [-10, 0, 5, 1, 1, 5]])    # in the plane, 9 m south
    s = ObstacleSensor(SensorConfig(), city, "px4", seed=0)
    s.sample(0.0, np.array([0.0, 0.0, 5.0]), 0.0, np.array([0.0, 0.0, 4.7]))
    d = s.distances_m
    assert d[36] == pytest.approx(9.0)  # bearing 180 degrees
    assert np.isinf(np.delete(d, [35, 36, 37])).all()
    assert s.down_m == pytest.approx(4.7)  # the ground below (the low box is 10 m away)


def test_ardupilot_sectors_are_relative_to_the_heading():
    city = _city([[0, 20, 5, 2, 2, 5]])  # 18 m east
    s = ObstacleSensor(SensorConfig(), city, "ardupilot", seed=0)
    s.sample(0.0, np.array([0.0, 0.0, 5.0]), math.radians(90.0), np.zeros(3))  # nose east
    assert s.distances_m[0] == pytest.approx(18.0)
    s.sample(1.0, np.array([0.0, 0.0, 5.0]), math.radians(180.0), np.zeros(3))  # nose south: east is left (270)
    assert s.distances_m[6] == pytest.approx(18.0) and np.isinf(s.distances_m[0])


def test_dropout_and_noise_have_their_rates_and_spread():
    city = _city([[0, 20, 5, 200, 2, 5]])  # a 400 m wall 18 m east: many sectors see it
    s = ObstacleSensor(SensorConfig(noise_m=0.5, dropout_pct=10.0), city, "px4", seed=3)
    exact = sector_minima(city.lo[:, :2], city.hi[:, :2], 0.0, 0.0, 72, 0.0, 30.0)
    lost, errors = 0, []
    for k in range(200):
        s.sample(k * 0.1, np.array([0.0, 0.0, 5.0]), 0.0, np.zeros(3))
        lost += int(np.isnan(s.distances_m).sum())
        ok = np.isfinite(s.distances_m) & np.isfinite(exact)
        errors.extend((s.distances_m[ok] - exact[ok]).tolist())
    assert 0.08 < lost / (200 * 72) < 0.12
    assert np.std(errors) == pytest.approx(0.5, rel=0.15) and abs(np.mean(errors)) < 0.05


def test_px4_streams_obstacle_distance_north_aligned_in_centimetres(sim_start, sim_connect):
    sim = sim_start(strict=True)  # the conftest building: north 25..35, east -5..5, 25 m north of home
    c = sim_connect(sim)
    msg = c.wait_for("OBSTACLE_DISTANCE", timeout_s=10)
    assert msg.frame == M.MAV_FRAME_GLOBAL and msg.increment == 5 and msg.increment_f == 5.0
    assert (msg.min_distance, msg.max_distance) == (20, 3000)
    d = list(msg.distances)
    assert d[0] == 2500  # the south face, dead ahead
    # East of north the face is still seen up to atan(5 / 25) = 11.3 degrees: sectors 0..2 (2.5..12.5 deg).
    assert d[1] == round(25 / math.cos(math.radians(2.5)) * 100) and d[2] < 3000 and d[3] == 3001
    assert all(v == 3001 for v in d[3:70])
    down = c.wait_for("DISTANCE_SENSOR", lambda m: m.orientation == M.MAV_SENSOR_ROTATION_PITCH_270, timeout_s=5)
    assert down.current_distance == 20  # on the ground: the minimum range
    assert sim.report()["sensor"]["scans"] > 0


def test_ardupilot_sends_proximity_sectors_only_when_asked_and_only_once_valid(sim_start, sim_connect):
    sim = sim_start(autopilot="ardupilot")
    c = sim_connect(sim)
    wait_sim(sim, 2.0)
    assert not c.of_type("DISTANCE_SENSOR") and not c.of_type("OBSTACLE_DISTANCE")
    c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_SYS_STATUS, 200_000)  # ArduPilot: only when asked
    ranging = M.MAV_SYS_STATUS_SENSOR_PROXIMITY | M.MAV_SYS_STATUS_SENSOR_LASER_POSITION
    assert c.wait_for("SYS_STATUS").onboard_control_sensors_present & ranging == ranging  # how a client knows to ask
    ack = c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_DISTANCE_SENSOR, 100_000)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    since = c.mark()
    c.wait_for("DISTANCE_SENSOR", lambda m: m.id == 10, since=since, timeout_s=10)
    wait_sim(sim, 1.0)
    got = c.of_type("DISTANCE_SENSOR", since)
    sectors = {m.id: m for m in got if m.id >= 10}
    assert set(sectors) == {10}  # nose north (yaw 0): only the front sector ever had an obstacle
    front = sectors[10]
    assert front.orientation == M.MAV_SENSOR_ROTATION_NONE and front.current_distance == 2500
    assert front.type == M.MAV_DISTANCE_SENSOR_LASER and front.max_distance == 3000
    assert any(m.id == 0 and m.orientation == M.MAV_SENSOR_ROTATION_PITCH_270 for m in got)


def test_sensor_off_streams_nothing_and_refuses_the_interval(sim_start, sim_connect):
    sim = sim_start(strict=True, sensor=SensorConfig(enabled=False))
    c = sim_connect(sim)
    wait_sim(sim, 2.0)
    assert not c.of_type("OBSTACLE_DISTANCE")
    ranging = M.MAV_SYS_STATUS_SENSOR_PROXIMITY | M.MAV_SYS_STATUS_SENSOR_LASER_POSITION
    assert not c.wait_for("SYS_STATUS").onboard_control_sensors_present & ranging
    ack = c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_OBSTACLE_DISTANCE, 100_000)
    assert ack.result == M.MAV_RESULT_FAILED
    assert sim.report()["sensor"] == {"enabled": False}


def test_sensor_options_are_range_checked():
    with pytest.raises(ValueError, match="dropout"):
        SimConfig(sensor=SensorConfig(dropout_pct=120))
    with pytest.raises(ValueError, match="range"):
        SensorConfig(range_m=0.1)
