"""Geodetic <-> local NED conversions relative to a home point.

The project's map frame is the local tangent plane (NED) at the map's home point ``lat0, lon0`` at altitude 0 m:
``north_m`` points to true north, ``east_m`` to true east, ``down_m`` down. PX4 and ArduPilot use the same
kind of frame for LOCAL_POSITION_NED, but with *their* origin (where the EKF started), which need not be the map's.

The WGS84 maths lives in pymap3d; this module only names things. Latitude always comes before longitude, except
in the two classic wrappers at the bottom, which keep the exercise's ``(lon, lat, alt)`` order.

>>> home = Geodetic(37.792480, -122.397450, 0.0)
>>> p = geodetic_to_ned(Geodetic(37.793380, -122.397450, 10.0), home)
>>> round(p.north_m, 1), round(p.east_m, 1), round(p.down_m, 1)
(99.9, 0.0, -10.0)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pymap3d


class Geodetic(NamedTuple):
    """A WGS84 position: latitude and longitude in degrees, altitude in metres (above the ellipsoid/home datum)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0


class LocalNED(NamedTuple):
    """A position in metres in a local north-east-down frame."""

    north_m: float
    east_m: float
    down_m: float = 0.0

    @property
    def altitude_m(self) -> float:
        """Height above the frame's origin in metres (``-down_m``)."""
        return -self.down_m


def geodetic_to_ned(point: Geodetic, home: Geodetic) -> LocalNED:
    """Convert a geodetic position to local NED metres relative to ``home``."""
    north, east, down = pymap3d.geodetic2ned(
        point.lat_deg, point.lon_deg, point.alt_m, home.lat_deg, home.lon_deg, home.alt_m
    )
    return LocalNED(float(north), float(east), float(down))


def ned_to_geodetic(point: LocalNED, home: Geodetic) -> Geodetic:
    """Convert local NED metres relative to ``home`` to a geodetic position (degrees, metres)."""
    lat, lon, alt = pymap3d.ned2geodetic(
        point.north_m, point.east_m, point.down_m, home.lat_deg, home.lon_deg, home.alt_m
    )
    return Geodetic(float(lat), float(lon), float(alt))


def global_to_local(global_position, global_home) -> np.ndarray:
    """Classic-exercise wrapper: ``(lon, lat, alt)`` in, ``[north, east, down]`` metres out.

    Parameters
    ----------
    global_position, global_home : sequence of 3 floats
        **Longitude first**: ``(lon_deg, lat_deg, alt_m)``, as in the classic starter code and udacidrone's
        ``global_position`` property. Prefer :func:`geodetic_to_ned`, which names its fields.
    """
    lon, lat, alt = global_position
    lon0, lat0, alt0 = global_home
    return np.array(geodetic_to_ned(Geodetic(lat, lon, alt), Geodetic(lat0, lon0, alt0)))


def local_to_global(local_position, global_home) -> np.ndarray:
    """Classic-exercise wrapper: ``[north, east, down]`` metres in, ``[lon, lat, alt]`` out (**longitude first**)."""
    north, east, down = local_position
    lon0, lat0, alt0 = global_home
    lat, lon, alt = ned_to_geodetic(LocalNED(north, east, down), Geodetic(lat0, lon0, alt0))
    return np.array([lon, lat, alt])
