"""Geodetic <-> local NED, checked against independent facts rather than the code's own output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyroute.frames import Geodetic, LocalNED, geodetic_to_ned, global_to_local, local_to_global, ned_to_geodetic

HOME = Geodetic(37.792480, -122.397450, 0.0)
# WGS84 meridian radius of curvature at 37.79 deg N, so one degree of latitude is about 111,000 m.
METRES_PER_DEG_LAT = math.pi / 180 * 6335439 / (1 - 0.00669438 * math.sin(math.radians(37.79248)) ** 2) ** 1.5


def test_north_of_home_is_positive_north():
    p = geodetic_to_ned(Geodetic(HOME.lat_deg + 0.001, HOME.lon_deg, 0.0), HOME)
    assert p.north_m == pytest.approx(0.001 * METRES_PER_DEG_LAT, rel=1e-4)
    assert abs(p.east_m) < 1e-6


def test_east_and_up_have_the_right_signs():
    p = geodetic_to_ned(Geodetic(HOME.lat_deg, HOME.lon_deg + 0.001, 30.0), HOME)
    assert p.east_m > 80 and p.down_m == pytest.approx(-30, abs=0.01)
    assert p.altitude_m == pytest.approx(30, abs=0.01)


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
