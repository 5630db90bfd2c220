"""Geodetic <-> local NED, checked against independent facts rather than the code's own output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyroute.frames import Geodetic, LocalNED, geodetic_to_ned, global_to_local, local_to_global, ned_to_geodetic
from tests import geodesy

HOME = Geodetic(37.792480, -122.397450, 0.0)
# WGS84 meridian radius of curvature at 37.79 deg N, so one degree of latitude is about 111,000 m.
METRES_PER_DEG_LAT = math.pi / 180 * 6335439 / (1 - 0.00669438 * math.sin(math.radians(37.79248)) ** 2) ** 1.5


def test_north_of_home_is_positive_north():
    p = geodetic_to_ned(Geodetic(HOME.lat_deg + 0.001, HOME.lon_deg, 0.0), HOME)
    assert p.north_m == pytest.approx(0.001 * METRES_PER_DEG_LAT, rel=1e-4)
    assert abs(p.east_m) < 1e-6


def test_east_and_up_have_the_right_signs_and_scale():
    # 0.001 degrees of longitude at 37.79 deg N: N cos(lat) * 0.001 * pi / 180 = 6386170 m * 0.79024 *
    # 1.745e-5 = 88.08 m (by hand; tests/geodesy.py computes it the same way).
    p = geodetic_to_ned(Geodetic(HOME.lat_deg, HOME.lon_deg + 0.001, 30.0), HOME)
    _, expected_east_m = geodesy.latlon_to_ned(HOME.lat_deg, HOME.lon_deg + 0.001, HOME.lat_deg, HOME.lon_deg)
    assert expected_east_m == pytest.approx(88.08, abs=0.01)  # the reference itself, against the figure above
    assert p.east_m == pytest.approx(expected_east_m, abs=geodesy.tolerance_m(expected_east_m, HOME.lat_deg))
    assert p.down_m == pytest.approx(-30, abs=0.01)
    assert p.altitude_m == pytest.approx(30, abs=0.01)


@pytest.mark.parametrize("seed", range(10))
def test_local_offsets_match_the_ellipsoids_radii_of_curvature_out_to_5_km(seed):
    rng = np.random.default_rng(50 + seed)
    home = Geodetic(float(rng.uniform(-60, 60)), float(rng.uniform(-180, 180)), 0.0)
    north_m, east_m = rng.uniform(-5000, 5000, size=2)
    lat, lon = geodesy.ned_to_latlon(north_m, east_m, home.lat_deg, home.lon_deg)
    p = geodetic_to_ned(Geodetic(lat, lon, 0.0), home)
    allowed_m = geodesy.tolerance_m(math.hypot(north_m, east_m), home.lat_deg)
    assert math.hypot(p.north_m - north_m, p.east_m - east_m) <= allowed_m
    back = ned_to_geodetic(LocalNED(north_m, east_m, 0.0), home)
    assert math.hypot(*geodesy.latlon_to_ned(back.lat_deg, back.lon_deg, lat, lon)) <= allowed_m


@pytest.mark.parametrize("seed", range(10))
def test_round_trip_within_a_millimetre(seed):
    rng = np.random.default_rng(seed)
    north, east = rng.uniform(-5000, 5000, size=2)
    down = rng.uniform(-300, 0)
    back = geodetic_to_ned(ned_to_geodetic(LocalNED(north, east, down), HOME), HOME)
    assert np.allclose(back, (north, east, down), atol=1e-3)


def test_classic_wrappers_take_longitude_first():
    local = global_to_local((HOME.lon_deg, HOME.lat_deg + 0.001, 5.0), (HOME.lon_deg, HOME.lat_deg, 0.0))
    assert local[0] == pytest.approx(0.001 * METRES_PER_DEG_LAT, rel=1e-4)
    assert local[2] == pytest.approx(-5.0, abs=1e-3)
    lon, lat, alt = local_to_global(local, (HOME.lon_deg, HOME.lat_deg, 0.0))
    assert (lon, lat, alt) == pytest.approx((HOME.lon_deg, HOME.lat_deg + 0.001, 5.0), abs=1e-9)


def test_classic_wrappers_measure_altitude_from_the_homes_altitude():
    # A home 10 m up: a point at 15 m is 5 m above it (down -5), and back again.
    home = (HOME.lon_deg, HOME.lat_deg, 10.0)
    local = global_to_local((HOME.lon_deg, HOME.lat_deg, 15.0), home)
    assert local == pytest.approx([0.0, 0.0, -5.0], abs=1e-6)
    assert local_to_global([0.0, 0.0, -5.0], home) == pytest.approx([HOME.lon_deg, HOME.lat_deg, 15.0], abs=1e-6)
