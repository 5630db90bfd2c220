"""What the autopilot's tilt limit leaves once the wind's drag is held: the speed to fly along each direction and
the acceleration to plan corners and braking with.

A multicopter's thrust gives at most ``g tan(max tilt)`` horizontally (PX4 MPC_TILTMAX_AIR, 45 degrees by
default; ArduCopter ANGLE_MAX, 30). Flying at a velocity ``v`` takes a lean of ``k v - c`` against the drag (``k``
the drag, 1/s; ``c = k * wind``, the lean the wind alone takes), and whatever the limit leaves is all the autopilot
has to turn, brake and hold its track. When its velocity loop asks for more, PX4 (``ControlMath::limitTilt``) and
ArduCopter scale the whole lean down along its own direction, so in a crosswind the part that holds the vehicle on
its track is cut with the rest and the wind carries it off: our sim with MPC_TILTMAX_AIR = 30 and a 15 m/s wind
across a street flown south, asked for 10 m/s, leaned at the limit for 8 s, made 8.5 m/s and drifted 5 m
downwind, 0.4 m from a building.

:class:`TiltBudget` follows the wind's lean from the attitude (the thrust's horizontal part, less what changed the
velocity, is the drag; with ``k`` known, ``c = k v - drag lean``, filtered over seconds) and :meth:`TiltBudget.plan`
fits the flight within the limit: a reserve for turning and braking (the schedule's lateral acceleration, less in a
wind that leaves less), the schedule's accelerations within it, and along each direction the fastest ground speed
whose steady lean leaves that reserve across the track (:func:`speed_caps_mps`). A calm flight is planned as
before unless the drag itself nears the limit at cruise (PX4's SIH airframe, drag 1 m/s^2 per m/s, leans its full
45 degrees at 10 m/s: capped at 8.9 m/s, where the corners and the cross-track error keep 2.7 m/s^2 to work with).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .drag import GRAVITY_MPS2, thrust_accel_ne
from .preflight import Speeds

log = logging.getLogger(__name__)

#: Share of the tilt limit's acceleration the plan may use (the attitude loop and the gusts take the rest).
LEAN_SHARE = 0.95
#: The drag (1/s) assumed until the vehicle's own is learnt (:class:`~.drag.DragEstimate`): ArduCopter SITL's;
#: our sim's is 0.3, PX4 SIH's 1.0.
DEFAULT_DRAG_1_S = 0.5
#: The least speed (m/s) a cap leaves along any direction, and the least acceleration (m/s^2) the plan keeps.
MIN_SPEED_MPS = 1.0
MIN_ACCEL_MPS2 = 0.3


def speed_caps_mps(directions_ne: np.ndarray, *, drag_1_s: float, wind_lean_ne, lean_max_mps2: float,
                   reserve_mps2: float) -> np.ndarray:
    """The fastest ground speed (m/s) along each unit ``directions_ne`` row (north, east) whose steady lean
    ``k v u - c`` keeps ``reserve_mps2`` across the track within ``lean_max_mps2``:
    ``(k v - c.u)^2 + (|c x u| + reserve)^2 <= lean_max^2``; at least :data:`MIN_SPEED_MPS`.

    >>> caps = speed_caps_mps(np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), drag_1_s=0.3,
    ...                       wind_lean_ne=(0.0, 3.0), lean_max_mps2=5.0, reserve_mps2=1.0)  # 10 m/s wind, east
    >>> [round(float(v), 2) for v in caps]  # across it, with it, against it
    [10.0, 26.33, 6.33]
    """
    u = np.asarray(directions_ne, float).reshape(-1, 2)
    c = np.asarray(wind_lean_ne, float)
    along = u @ c
    across = np.abs(u[:, 0] * c[1] - u[:, 1] * c[0])
    room = lean_max_mps2**2 - (across + reserve_mps2) ** 2
    k = max(drag_1_s, 1e-6)
    caps = (along + np.sqrt(np.maximum(room, 0.0))) / k
    return np.where(room > 0.0, np.maximum(caps, MIN_SPEED_MPS), MIN_SPEED_MPS)


@dataclass(frozen=True)
class TiltPlan:
    """What :meth:`TiltBudget.plan` leaves: ``speeds`` (the schedule's accelerations within the reserve),
    ``lean_max_mps2`` and ``reserve_mps2`` (m/s^2), the ``drag_1_s`` and ``wind_lean_ne`` they were fitted to."""

    speeds: Speeds
    lean_max_mps2: float
    reserve_mps2: float
    drag_1_s: float
    wind_lean_ne: tuple[float, float]

    def caps_mps(self, directions_ne: np.ndarray) -> np.ndarray:
        """:func:`speed_caps_mps` for this plan (a ``speed_cap_fn`` for :func:`~.path.smooth_path`)."""
        return speed_caps_mps(directions_ne, drag_1_s=self.drag_1_s, wind_lean_ne=self.wind_lean_ne,
                              lean_max_mps2=self.lean_max_mps2, reserve_mps2=self.reserve_mps2)

    def caps_round_mps(self) -> np.ndarray:
        """:meth:`caps_mps` every 5 degrees from north, clockwise (72,)."""
        turns = np.radians(np.arange(0.0, 360.0, 5.0))
        return self.caps_mps(np.column_stack([np.cos(turns), np.sin(turns)]))

    def binds(self, cruise_mps: float) -> bool:
        """True when some direction is capped under ``cruise_mps``."""
        return bool(self.caps_round_mps().min() < cruise_mps)


class TiltBudget:
    """The wind's lean (m/s^2, north, east), followed from attitude and velocity samples in level flight, and the
    flight it leaves within a tilt limit of ``max_tilt_rad``. Until the vehicle's drag is learnt only samples at
    ``slow_mps`` or less count (hovering, and each leg's start), where a guessed drag matters little.

    >>> b = TiltBudget(math.radians(30.0))
    >>> for _ in range(100):  # hovering in a wind whose drag takes 3 m/s^2 towards the east: leaning west
    ...     b.update(math.radians(-17.0), 0.0, 0.0, (0.0, 0.0, 0.0), 0.1, drag_1_s=0.3)
    >>> [round(x, 1) for x in b.wind_lean_ne]
    [0.0, 3.0]
    """

    def __init__(self, max_tilt_rad: float, *, time_constant_s: float = 2.0, max_climb_mps: float = 1.0,
                 slow_mps: float = 2.0, max_accel_change_mps2: float = 1.0) -> None:
        self.lean_limit_mps2 = (GRAVITY_MPS2 * math.tan(min(max(max_tilt_rad, 0.0), math.radians(80.0)))
                                if math.isfinite(max_tilt_rad) else math.inf)
        self.time_constant_s, self.max_climb_mps, self.slow_mps = time_constant_s, max_climb_mps, slow_mps
        self.max_accel_change_mps2 = max_accel_change_mps2
        self.drag_1_s = DEFAULT_DRAG_1_S
        self._c = np.zeros(2)
        self._seen_s = 0.0
        self._previous: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None

    @property
    def known(self) -> bool:
        """True once a limit is known and the wind's lean has been followed for half a time constant."""
        return math.isfinite(self.lean_limit_mps2) and self._seen_s >= 0.5 * self.time_constant_s

    @property
    def wind_lean_ne(self) -> tuple[float, float]:
        """``c`` above: the wind's drag on a hovering vehicle (m/s^2, north, east). It points where the wind blows;
        the vehicle leans the other way to hold it."""
        return float(self._c[0]), float(self._c[1])

    def update(self, roll_rad: float, pitch_rad: float, yaw_rad: float, velocity_neu, dt_s: float, *,
               drag_1_s: float | None = None) -> None:
        """Add a sample: attitude (rad), velocity (m/s, north, east, up) held for ``dt_s`` (autopilot s), and the
        drag learnt so far (1/s, :attr:`~.drag.DragEstimate.fitted_1_s`; None: not yet, :data:`DEFAULT_DRAG_1_S`
        is assumed)."""
        vn, ve, vu = (float(x) for x in velocity_neu)
        if not (dt_s > 0 and abs(vu) <= self.max_climb_mps
                and all(math.isfinite(x) for x in (roll_rad, pitch_rad, yaw_rad, vn, ve))):
            self._previous = None
            return
        if drag_1_s is not None:
            self.drag_1_s = drag_1_s
        thrust = np.array(thrust_accel_ne(roll_rad, pitch_rad, yaw_rad))
        velocity = np.array([vn, ve])
        previous, self._previous = self._previous, (velocity, thrust, None)
        if previous is None:
            return
        accel = (velocity - previous[0]) / dt_s
        self._previous = (velocity, thrust, accel)
        # The interval's mean thrust less what changed the velocity is the drag's lean. The attitude is an
        # instant's, the velocity's change an interval's (of the mission's poll, not the autopilot's stream), so
        # where the acceleration changes (a corner's ends, braking) they disagree: those intervals are left out.
        if previous[2] is None or float(np.hypot(*(accel - previous[2]))) > self.max_accel_change_mps2:
            return
        mean_v = 0.5 * (velocity + previous[0])
        if drag_1_s is None and float(np.hypot(*mean_v)) > self.slow_mps:
            return  # a guessed drag would pass a lean at speed for a wind: ArduPilot at 10 m/s in calm air, 2 m/s^2
        c = self.drag_1_s * mean_v - (0.5 * (thrust + previous[1]) - accel)
        self._c += (c - self._c) * min(1.0, dt_s / self.time_constant_s) if self._seen_s > 0 else c - self._c
        self._seen_s += dt_s

    def plan(self, speeds: Speeds) -> TiltPlan | None:
        """The schedule within the tilt limit (None until :attr:`known`): braking and corners at most half of
        what the wind leaves a hovering vehicle (at least :data:`MIN_ACCEL_MPS2`), and the speeds along each
        direction capped (:meth:`TiltPlan.caps_mps`) so that the corners' lateral acceleration stays in reserve
        across the track."""
        if not self.known:
            return None
        lean_max = LEAN_SHARE * self.lean_limit_mps2
        spare = max(0.5 * (lean_max - math.hypot(*self._c)), MIN_ACCEL_MPS2)
        fitted = Speeds(speeds.cruise_mps, min(speeds.accel_mps2, spare), min(speeds.lateral_accel_mps2, spare),
                        speeds.vertical_mps)
        return TiltPlan(fitted, lean_max, fitted.lateral_accel_mps2, self.drag_1_s, self.wind_lean_ne)
