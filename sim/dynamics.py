"""Point-mass quadcopter with a cascaded position/velocity controller.

All vectors are in the map frame ``(north, east, up)`` in metres, m/s and m/s^2. Yaw is the NED
heading in radians (0 = north, positive clockwise seen from above).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

GRAVITY_M_S2 = 9.80665
NAN3 = (math.nan, math.nan, math.nan)
#: Within this height (m) of the surface, a vehicle not asked to climb has touched down.
TOUCHDOWN_M = 0.02


@dataclass
class Limits:
    """Controller limits (SI units)."""

    max_horizontal_speed_m_s: float = 10.0
    max_climb_m_s: float = 3.0
    max_descent_m_s: float = 1.5
    max_horizontal_accel_m_s2: float = 4.0
    max_vertical_accel_m_s2: float = 3.0
    max_yaw_rate_rad_s: float = math.radians(60.0)
    position_gain_1_s: float = 1.0
    velocity_gain_1_s: float = 4.0
    yaw_gain_1_s: float = 2.0
    #: Linear drag coefficient (1/s) coupling the airframe to the air, still or moving (the client measures PX4
    #: SIH's at ~1.1/s and ArduCopter SITL's at ~0.5/s).
    drag_1_s: float = 0.3
    #: Horizontal acceleration the airframe's tilt can give at most (m/s^2): g tan(30 degrees), ArduCopter's
    #: ANGLE_MAX default; the autopilot sets it from its parameter (PX4's MPC_TILTMAX_AIR is 45 degrees). The
    #: trajectory limit (``max_horizontal_accel_m_s2``, WPNAV_ACCEL / MPC_ACC_HOR) shapes what the vehicle is asked
    #: to do; holding it against the wind's drag comes on top, up to this.
    max_tilt_accel_m_s2: float = GRAVITY_M_S2 * math.tan(math.radians(30.0))
    #: Time constant (s) of the velocity loop's integrator, which learns the wind's drag and leans into it.
    wind_integrator_s: float = 1.0


@dataclass
class ControlTarget:
    """What the controller should do this step (map frame; NaN means "not controlled").

    ``position_neu`` axes that are finite are position-controlled, with ``velocity_neu`` as
    feed-forward; axes with only a finite velocity are velocity-controlled; axes with neither are
    braked to zero velocity.
    """

    position_neu: tuple[float, float, float] = NAN3
    velocity_neu: tuple[float, float, float] = NAN3
    yaw_rad: float = math.nan
    yaw_rate_rad_s: float = math.nan
    max_horizontal_speed_m_s: float = math.nan
    #: Vertical speed limit override while descending (m/s, positive), e.g. landing speed.
    max_descent_m_s: float = math.nan
    #: Feed-forward acceleration (m/s^2, map frame; NaN axes none), added to the velocity loop's output as PX4
    #: OFFBOARD does; the loop's integrator then learns only what it leaves of the drag.
    accel_neu: tuple[float, float, float] = NAN3


@dataclass
class QuadState:
    """Kinematic truth of the vehicle (map frame)."""

    position_neu: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_neu: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_neu: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: What the thrust gives (m/s^2): the acceleration less the drag; the attitude leans along it.
    thrust_neu: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    on_ground: bool = True


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def _approach_speed(distance_m: float, vmax: float, gain: float, accel: float) -> float:
    """Speed (m/s) that reaches a target ``distance_m`` away without overshoot."""
    return min(vmax, gain * distance_m, math.sqrt(2.0 * 0.8 * accel * distance_m))


class PointMassQuad:
    """Integrates a point-mass multicopter with a fixed time step.

    Parameters
    ----------
    limits : Limits
        Speed/acceleration limits and gains.
    position_neu : array-like, shape (3,)
        Initial map position (m); the vehicle starts landed there.
    yaw_rad : float
        Initial heading (rad).
    """

    def __init__(self, limits: Limits, position_neu, yaw_rad: float = 0.0) -> None:
        self.limits = limits
        self.state = QuadState(position_neu=np.array(position_neu, dtype=float), yaw_rad=yaw_rad)
        self._lean_m_s2 = np.zeros(2)  # what the velocity loop's integrator has learnt to lean into the wind

    def desired_velocity(self, target: ControlTarget, estimate_error_neu: np.ndarray | None = None) -> np.ndarray:
        """Velocity command (m/s, map frame) from the target, before acceleration limits; the position loop acts
        on the autopilot's estimate, the truth plus ``estimate_error_neu`` (m, map frame)."""
        lim = self.limits
        s = self.state
        here = s.position_neu if estimate_error_neu is None else s.position_neu + estimate_error_neu
        pos_t = np.array(target.position_neu, dtype=float)
        vel_t = np.array(target.velocity_neu, dtype=float)
        vmax_h = lim.max_horizontal_speed_m_s
        if math.isfinite(target.max_horizontal_speed_m_s):
            vmax_h = max(0.0, min(vmax_h, target.max_horizontal_speed_m_s))
        v_down = lim.max_descent_m_s
        if math.isfinite(target.max_descent_m_s):
            v_down = max(0.05, min(v_down, target.max_descent_m_s))
        v_des = np.zeros(3)
        # Horizontal: joint profile when both axes are position-controlled.
        if math.isfinite(pos_t[0]) and math.isfinite(pos_t[1]):
            err = pos_t[:2] - here[:2]
            dist = float(np.hypot(*err))
            if dist > 1e-9:
                speed = _approach_speed(dist, vmax_h, lim.position_gain_1_s, lim.max_horizontal_accel_m_s2)
                v_des[:2] = err / dist * speed
        else:
            for axis in (0, 1):
                if math.isfinite(pos_t[axis]):
                    err = pos_t[axis] - here[axis]
                    speed = _approach_speed(
                        abs(err), vmax_h, lim.position_gain_1_s, lim.max_horizontal_accel_m_s2
                    )
                    v_des[axis] = math.copysign(speed, err)
        for axis in (0, 1):
            if math.isfinite(vel_t[axis]):
                v_des[axis] += vel_t[axis]
        h = float(np.hypot(v_des[0], v_des[1]))
        if h > vmax_h > 0.0:
            v_des[:2] *= vmax_h / h
        elif vmax_h <= 0.0:
            v_des[:2] = 0.0
        # Vertical.
        if math.isfinite(pos_t[2]):
            err = pos_t[2] - here[2]
            vmax = lim.max_climb_m_s if err > 0 else v_down
            v_des[2] = math.copysign(
                _approach_speed(abs(err), vmax, lim.position_gain_1_s, lim.max_vertical_accel_m_s2), err
            )
        if math.isfinite(vel_t[2]):
            v_des[2] += vel_t[2]
        v_des[2] = min(max(v_des[2], -v_down), lim.max_climb_m_s)
        return v_des

    def step(
        self,
        dt_s: float,
        target: ControlTarget,
        armed: bool,
        ground_up_fn: Callable[[float, float, float], float],
        wind_neu: np.ndarray | None = None,
        estimate_error_neu: np.ndarray | None = None,
    ) -> bool:
        """Advance one fixed step.

        Parameters
        ----------
        dt_s : float
            Step (s, simulated time).
        target : ControlTarget
            Controller target for this step.
        armed : bool
            Motors running. A disarmed vehicle on the ground does not move.
        ground_up_fn : callable
            ``(north_m, east_m, below_up_m) -> up_m`` of the surface under the vehicle.
        wind_neu : ndarray, shape (3,), optional
            Air velocity (m/s, map frame).
        estimate_error_neu : ndarray, shape (3,), optional
            The autopilot's position estimate minus the truth (m, map frame): its position loop flies the
            estimate to the target, so the truth ends up off the target by the error, as on a real vehicle.

        Returns
        -------
        bool
            True on the step the vehicle touched down (was airborne, now on the ground).
        """
        lim = self.limits
        s = self.state
        if not armed:
            s.velocity_neu[:] = 0.0
            s.accel_neu[:] = 0.0
            s.thrust_neu[:] = 0.0
            s.yaw_rate_rad_s = 0.0
            self._lean_m_s2[:] = 0.0
            return False
        v_des = self.desired_velocity(target, estimate_error_neu)
        if s.on_ground:
            if v_des[2] <= 0.05:
                s.velocity_neu[:] = 0.0
                s.accel_neu[:] = 0.0
                s.yaw_rate_rad_s = 0.0
                return False
            s.on_ground = False
        accel = lim.velocity_gain_1_s * (v_des - s.velocity_neu)
        ah = float(np.hypot(accel[0], accel[1]))
        if ah > lim.max_horizontal_accel_m_s2:
            accel[:2] *= lim.max_horizontal_accel_m_s2 / ah
        accel[2] = min(max(accel[2], -lim.max_vertical_accel_m_s2), lim.max_vertical_accel_m_s2)
        feedforward = np.nan_to_num(np.array(target.accel_neu[:2], dtype=float), nan=0.0)
        thrust = accel.copy()
        if wind_neu is not None or feedforward.any():
            # The velocity loop's integrator learns the drag (a first-order lag) and leans against it, on top of
            # the shaped acceleration and the feed-forward, within what the tilt allows: a steady wind leaves no
            # steady offset, a gust pushes the vehicle until it is learnt, a wind beyond the tilt's reach carries
            # it off. A feed-forward that carries the drag leaves the integrator nothing to learn.
            drag = np.zeros(2) if wind_neu is None else lim.drag_1_s * (wind_neu[:2] - s.velocity_neu[:2])
            self._lean_m_s2 += (drag + feedforward - self._lean_m_s2) * min(
                1.0, dt_s / max(lim.wind_integrator_s, 1e-9))
            thrust[:2] = accel[:2] + feedforward - self._lean_m_s2
            th = float(np.hypot(thrust[0], thrust[1]))
            if th > lim.max_tilt_accel_m_s2:
                thrust[:2] *= lim.max_tilt_accel_m_s2 / th
            accel[:2] = thrust[:2] + drag
        s.accel_neu, s.thrust_neu = accel, thrust
        s.velocity_neu = s.velocity_neu + accel * dt_s
        s.position_neu = s.position_neu + s.velocity_neu * dt_s
        # Yaw.
        if math.isfinite(target.yaw_rad):
            rate = lim.yaw_gain_1_s * wrap_pi(target.yaw_rad - s.yaw_rad)
        elif math.isfinite(target.yaw_rate_rad_s):
            rate = target.yaw_rate_rad_s
        else:
            rate = 0.0
        rate = min(max(rate, -lim.max_yaw_rate_rad_s), lim.max_yaw_rate_rad_s)
        s.yaw_rate_rad_s = rate
        s.yaw_rad = wrap_pi(s.yaw_rad + rate * dt_s)
        # Ground contact.
        ground = ground_up_fn(s.position_neu[0], s.position_neu[1], s.position_neu[2] + 0.05)
        if s.position_neu[2] <= ground + TOUCHDOWN_M and v_des[2] <= 0.05:
            s.position_neu[2] = ground
            s.on_ground = True
            s.velocity_neu[:] = 0.0
            s.accel_neu[:] = 0.0
            return True
        if s.position_neu[2] < ground:
            s.position_neu[2] = ground
            s.velocity_neu[2] = max(s.velocity_neu[2], 0.0)
        return False

    def attitude(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw (rad) a multicopter would hold for its thrust's acceleration (it leans into a wind)."""
        s = self.state
        c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        a_fwd = c * s.thrust_neu[0] + sn * s.thrust_neu[1]
        a_right = -sn * s.thrust_neu[0] + c * s.thrust_neu[1]
        g = GRAVITY_M_S2 + s.thrust_neu[2]
        pitch = -math.atan2(a_fwd, g)
        roll = math.atan2(a_right, g)
        return roll, pitch, s.yaw_rad
