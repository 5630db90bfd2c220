"""Sensor messages encoded to bytes and decoded as the link does, translated into SI readings."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyroute.vehicle.sensors import HeightReading, RangeScan, SensorFeed, translate_sensor


def _wire(msg):
    """``msg`` packed into MAVLink 2 bytes and parsed back (what the link's reader gets)."""
    sender = M.MAVLink(io.BytesIO(), 1, 1)
    data = msg.pack(sender)
    (decoded,) = M.MAVLink(io.BytesIO(), 255, 191).parse_buffer(data)
    return decoded


def _obstacle_distance(distances, frame=M.MAV_FRAME_GLOBAL, increment=5, increment_f=5.0, offset=0.0):
    return _wire(M.MAVLink_obstacle_distance_message(3_500_000, M.MAV_DISTANCE_SENSOR_LASER, distances, increment,
                                                     20, 3000, increment_f=increment_f, angle_offset=offset,
                                                     frame=frame))


def test_obstacle_distance_north_aligned_sectors_in_metres():
    cells = [65535] + [1234, 3001, 3000, 0] + [3001] * 67
    scan = translate_sensor(_obstacle_distance(cells), 7.0, heading_rad=1.0)  # heading ignored: north frame
    assert isinstance(scan, RangeScan) and scan.source == "OBSTACLE_DISTANCE"
    assert np.degrees(scan.bearings_rad[:3]).round(6).tolist() == [0.0, 5.0, 10.0]
    assert math.isnan(scan.distances_m[0])  # UINT16_MAX: unknown
    assert scan.distances_m[1] == pytest.approx(12.34)
    assert math.isinf(scan.distances_m[2])  # max + 1: nothing there
    assert scan.distances_m[3] == pytest.approx(30.0)  # exactly max is still an obstacle at max for PX4
    assert scan.distances_m[4] == 0.0
    assert (scan.min_range_m, scan.max_range_m, scan.time_s, scan.received_s) == (0.2, 30.0, 3.5, 7.0)
    assert scan.half_width_rad == pytest.approx(math.radians(2.5))


def test_obstacle_distance_in_the_body_frame_turns_with_the_heading_and_needs_one():
    msg = _obstacle_distance([1000] * 72, frame=M.MAV_FRAME_BODY_FRD, offset=-10.0)
    scan = translate_sensor(msg, 0.0, heading_rad=math.radians(90.0))
    assert math.degrees(scan.bearings_rad[0]) == pytest.approx(80.0)
    assert translate_sensor(msg, 0.0, heading_rad=math.nan) is None


def test_obstacle_distance_takes_increment_f_and_only_one_turn_of_sectors():
    scan = translate_sensor(_obstacle_distance([500] * 72, increment=10, increment_f=10.0), 0.0, 0.0)
    assert len(scan.bearings_rad) == 36 and scan.half_width_rad == pytest.approx(math.radians(5.0))


@pytest.mark.parametrize("orientation,heading_deg,bearing_deg", [
    (M.MAV_SENSOR_ROTATION_NONE, 0.0, 0.0), (M.MAV_SENSOR_ROTATION_YAW_45, 0.0, 45.0),
    (M.MAV_SENSOR_ROTATION_YAW_315, 90.0, 45.0), (M.MAV_SENSOR_ROTATION_YAW_180, 270.0, 90.0)])
def test_proximity_distance_sensor_sector_bearing_from_the_heading(orientation, heading_deg, bearing_deg):
    msg = _wire(M.MAVLink_distance_sensor_message(1200, 20, 3000, 850, M.MAV_DISTANCE_SENSOR_LASER, 11,
                                                  orientation, 0))
    scan = translate_sensor(msg, 0.0, math.radians(heading_deg))
    assert math.degrees(scan.bearings_rad[0]) == pytest.approx(bearing_deg % 360.0)
    assert scan.distances_m[0] == pytest.approx(8.5) and scan.time_s == pytest.approx(1.2)
    assert scan.half_width_rad == pytest.approx(math.radians(22.5))


def test_proximity_sector_at_its_maximum_is_empty_and_unknown_is_nan():
    empty = _wire(M.MAVLink_distance_sensor_message(0, 20, 3000, 3000, 0, 10, M.MAV_SENSOR_ROTATION_NONE, 0))
    unknown = _wire(M.MAVLink_distance_sensor_message(0, 20, 3000, 65535, 0, 10, M.MAV_SENSOR_ROTATION_NONE, 0))
    assert math.isinf(translate_sensor(empty, 0.0, 0.0).distances_m[0])
    assert math.isnan(translate_sensor(unknown, 0.0, 0.0).distances_m[0])


def test_downward_rangefinder_is_a_height_and_upward_is_ignored():
    down = _wire(M.MAVLink_distance_sensor_message(500, 20, 4000, 523, 0, 0, M.MAV_SENSOR_ROTATION_PITCH_270, 0))
    reading = translate_sensor(down, 0.0, math.nan)  # needs no heading
    assert isinstance(reading, HeightReading) and reading.height_m == pytest.approx(5.23)
    up = _wire(M.MAVLink_distance_sensor_message(500, 20, 4000, 523, 0, 19, M.MAV_SENSOR_ROTATION_PITCH_90, 0))
    assert translate_sensor(up, 0.0, 0.0) is None


def test_feed_queues_readings_counts_scans_and_says_when_streaming():
    now = [100.0]
    feed = SensorFeed(keep=2, clock=lambda: now[0])
    assert not feed.streaming
    assert not feed.handle(_wire(M.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3)), now[0], 0.0)
    for _ in range(3):
        assert feed.handle(_obstacle_distance([1000] * 72), now[0], 0.0)
    assert feed.streaming and feed.scans == 3 and feed.dropped == 1
    assert len(feed.drain()) == 2 and feed.drain() == []
    now[0] += 2.5
    assert not feed.streaming
    assert not feed.wait(0.01)


def test_feed_stamps_scans_with_the_local_position_they_arrived_at():
    feed = SensorFeed()
    feed.handle(_obstacle_distance([1000] * 72), 1.0, 0.0, (12.5, -3.0), -4.5)
    feed.handle(_obstacle_distance([1000] * 72), 1.1, 0.0, (math.nan, math.nan))  # no position yet
    first, second = feed.drain()
    assert first.local_ne == (12.5, -3.0) and first.local_down_m == -4.5
    assert second.local_ne is None and second.local_down_m is None


def test_feed_stamps_scans_with_three_times_the_receivers_accuracy_as_their_position_error():
    feed = SensorFeed()
    feed.handle(_obstacle_distance([1000] * 72), 1.0, 0.0, (12.5, -3.0), -4.5, horizontal_accuracy_m=0.9)
    feed.handle(_obstacle_distance([1000] * 72), 1.1, 0.0, (12.5, -3.0), -4.5)  # accuracy unknown
    first, second = feed.drain()
    assert first.position_error_m == pytest.approx(2.7) and second.position_error_m == 0.0


def test_feed_places_a_scan_where_the_vehicle_was_at_the_scans_own_time():
    # the scan was taken at 3.5 s of the autopilot's clock; the latest position is from 3.2 s, flying 10 m/s north
    # and sinking 1 m/s: the scan was read 3 m further north and 0.3 m lower than that position
    feed = SensorFeed()
    moving = dict(local_time_s=3.2, local_velocity_ned=(10.0, 0.0, 1.0))
    feed.handle(_obstacle_distance([1000] * 72), 1.0, 0.0, (12.5, -3.0), -4.5, **moving)
    far = dict(local_time_s=1.0, local_velocity_ned=(10.0, 0.0, 1.0))  # 2.5 s apart: another clock, not moved
    feed.handle(_obstacle_distance([1000] * 72), 1.1, 0.0, (12.5, -3.0), -4.5, **far)
    near, kept = feed.drain()
    assert near.local_ne == pytest.approx((15.5, -3.0)) and near.local_down_m == pytest.approx(-4.2)
    assert kept.local_ne == (12.5, -3.0) and kept.local_down_m == -4.5


def _measured(readings):
    """The readings an autopilot sent, without the never-sent proximity sectors read as empty."""
    return [r for r in readings if not np.isinf(r.distances_m).all()]


def test_proximity_sectors_never_sent_read_empty_and_those_that_dropped_out_stay_unknown():
    # ArduPilot sends a sector only once it has had a valid reading: at 1.0 s the nose (8.5 m) and the right (10 m)
    feed = SensorFeed()
    for orientation, cm in ((M.MAV_SENSOR_ROTATION_NONE, 850), (M.MAV_SENSOR_ROTATION_YAW_90, 1000)):
        feed.handle(_wire(M.MAVLink_distance_sensor_message(1000, 20, 3000, cm, 0, 10, orientation, 0)), 1.0,
                    math.radians(90.0))
    assert len(feed.drain()) == 2  # what the rest of that sample holds is known once the next one starts
    # at 1.1 s only the right: the six never sent in the first sample are empty (nose east: 90 and 180 were sent)
    for time_ms in (1100, 1200):
        feed.handle(_wire(M.MAVLink_distance_sensor_message(time_ms, 20, 3000, 1000, 0, 10,
                                                            M.MAV_SENSOR_ROTATION_YAW_90, 0)), 1.1, math.radians(90.0))
        got = feed.drain()
        empty = sorted(round(math.degrees(r.bearings_rad[0])) for r in got if np.isinf(r.distances_m).all())
        assert len(_measured(got)) == 1 and empty == [0, 45, 135, 225, 270, 315]  # the nose (90) dropped out
        assert all(r.time_s == pytest.approx(time_ms / 1000.0 - 0.1) for r in got if np.isinf(r.distances_m).all())


def test_heading_relative_sectors_are_dropped_while_the_vehicle_yaws_fast_and_kept_once_it_holds():
    feed = SensorFeed()

    def sector(time_ms):
        return _wire(M.MAVLink_distance_sensor_message(time_ms, 20, 3000, 850, 0, 10, M.MAV_SENSOR_ROTATION_NONE, 0))

    feed.handle(sector(1000), 1.0, 0.0)
    feed.handle(sector(1100), 1.1, math.radians(9.0))  # 90 deg/s: turning
    feed.handle(sector(1200), 1.2, math.radians(18.0))
    assert feed.turning and feed.turning_dropped == 2
    feed.handle(sector(1800), 1.8, math.radians(18.0))  # held for 0.6 s
    north = _obstacle_distance([1000] * 72)  # north-aligned scans never depend on the heading
    feed.handle(north, 1.9, math.radians(18.0))
    assert not feed.turning and len(_measured(feed.drain())) == 3


def test_a_heading_relative_sector_is_turned_by_the_heading_at_its_own_time_with_a_small_allowance():
    # nose at 90 degrees sampled at 1.0 s, yawing 20 deg/s; the sector read at 1.1 s looked 2 degrees further on
    feed = SensorFeed()
    sector = _wire(M.MAVLink_distance_sensor_message(1100, 20, 3000, 850, 0, 10, M.MAV_SENSOR_ROTATION_NONE, 0))
    feed.handle(sector, 1.15, math.radians(90.0), heading_time_s=1.0, yaw_rate_rad_s=math.radians(20.0))
    (scan,) = _measured(feed.drain())
    assert math.degrees(scan.bearings_rad[0]) == pytest.approx(92.0)
    assert math.degrees(scan.bearing_error_rad) == pytest.approx(3.0 + 20.0 * 0.2)  # not the blind 15 degrees
    held = _wire(M.MAVLink_distance_sensor_message(2000, 20, 3000, 850, 0, 10, M.MAV_SENSOR_ROTATION_NONE, 0))
    feed.handle(held, 2.05, math.radians(90.0), heading_time_s=2.0, yaw_rate_rad_s=0.0)
    (steady,) = _measured(feed.drain())
    assert math.degrees(steady.bearing_error_rad) == pytest.approx(3.0)
    # without the heading's time (or a second apart: another clock) the latest heading stands, with 15 degrees
    feed.handle(held, 2.1, math.radians(90.0))
    feed.handle(held, 2.2, math.radians(90.0), heading_time_s=0.5, yaw_rate_rad_s=0.0)
    for blind in _measured(feed.drain()):
        assert math.degrees(blind.bearings_rad[0]) == pytest.approx(90.0)
        assert math.degrees(blind.bearing_error_rad) == pytest.approx(15.0)
