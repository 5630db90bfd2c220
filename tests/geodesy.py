"""WGS84 near a home point, written here from the ellipsoid's two radii of curvature and independently of
``skyroute.frames`` (which uses pymap3d), so tests can check the client's conversions against it.

One degree of latitude is ``pi / 180`` times the meridional radius ``M = a (1 - e^2) / (1 - e^2 sin^2 lat)^1.5``;
one degree of longitude is ``pi / 180`` times ``N cos lat`` with the normal radius ``N = a / sqrt(1 - e^2 sin^2
lat)``, both taken at the home latitude. The flat approximation is off by about ``d^2 / R`` (``R`` ~ 6370 km) at a
distance ``d`` from home (mostly north, ``d^2 tan(lat) / 2R``, the tangent plane falling away from the meridian):
~1 mm at 100 m, ~7 cm at 1 km at San Francisco's latitude; :func:`tolerance_m` says how much to allow.
"""

from __future__ import annotations

import math

WGS84_A_M = 6378137.0
WGS84_F = 1 / 298.257223563
EARTH_RADIUS_M = 6.371e6


def radii_m(lat0_deg: float) -> tuple[float, float]:
    """``(meridional, normal)`` radii of curvature in metres at latitude ``lat0_deg``."""
    e2 = WGS84_F * (2 - WGS84_F)
    w = 1 - e2 * math.sin(math.radians(lat0_deg)) ** 2
    return WGS84_A_M * (1 - e2) / w**1.5, WGS84_A_M / math.sqrt(w)


def ned_to_latlon(north_m: float, east_m: float, lat0_deg: float, lon0_deg: float) -> tuple[float, float]:
    """``(lat_deg, lon_deg)`` of the point ``north_m``, ``east_m`` from home, flat near home."""
    meridional, normal = radii_m(lat0_deg)
    return (lat0_deg + math.degrees(north_m / meridional),
            lon0_deg + math.degrees(east_m / (normal * math.cos(math.radians(lat0_deg)))))


def latlon_to_ned(lat_deg: float, lon_deg: float, lat0_deg: float, lon0_deg: float) -> tuple[float, float]:
    """``(north_m, east_m)`` of a point from home, flat near home (the inverse of :func:`ned_to_latlon`)."""
    meridional, normal = radii_m(lat0_deg)
    return (math.radians(lat_deg - lat0_deg) * meridional,
            math.radians(lon_deg - lon0_deg) * normal * math.cos(math.radians(lat0_deg)))


def tolerance_m(distance_m: float, lat0_deg: float) -> float:
    """How far the flat approximation may be from the exact ellipsoid at ``distance_m`` from a home at
    ``lat0_deg``: ``d^2 (tan(lat) / 2 + 1/4) / R`` plus a millimetre (at least 1.1 times the worst error seen
    between 0 and 60 degrees of latitude, out to 10 km)."""
    return distance_m**2 * (abs(math.tan(math.radians(lat0_deg))) / 2 + 0.25) / EARTH_RADIUS_M + 1e-3


def distance_m(lat_a: float, lon_a: float, lat_b: float, lon_b: float) -> float:
    """Horizontal distance (m) between two nearby points, flat at the first one's latitude."""
    return math.hypot(*latlon_to_ned(lat_b, lon_b, lat_a, lon_a))
