"""Before the mission plans: wait for the vehicle to get ready, tie its altitudes to the map, fit the autopilot.

Pure helpers of :class:`~skyroute.flight.mission.Mission` (the vehicle, clock and sleep are passed in).

Altitude datum: map altitude 0 is the map's ground, not the autopilot's home (real autopilots move home to
wherever they arm, and a vehicle may stand on a roof). The ground's altitude above mean sea level is the
vehicle's own AMSL altitude, while it stands on the ground before arming, minus the height of the surface the
map shows under it (0 in a street, the roof's height on a building); ``ground_amsl_m`` overrides it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from skyroute.frames import Geodetic, LocalNED, geodetic_to_ned

from .protocol import Limits, ProgressFn, SurfaceFn, Vehicle

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Speeds:
    """The flight path's speed schedule (m/s, m/s^2), see :func:`~skyroute.flight.path.smooth_path`."""

    cruise_mps: float
    accel_mps2: float
    lateral_accel_mps2: float
    vertical_mps: float


def wait_until_ready(vehicle: Vehicle, *, deadline_s: float, clock: Callable[[], float],
                     sleep: Callable[[float], None], progress: ProgressFn, every_s: float) -> str | None:
    """Wait for ``vehicle.readiness()`` until ``clock() >= deadline_s``, one progress line every ``every_s``.

    Returns None once ready, else the last description of what is missing (the link lost returns
    "the link was lost").
    """
    last_line_s = clock() - every_s + 1.0  # the first line after a second: a ready vehicle says nothing
    while True:
        state = vehicle.readiness()
        if state.ready:
            return None
        if not vehicle.link_ok:
            return "the link was lost"
        now = clock()
        if now >= deadline_s:
            return state.describe()
        if now - last_line_s >= every_s:
            progress(f"{state.describe()} ({deadline_s - now:.0f} s left)")
            last_line_s = now
        sleep(0.2)


def ground_amsl(vehicle: Vehicle, map_origin: Geodetic, surface_fn: SurfaceFn | None) -> tuple[float, float]:
    """``(ground_amsl_m, surface_m)``: the map ground's AMSL altitude from the standing vehicle, and the height
    of the surface under it (see the module docstring)."""
    t = vehicle.telemetry
    here = geodetic_to_ned(Geodetic(t.lat_deg, t.lon_deg, 0.0), map_origin)
    surface = 0.0 if surface_fn is None else float(surface_fn(here.north_m, here.east_m))
    return float(t.alt_amsl_m) - surface, surface


def fit_speeds(wanted: Speeds, limits: Limits, accel_margin: float = 0.9) -> Speeds:
    """The schedule within the autopilot's own limits: cruise at most its speed limit (it clips a faster
    feed-forward anyway), braking within ``accel_margin`` of its acceleration limit, and the arcs' lateral
    acceleration within its ``lateral_accel_mps2`` (when it gives one; else ``accel_margin`` of the limit): the
    position loop needs the rest to correct the cross-track error (ArduCopter SITL, which shapes its target with a
    jerk limit, swung 5 m wide of 60-degree corners planned at 0.9 x WPNAV_ACCEL, 1.1 m at 0.6 x).

    >>> class L: cruise_mps, accel_mps2, lateral_accel_mps2 = 10.0, 2.5, 1.5  # ArduCopter's WPNAV_SPEED, _ACCEL
    >>> fit_speeds(Speeds(12.0, 3.0, 3.0, 1.5), L())
    Speeds(cruise_mps=10.0, accel_mps2=2.25, lateral_accel_mps2=1.5, vertical_mps=1.5)
    """
    def fit(value: float, limit: float, margin: float) -> float:
        return min(value, margin * limit) if math.isfinite(limit) and limit > 0 else value

    lateral = float(getattr(limits, "lateral_accel_mps2", math.inf))
    if not math.isfinite(lateral):
        lateral = accel_margin * limits.accel_mps2
    return Speeds(fit(wanted.cruise_mps, limits.cruise_mps, 1.0),
                  fit(wanted.accel_mps2, limits.accel_mps2, accel_margin),
                  fit(wanted.lateral_accel_mps2, lateral, 1.0), wanted.vertical_mps)


def describe_offset(offset: LocalNED, ground_amsl_m: float, surface_m: float) -> str:
    where = f"on a {surface_m:.1f} m roof" if surface_m > 0.05 else "on the ground"
    return (f"map ground at {ground_amsl_m:.2f} m AMSL (the vehicle stands {where}); autopilot local frame + "
            f"({offset.north_m:.1f}, {offset.east_m:.1f}, {offset.down_m:.1f}) m = map frame")
