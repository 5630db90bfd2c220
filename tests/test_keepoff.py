"""The keep-off shift (skyroute.flight.keepoff): readings closer than the distance kept move the route away by
as little as clears them, whatever the position estimate says; the shift lasts while they do."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from skyroute.flight.keepoff import WINDOW_S, KeepOff, ahead_distances_m, project_onto_half_planes

NARROW = math.radians(2.5)
WIDE = math.radians(22.5)


def _scan(bearings_deg, distances_m, *, at=(0.0, 0.0), received_s=0.0, half_width_rad=NARROW):
    return SimpleNamespace(bearings_rad=np.radians(np.asarray(bearings_deg, float)),
                           distances_m=np.asarray(distances_m, float), half_width_rad=half_width_rad,
                           local_ne=at, received_s=received_s)


def _wall_east(distance_m, *, at=(0.0, 0.0), received_s=0.0):
    """A 72-sector scan of a north-south wall ``distance_m`` east of ``at`` (nearest point per 5 degree sector)."""
    bearings = np.arange(0.0, 360.0, 5.0)
    b = np.radians(bearings)
    lo, hi = b - NARROW, b + NARROW
    east = np.sin(np.clip(np.pi / 2, lo, hi))  # the sector's bearing nearest due east
    d = np.where(east > 1e-9, distance_m / np.maximum(east, 1e-9), np.inf)
    return _scan(bearings, np.where(d <= 30.0, d, np.inf), at=at, received_s=received_s)


def test_a_wall_read_closer_than_kept_shifts_the_route_away_by_the_difference():
    k = KeepOff(keep_m=4.0)
    k.observe(_wall_east(1.5))
    shift = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=0.0, rate=1.0, dt_s=0.02)
    # 4 m less the 6.5 cm a 5 degree sector's point may be off its centre line at 1.5 m
    assert shift == pytest.approx((0.0, -2.5 + 1.5 * math.sin(NARROW)), abs=0.01)


def test_readings_beyond_the_distance_kept_leave_the_route_where_it_is():
    k = KeepOff(keep_m=4.0)
    for i in range(50):
        k.observe(_wall_east(4.6, at=(i * 0.2, 0.0), received_s=i * 0.02))
        route = [(i * 0.2 + s, 0.0) for s in (0.0, *ahead_distances_m(10.0))]
        shift = k.update((i * 0.2, 0.0), np.array(route) - (i * 0.2, 0.0), now_s=i * 0.02, rate=1.0, dt_s=0.02)
        assert not shift.any()
    assert k.largest_m == 0.0


def test_the_shift_waits_for_the_vehicle_instead_of_adding_up():
    """Read again before the vehicle has moved over, the wall asks for nothing more: the tracked point is already
    shifted by what it needs."""
    k = KeepOff(keep_m=4.0)
    k.observe(_wall_east(1.5))
    first = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=0.0, rate=1.0, dt_s=0.02).copy()
    k.observe(_wall_east(1.5, received_s=0.1))
    second = k.update((0.0, 0.0), [tuple(first)], now_s=0.1, rate=1.0, dt_s=0.1)
    assert second == pytest.approx(first, abs=1e-6)


def test_the_shift_relaxes_once_nothing_reads_close_and_holds_while_something_does():
    """The route was planned along local east 0 and the vehicle has moved over to east -2.5, where the wall reads
    4 m: for three seconds the shift stays (within what a sector's point may be off), then the wall ends."""
    k = KeepOff(keep_m=4.0, relax_s=3.0)
    k.observe(_wall_east(1.5))
    shift = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=0.0, rate=1.0, dt_s=0.02)
    vehicle = np.array([0.0, -2.5])
    for i in range(1, 30):
        k.observe(_wall_east(4.0, at=tuple(vehicle), received_s=0.1 * i))
        shift = k.update(vehicle, [shift - vehicle], now_s=0.1 * i, rate=1.0, dt_s=0.1)
    assert shift == pytest.approx((0.0, -2.5), abs=4.0 * math.sin(NARROW) + 0.01)
    for i in range(30, 130):  # the wall ends: 10 s of nothing within range
        k.observe(_scan(np.arange(0.0, 360.0, 5.0), np.full(72, np.inf), at=tuple(vehicle), received_s=0.1 * i))
        shift = k.update(vehicle, [shift - vehicle], now_s=0.1 * i, rate=1.0, dt_s=0.1)
    assert np.hypot(*shift) < 0.1


def test_a_reading_older_than_the_window_no_longer_counts():
    k = KeepOff(keep_m=4.0)
    k.observe(_wall_east(1.5, received_s=0.0))
    # the autopilot runs 5x: WINDOW_S autopilot seconds is a fifth of that in our clock
    shift = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=1.01 * WINDOW_S / 5.0, rate=5.0, dt_s=0.0)
    assert not shift.any()


def test_between_two_walls_closer_than_kept_the_shift_settles_between_them():
    k = KeepOff(keep_m=4.0, max_shift_m=5.0)
    scan = _scan([90.0, 270.0], [1.0, 5.0])  # a 6 m gap, kept 4 m from either side: no room; 1 m off centre
    k.observe(scan)
    shift = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=0.0, rate=1.0, dt_s=0.02)
    assert -3.0 <= shift[1] <= -1.0 and abs(shift[0]) < 1e-9


def test_a_corner_ahead_in_a_narrow_sector_moves_the_route_before_the_vehicle_gets_there():
    """Flying north at 10 m/s, a building's corner 2 m east of the route 10 m ahead: the route moves west now, to
    4 m from the corner less what a point read 10 m off in a 5 degree sector may be off (0.44 m)."""
    k = KeepOff(keep_m=4.0)
    k.observe(_scan([math.degrees(math.atan2(2.0, 10.0))], [math.hypot(2.0, 10.0)]))
    ahead = ahead_distances_m(10.0)
    route = np.column_stack([np.concatenate([[0.0], ahead]), np.zeros(len(ahead) + 1)])
    shift = k.update((0.0, 0.0), route, now_s=0.0, rate=1.0, dt_s=0.02)
    assert shift[1] < -1.4
    clearance = np.hypot(route[:, 0] + shift[0] - 10.0, route[:, 1] + shift[1] - 2.0).min()
    assert clearance == pytest.approx(4.0 - math.hypot(2.0, 10.0) * math.sin(NARROW), abs=0.05)


def test_wide_sectors_are_not_taken():
    """ArduPilot's 45 degree sectors: the nearest point is anywhere on a wide arc (north-east of a wall 5 m east,
    the sector reads 5.4 m at its edge; placed on its centre line it would lie 3.8 m from the route ahead), and
    their faces at the vehicle shifted the route the wrong way at corners: nothing is kept off them."""
    k = KeepOff(keep_m=4.0)
    d = 5.0 / math.cos(math.radians(22.5))
    k.observe(_scan([0.0, 45.0, 90.0, 135.0, 180.0], [math.inf, d, 5.0, d, math.inf], half_width_rad=WIDE))
    k.observe(_scan([270.0], [3.0], half_width_rad=WIDE))
    ahead = ahead_distances_m(10.0)
    route = np.column_stack([np.concatenate([[0.0], ahead]), np.zeros(len(ahead) + 1)])
    shift = k.update((0.0, 0.0), route, now_s=0.0, rate=1.0, dt_s=0.02)
    assert not shift.any() and k.nearest()[0] == math.inf


def test_the_shift_is_capped():
    k = KeepOff(keep_m=4.0, max_shift_m=2.0)
    k.observe(_wall_east(0.5))
    shift = k.update((0.0, 0.0), [(0.0, 0.0)], now_s=0.0, rate=1.0, dt_s=0.02)
    assert np.hypot(*shift) == pytest.approx(2.0)


def test_projection_onto_half_planes_finds_the_nearest_point_of_a_corner():
    normals = np.array([[0.0, 1.0], [1.0, 0.0]])
    y = project_onto_half_planes(np.array([1.0, 1.0]), normals, np.array([-0.5, 0.0]))
    assert y == pytest.approx((0.0, -0.5))


def _height(h, received_s=0.0):
    return SimpleNamespace(height_m=h, min_range_m=0.2, max_range_m=40.0, received_s=received_s)


def test_a_roof_read_closer_below_than_kept_lifts_the_route_by_the_difference_and_no_more():
    k = KeepOff(keep_m=4.0)
    for i in range(3):
        k.observe_height(_height(2.0, received_s=0.1 * i))
    assert k.update_lift(0.0, now_s=0.2, rate=1.0, dt_s=0.1) == pytest.approx(2.0)
    # still climbing (1.5 m below the lifted route), the roof still reads 2 m: no more lift
    k.observe_height(_height(2.0, received_s=0.3))
    assert k.update_lift(-2.0, now_s=0.3, rate=1.0, dt_s=0.1) == pytest.approx(2.0)


def test_the_ground_read_below_at_the_flight_altitude_lifts_nothing_and_a_glitch_neither():
    """Flying at 5 m over the ground (it reads 5 m, more than the 4 m kept); one reading of 0.3 m (a bird, a
    glitch) among them is outvoted; a reading outside the sensor's range says nothing."""
    k = KeepOff(keep_m=4.0)
    for i, h in enumerate([5.0, 5.0, 0.3, 5.0, 5.0, 0.1, 45.0]):
        k.observe_height(_height(h, received_s=0.05 * i))
        lift = k.update_lift(0.0, now_s=0.05 * i, rate=1.0, dt_s=0.05)
        assert lift == 0.0


def test_the_lift_relaxes_once_past_the_roof():
    k = KeepOff(keep_m=4.0, relax_s=3.0)
    k.observe_height(_height(2.0))
    k.update_lift(0.0, now_s=0.0, rate=1.0, dt_s=0.1)
    for i in range(1, 101):  # 10 s over the ground, the vehicle at the lifted altitude
        k.observe_height(_height(5.0 + k.lift_m, received_s=0.1 * i))
        k.update_lift(0.0, now_s=0.1 * i, rate=1.0, dt_s=0.1)
    assert k.lift_m < 0.1
