"""The vehicle's drag, learnt in flight from its attitude, for an acceleration feed-forward.

A multicopter holds its speed against drag by tilting: in level flight its thrust gives a horizontal
acceleration of ``g * tan(tilt)`` towards where it leans, and at a steady speed that cancels the drag. An
autopilot learns that lean in its velocity loop's integrator, in the local (north, east) frame. After a turn the
drag points another way and the integrator takes seconds to swing round; meanwhile it pushes the vehicle off the
new leg. PX4 1.15 SITL (SIH quadcopter, drag 1 m/s^2 per m/s) came out of a 70 degree corner at 7 m/s 2.4 m wide
and was still 1.5 m off the leg 50 m on.

:class:`DragEstimate` fits ``drag = -k * velocity`` (``k`` in 1/s) to what the attitude and the velocity say in
level flight; the mission sends ``k`` times its feed-forward velocity as a feed-forward acceleration to an autopilot
that adds a setpoint's acceleration to its velocity loop's output (PX4), so its integrator has no drag to learn and
nothing to unlearn at a corner. Measured on the SITL binaries in ../shared/sitl: PX4 SIH k = 1.01, ArduCopter
SITL k = 0.53; our sim without wind k = 0.007.
"""

from __future__ import annotations

import math

GRAVITY_MPS2 = 9.80665


def thrust_accel_ne(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float]:
    """Horizontal acceleration (m/s^2, north, east) the thrust gives a multicopter at this attitude (rad, NED
    Euler angles) while its thrust holds it level (vertical thrust = g).

    >>> n, e = thrust_accel_ne(0.0, math.radians(-45.0), 0.0)  # nose down 45 degrees, heading north
    >>> round(n, 3), round(e, 3)
    (9.807, 0.0)
    >>> n, e = thrust_accel_ne(math.radians(10.0), 0.0, math.pi / 2)  # heading east, right wing down: south
    >>> round(n, 3), round(e, 3)
    (-1.729, 0.0)
    """
    tan_p, side = math.tan(pitch_rad), math.tan(roll_rad) / math.cos(pitch_rad)
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return -GRAVITY_MPS2 * (c * tan_p + s * side), -GRAVITY_MPS2 * (s * tan_p - c * side)


class DragEstimate:
    """Least-squares fit of a linear drag ``-k * (v - wind)`` (k in 1/s, wind a constant) from attitude and
    velocity samples.

    Each :meth:`update` adds a sample weighted by its duration, when the vehicle flies level (climb under
    ``max_climb_mps``) at ``min_speed_mps`` or more: the thrust's horizontal acceleration less the change of
    velocity is the drag. The wind's part is fitted too (an autopilot's integrator holds a steady wind well: only
    ``k`` goes into the feed-forward). :attr:`k_1_s` is 0 until ``min_time_s`` of such flight over which the
    velocity has varied enough to tell the two apart (``min_spread``: the samples' time-weighted squared distance
    from their mean velocity, (m/s)^2 s), then the fit within ``[0, max_1_s]``. ``wind_prior`` (weight, s) pulls
    the wind's part towards none; it is 0 by default: with a pull of a second, a 15 m/s wind along the first
    leg flown in our sim passed for a drag of 1.65/s (0.3 true) for 30 s, and its feed-forward leaned the
    vehicle 10 m/s^2 the wrong way at each corner.

    >>> d = DragEstimate()
    >>> for step in range(70):  # 7 s north, slowing from 10 to 3 m/s at 1 m/s^2 against a drag of 1/s
    ...     speed = 10.0 - 0.1 * step
    ...     d.update(0.0, -math.atan((speed - 1.0) / GRAVITY_MPS2), 0.0, (speed, 0.0, 0.0), 0.1)
    >>> round(d.k_1_s, 1)
    1.0
    """

    def __init__(self, *, min_speed_mps: float = 1.0, max_climb_mps: float = 1.0, min_time_s: float = 3.0,
                 max_1_s: float = 2.0, wind_prior: float = 0.0, min_spread: float = 20.0) -> None:
        self.min_speed_mps, self.max_climb_mps = min_speed_mps, max_climb_mps
        self.min_time_s, self.max_1_s = min_time_s, max_1_s
        # sums (time-weighted) of the normal equations of thrust = k v - c (c = k * wind), unknowns k, c_n, c_e
        self._vv = self._vn = self._ve = self._time_s = 0.0
        self._av = self._an = self._ae = 0.0
        self.wind_prior, self.min_spread = wind_prior, min_spread
        self._previous: tuple[float, float] | None = None

    def update(self, roll_rad: float, pitch_rad: float, yaw_rad: float, velocity_neu, dt_s: float) -> None:
        """Add a sample: attitude (rad), velocity (m/s, north, east, up) held for ``dt_s`` (s, autopilot time)."""
        vn, ve, vu = (float(x) for x in velocity_neu)
        usable = (dt_s > 0 and math.hypot(vn, ve) >= self.min_speed_mps and abs(vu) <= self.max_climb_mps
                  and all(math.isfinite(x) for x in (roll_rad, pitch_rad, yaw_rad, vn, ve)))
        if not usable:
            self._previous = None
            return
        an, ae = thrust_accel_ne(roll_rad, pitch_rad, yaw_rad)
        if self._previous is not None:  # the thrust less what changed the velocity is what the drag took
            an -= (vn - self._previous[0]) / dt_s
            ae -= (ve - self._previous[1]) / dt_s
        self._previous = (vn, ve)
        self._vv += (vn * vn + ve * ve) * dt_s
        self._vn += vn * dt_s
        self._ve += ve * dt_s
        self._av += (an * vn + ae * ve) * dt_s
        self._an += an * dt_s
        self._ae += ae * dt_s
        self._time_s += dt_s

    @property
    def k_1_s(self) -> float:
        """The drag coefficient (1/s): 0 until enough level flight at speed has been seen."""
        k = self.fitted_1_s
        return 0.0 if k is None else k

    @property
    def fitted_1_s(self) -> float | None:
        """The drag coefficient (1/s), None until enough level flight at varied speeds has been seen (a vehicle
        with no drag at all fits 0)."""
        if self._time_s < self.min_time_s:
            return None
        # the wind's part eliminated: c = (k * sum v - sum a) / (T + prior)
        t = self._time_s + self.wind_prior
        spread = self._vv - (self._vn * self._vn + self._ve * self._ve) / t
        if spread < self.min_spread or spread <= 0.0:
            return None
        k = (self._av - (self._vn * self._an + self._ve * self._ae) / t) / spread
        return min(max(k, 0.0), self.max_1_s)
