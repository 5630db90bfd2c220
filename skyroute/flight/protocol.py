"""What the mission needs from a vehicle, and the callables the command line injects.

``skyroute.vehicle.MavlinkVehicle`` implements :class:`Vehicle`; unit tests use a fake. The mission never imports
the vehicle package nor planning: the planner, the clearance along a straight line and the map's surface height
come in as plain callables (:data:`PlanFn`, :data:`ClearanceFn`, :data:`SurfaceFn`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from skyroute.frames import Geodetic, LocalNED


class Telemetry(Protocol):
    """The telemetry fields the mission reads (SI units; positions in the autopilot's local NED frame)."""

    armed: bool
    mode: str
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    north_m: float
    east_m: float
    down_m: float
    local_v_north_mps: float
    local_v_east_mps: float
    local_v_down_mps: float
    local_time_s: float

    @property
    def on_ground(self) -> bool: ...


class Readiness(Protocol):
    """What the vehicle still lacks (``missing``), in words; ``describe()`` is one progress line."""

    missing: tuple[str, ...]

    @property
    def ready(self) -> bool: ...

    def describe(self) -> str: ...


class Limits(Protocol):
    """The autopilot's limits (``skyroute.vehicle.FlightLimits``): speeds in m/s, accelerations in m/s^2."""

    cruise_mps: float
    accel_mps2: float
    link_loss: str
    leaves_flying: bool

    def coast_m(self, speed_mps: float) -> float: ...

    def speed_for_clearance_mps(self, clear_m: float) -> float: ...


class Vehicle(Protocol):
    """What the mission needs from a vehicle. Errors it raises are the mission's ``vehicle_errors``; one with a
    true ``permanent`` attribute is a refusal that waiting will not change (a DENIED/FAILED answer)."""

    @property
    def telemetry(self) -> Telemetry: ...

    @property
    def link_ok(self) -> bool: ...

    @property
    def round_trip_s(self) -> float: ...

    @property
    def in_control(self) -> bool: ...

    def mode_kind(self) -> object:
        """An object whose ``value`` is "ours", "hold", "return", "pilot" or "other"."""

    def readiness(self) -> Readiness: ...

    def failsafe_hint(self, *, texts: bool = True) -> str | None:
        """Why the autopilot may have left our mode for a reason on our side (our setpoints paused, our link was
        silent; with ``texts``, also a failsafe it announced without naming a cause of its own); None if none."""

    def own_failsafe(self) -> str | None:
        """The autopilot's words if it just announced a failsafe of its own (battery, geofence, ...); else None."""

    def map_offset(self, map_origin: Geodetic, ground_amsl_m: float) -> LocalNED: ...

    def flight_limits(self) -> Limits: ...

    def prepare_flight(self) -> None: ...

    def take_control(self) -> None: ...

    def arm(self) -> None: ...

    def disarm(self) -> None: ...

    def takeoff(self, altitude_m: float) -> LocalNED: ...

    def goto_local(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
                   velocity_ned: tuple[float, float, float] | None = None,
                   accel_ned: tuple[float, float, float] | None = None) -> None: ...

    def land(self) -> None: ...

    def hold(self) -> None: ...

    def release_control(self) -> None: ...


#: ``(start_north_m, start_east_m) -> ndarray (K, 4)`` of map-frame waypoints ``[north_m, east_m, altitude_m,
#: heading_rad]``, the first near the start; altitude NaN means the flight altitude.
PlanFn = Callable[[float, float], np.ndarray]
#: ``(north_m, east_m, altitude_m, direction_north, direction_east, max_m) -> m``: how far the horizontal ray
#: from the point along the (unit) direction stays out of every building's planning margin, up to ``max_m``.
ClearanceFn = Callable[[float, float, float, float, float, float], float]
#: ``(north_m, east_m) -> m``: the height of the surface the map shows there (a roof, or 0 on the ground).
SurfaceFn = Callable[[float, float], float]
#: ``(points_ne (P, 2), home_ne) -> (top_m, (north_m, east_m))``: the highest building a straight line from any of
#: the points to home crosses (its top above the map's ground) and where it stands; ``(0, home)`` for none.
ReturnLineFn = Callable[[np.ndarray, tuple[float, float]], tuple[float, tuple[float, float]]]
#: One progress line for the user.
ProgressFn = Callable[[str], None]
