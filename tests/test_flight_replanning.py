"""The mission's sensing step with a fake vehicle and a real live layer: readings in, blockages out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from skyroute.flight.replanning import ReplanRecord, Sensing, braking_distance_m, can_turn_in_time
from skyroute.planning.livemap import LiveMap
from skyroute.planning.replan import Blockage, Replanner


@dataclass
class Scan:
    bearings_rad: np.ndarray
    half_width_rad: float
    distances_m: np.ndarray
    max_range_m: float
    received_s: float


@dataclass
class Height:
    height_m: float
    received_s: float


class FakeVehicle:
    def __init__(self):
        self.queue: list = []
        self.sensing = True

    def sensor_readings(self):
        out, self.queue = self.queue, []
        return out


def _wall_ahead(distance_m: float, received_s: float) -> Scan:
    d = np.full(72, np.inf)
    d[0] = distance_m
    return Scan(np.radians(np.arange(0.0, 360.0, 5.0)), math.radians(2.5), d, 30.0, received_s)


def _sensing(now):
    live = LiveMap(np.zeros((80, 40), bool), None, 0, 0, safety_m=3.0, confirm_hits=2)
    vehicle = FakeVehicle()
    return Sensing(vehicle, Replanner(live, (75.5, 20.5), 5.0), clock=lambda: now[0]), vehicle, live


def test_a_wall_seen_twice_blocks_the_path_and_the_latency_runs_from_the_first_reading():
    now = [10.0]
    sensing, vehicle, _ = _sensing(now)
    path = np.array([[75.5, 20.5]])
    vehicle.queue = [_wall_ahead(20.0, 9.99), Height(5.0, 9.99)]
    assert sensing.step((5.5, 20.5), path) is None  # one scan: not confirmed yet
    vehicle.queue = [_wall_ahead(20.0, 10.05)]
    now[0] = 10.06
    block = sensing.step((5.5, 20.5), path)
    # The hit at north 25.5 is cell 25..26; its 3 m margin starts at cell 22..23's south edge, 16.5 m ahead.
    assert block is not None and block.reason == "margin" and block.along_m == pytest.approx(16.5)
    assert sensing.latency_ms() == pytest.approx(10.0)  # from the reading at 10.05 (the first was all clear)
    assert sensing.scans == 2 and sensing.heights == 1
    assert len(sensing.discovered_ne()) > 0


def test_with_replanning_off_or_no_sensor_nothing_is_checked_but_readings_are_drained():
    now = [0.0]
    sensing, vehicle, live = _sensing(now)
    sensing.obstacles = None
    vehicle.queue = [_wall_ahead(10.0, 0.0)] * 3
    assert sensing.step((5.5, 20.5), np.array([[75.5, 20.5]])) is None and vehicle.queue == []
    assert live.scans == 0 and not sensing.active
    sensing2, vehicle2, _ = _sensing(now)
    vehicle2.sensing = False
    assert not sensing2.active


def test_replan_records_describe_themselves_in_one_line():
    rec = ReplanRecord(1.0, 10.0, 20.0, "margin", 17.0, 4.2, 9.8, False, np.zeros((3, 4)))
    line = rec.describe()
    assert "\n" not in line and "17.0 m ahead" in line and "4.2 ms" in line and "9.8 ms" in line


def test_braking_decides_whether_to_turn_without_stopping():
    assert braking_distance_m(10.0, 2.5, reaction_s=0.0) == pytest.approx(20.0)
    far, near = Blockage("margin", 25.0, (0.0, 0.0)), Blockage("margin", 8.0, (0.0, 0.0))
    assert can_turn_in_time(far, 10.0, 3.0, 5.0) and not can_turn_in_time(near, 10.0, 3.0, 5.0)
    assert can_turn_in_time(near, 2.0, 3.0, 5.0) and can_turn_in_time(None, 20.0, 1.0, 5.0)
    assert not can_turn_in_time(Blockage("blocked", 2.0, (0.0, 0.0)), 1.0, 3.0, 5.0)


@dataclass
class FakeScan:
    """The fields of a :class:`~skyroute.vehicle.sensors.RangeScan` the sensing step reads."""

    local_ne: tuple | None = (0.0, 0.0)
    local_down_m: float | None = None
    bearings_rad: np.ndarray = field(default_factory=lambda: np.zeros(1))
    half_width_rad: float = 0.1
    distances_m: np.ndarray = field(default_factory=lambda: np.array([5.0]))
    max_range_m: float = 30.0
    received_s: float = 0.0
    position_error_m: float = 0.0


class PlacesMap:
    """An obstacle map that records where each scan was placed (map north, east m)."""

    def __init__(self):
        self.at = []

    def add_scan(self, north_m, east_m, *rest):
        self.at.append((north_m, east_m))


class SensingVehicle:
    sensing = True

    def __init__(self, *scans: FakeScan):
        self.scans = list(scans)

    def sensor_readings(self):
        return self.scans


def test_a_scan_is_placed_where_it_arrived_not_where_the_mission_reads_it():
    obstacles = PlacesMap()
    vehicle = SensingVehicle(FakeScan((10.0, 20.0)), FakeScan(None))
    Sensing(vehicle, obstacles, lambda: 0.0).drain((55.0, 66.0), offset_ne=(100.0, -50.0))
    assert obstacles.at == [(110.0, -30.0), (55.0, 66.0)]


def test_scans_from_below_the_flight_altitude_are_dropped():
    obstacles = PlacesMap()
    # climbing through 2 m, at 4.5 m, at 5.2 m (local down, map = local - 1 m)
    vehicle = SensingVehicle(*(FakeScan(local_down_m=down) for down in (-1.0, -3.5, -4.2)))
    sensing = Sensing(vehicle, obstacles, lambda: 0.0)
    sensing.drain((0.0, 0.0), (0.0, 0.0), offset_down_m=-1.0, min_altitude_m=4.0)
    assert len(obstacles.at) == 2 and sensing.low_scans == 1


def test_scans_from_below_the_flight_altitude_still_place_the_vehicle_at_their_own_altitude():
    # the descent to land: the layer leaves those scans out, the fix matches them against the map where they were
    # read, so its correction follows the estimate's drift down to the touchdown
    class RecordingFix:
        def __init__(self):
            self.calls = []

        def observe(self, time_s, north_m, east_m, *rest, bearing_error_rad=0.0, altitude_m=None):
            self.calls.append((north_m, east_m, altitude_m))

        correction_ne, bound_m = (0.0, 0.0), 1.0

        def describe(self):
            return ""

    obstacles, fix = PlacesMap(), RecordingFix()
    scans = [FakeScan((10.0, 20.0), local_down_m=down, position_error_m=3.0) for down in (-1.0, -5.2)]
    sensing = Sensing(SensingVehicle(*scans, FakeScan(None, local_down_m=-2.0)), obstacles, lambda: 0.0, fix=fix)
    sensing.drain((0.0, 0.0), (100.0, -50.0), offset_down_m=-1.0, min_altitude_m=4.0)
    assert obstacles.at == [(110.0, -30.0)] and sensing.low_scans == 2  # only the one at 6.2 m in the layer
    assert fix.calls == [(110.0, -30.0, 2.0), (110.0, -30.0, None)]  # the unstamped one places nothing


def test_single_sectors_read_at_one_place_make_one_layer_update_and_whole_scans_their_own():
    calls = []

    class Map:
        def add_scan(self, north_m, east_m, bearings, half, distances, max_range_m, error=0.0, position_error=0.0):
            calls.append((len(bearings), position_error))

    def sector(bearing_rad: float, position_error_m: float = 0.6) -> FakeScan:
        return FakeScan((1.0, 2.0), bearings_rad=np.array([bearing_rad]), half_width_rad=0.39,
                        position_error_m=position_error_m)

    eight = [sector(k * 0.785) for k in range(8)]
    again = [sector(0.0)]  # the next round's first sector
    worse = [sector(0.785, 3.0)]  # the receiver's accuracy changed: its own update
    whole = [FakeScan((1.0, 2.0), bearings_rad=np.zeros(72), half_width_rad=0.39, distances_m=np.ones(72))
             for _ in range(2)]
    Sensing(SensingVehicle(*eight, *again, *worse, *whole), Map(), lambda: 0.0).drain((0.0, 0.0), (0.0, 0.0))
    assert calls == [(8, 0.6), (1, 0.6), (1, 3.0), (72, 0.0), (72, 0.0)]


def test_readings_beyond_the_horizon_say_only_that_nothing_stands_within_it():
    """ArduCopter SITL's proximity sensor reads up to 200 m: a scan that far cost 18 ms a sector, and eight
    sectors a cycle held up the setpoints for seconds."""
    calls = []

    class Map:
        def add_scan(self, north_m, east_m, bearings, half, distances, max_range_m, *rest):
            calls.append((distances.tolist(), max_range_m))

    far = FakeScan(bearings_rad=np.zeros(3), distances_m=np.array([12.0, 199.9, np.nan]), max_range_m=200.0)
    near = FakeScan(distances_m=np.array([25.0]), max_range_m=30.0)
    sensing = Sensing(SensingVehicle(far, near), Map(), lambda: 0.0)
    sensing.drain((0.0, 0.0), (0.0, 0.0))
    assert sensing.horizon_m == 60.0
    (d_far, range_far), (d_near, range_near) = calls
    assert d_far[:2] == [12.0, math.inf] and math.isnan(d_far[2]) and range_far == 60.0
    assert (d_near, range_near) == ([25.0], 30.0)  # a sensor shorter than the horizon is taken as it is


def test_readings_that_come_faster_than_the_layer_takes_them_are_dropped_oldest_first(caplog):
    """However slow the layer, one poll spends about the budget on the readings, the newest, and counts the rest:
    the setpoints go out."""
    import time

    taken = []

    class SlowMap:
        def add_scan(self, north_m, east_m, *rest):
            time.sleep(0.005)
            taken.append(north_m)

    vehicle = SensingVehicle(FakeScan((0.0, 0.0)))
    sensing = Sensing(vehicle, SlowMap(), lambda: 0.0)
    sensing.drain((0.0, 0.0), (0.0, 0.0))  # learns the cost: at least 5 ms a reading
    vehicle.scans = [FakeScan((float(k), 0.0)) for k in range(1, 401)]
    taken.clear()
    started = time.perf_counter()
    sensing.drain((0.0, 0.0), (0.0, 0.0))
    assert time.perf_counter() - started < 1.5  # all 400 would take at least two seconds
    assert 1 <= len(taken) <= 100 and taken == [float(k) for k in range(401 - len(taken), 401)]
    assert sensing.dropped == 400 - len(taken)
    assert "keeping the newest" in caplog.text
