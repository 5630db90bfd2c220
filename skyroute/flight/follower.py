"""Steering along a :class:`~skyroute.flight.path.SmoothPath`: the setpoint to send now, in the map frame.

Pure functions, no vehicle and no clock. Each poll the follower predicts where the vehicle will be when this
setpoint reaches it (:func:`predict_over_link`: over the link's round trip it flies the setpoints already sent)
and while it is the autopilot's latest (``ahead_s``: the autopilot's response and one poll, at the predicted
velocity), and commands the path point nearest to that, with the scheduled velocity along the path as a
feed-forward: the autopilot flies the schedule and its position loop only corrects the cross-track error, so it
neither brakes at each waypoint nor crawls behind a slow link.

Last-command safety: if this setpoint is the last one the autopilot gets (a crashed client, a cut link), the
autopilot keeps acting on it for a while (ArduCopter moves a position + velocity target on along the velocity
for GUID_TIMEOUT, 3 s; PX4 holds the position, its feed-forward carrying the vehicle about ``v / MPC_XY_P`` past
it) and then brakes: ``limits.coast_m(speed)`` metres along the feed-forward. :func:`feedforward_cap_mps` keeps
that straight continuation out of every building's planning margin (``clearance_fn``), so no single command can
carry the vehicle into a building, whatever happens next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .path import SmoothPath
from .protocol import ClearanceFn, Limits

#: Remaining path (m) from which the last waypoint is commanded as a plain position (no feed-forward): the
#: autopilot's position loop stops there. Before that the braking schedule's feed-forward brings the vehicle in
#: (handing PX4 a goal 17 m ahead at 10 m/s overshot it by 1.5 m, measured); only a vehicle coming in far faster
#: than the schedule (it needs twice the remaining path to brake) gets the plain position earlier.
FINAL_APPROACH_M = 1.0


@dataclass(frozen=True)
class Setpoint:
    """What to command: ``position`` (3,) map ``[north_m, east_m, altitude_m]``, ``velocity`` (3,) map
    ``[north, east, up]`` m/s or None (position only), ``heading_rad``, ``ref_s`` (its arc length), and
    ``acceleration`` (3,) map m/s^2, the drag's feed-forward, or None (none to send)."""

    position: np.ndarray
    velocity: np.ndarray | None
    heading_rad: float
    ref_s: float
    acceleration: np.ndarray | None = None


def feedforward_cap_mps(limits: Limits | None, clearance_fn: ClearanceFn | None, position, tangent,
                        speed_mps: float) -> float:
    """The fastest feed-forward along ``tangent`` from ``position`` whose coast stays clear (``speed_mps`` if
    nothing limits it).

    >>> class L:  # ArduCopter: 3 s of coasting, braking at 2.5 m/s^2
    ...     def coast_m(self, v): return v * 3.0 + v * v / 5.0
    ...     def speed_for_clearance_mps(self, c): return 2.5 * (-3.0 + math.sqrt(9.0 + 2.0 * c / 2.5))
    >>> round(feedforward_cap_mps(L(), lambda n, e, a, dn, de, m: min(m, 20.0), (0, 0, 5), (1, 0, 0), 10.0), 3)
    5.0
    """
    if limits is None or clearance_fn is None or not speed_mps > 0:
        return speed_mps
    horizontal = math.hypot(tangent[0], tangent[1])
    if horizontal < 1e-6:
        return speed_mps  # a climb or a descent: no horizontal coast
    want_m = limits.coast_m(speed_mps)
    clear_m = clearance_fn(float(position[0]), float(position[1]), float(position[2]),
                           tangent[0] / horizontal, tangent[1] / horizontal, want_m + 1.0)
    if clear_m >= want_m:
        return speed_mps
    # only the horizontal part coasts towards the building
    return min(speed_mps, limits.speed_for_clearance_mps(clear_m) / horizontal)


class SentCommands:
    """The feed-forward velocities sent lately, ``(time_s, velocity or None)`` oldest first, for
    :func:`predict_over_link`."""

    def __init__(self) -> None:
        self.commands: list[tuple[float, np.ndarray | None]] = []

    def add(self, time_s: float, velocity) -> None:
        """A setpoint sent at ``time_s`` (our clock) with this feed-forward (map n, e, up m/s; None: a position)."""
        self.commands.append((time_s, None if velocity is None else np.array(velocity, float)))

    def drop_older(self, since_s: float) -> None:
        """Forget what was sent before ``since_s``, but the last of it: the command in effect then."""
        c = self.commands
        k = 0
        while k + 1 < len(c) and c[k + 1][0] <= since_s:
            k += 1
        if k:
            del c[:k]


def predict_over_link(position, velocity, sent, *, now_s: float, rate: float, down_s: float, up_s: float,
                      response_s: float, accel_mps2: float, step_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Where the vehicle will be, and how fast, when a setpoint sent now reaches it: ``(position, velocity)``, map
    frame (m; m/s), like the measured ``position`` and ``velocity`` it starts from.

    A Smith predictor over the link: the measurement is ``down_s`` old (autopilot seconds) and the setpoint takes
    ``up_s`` to arrive, so over those seconds the vehicle flies the feed-forward velocities already sent, not the
    one it was measured at. ``sent`` holds ``(time_s, velocity)`` pairs (our clock, the feed-forward sent then; None
    for a plain position, taken as a stop), oldest first; ``rate`` is autopilot seconds per second of ours. The
    vehicle's velocity follows the command in effect (sent ``up_s`` earlier) as a first-order lag of
    ``response_s`` at most ``accel_mps2``. Before the first setpoint sent it keeps the measured velocity. With no
    delay either way this is the measurement itself. Steering from the measured state instead closes the position
    loop over the round trip: with a second each way (a 200 ms link at 5x) the speed swung 0-11 m/s round a
    6 m/s command, period ~4 s, and the vehicle came 3.5 m from a building it should pass 5 m off.

    >>> p, v = predict_over_link((0, 0, 5), (10, 0, 0), [(-1.0, (10, 0, 0))], now_s=0.0, rate=1.0, down_s=0.5,
    ...                          up_s=0.5, response_s=0.5, accel_mps2=3.0)
    >>> [round(float(x), 2) for x in p], [round(float(x), 2) for x in v]
    ([10.0, 0.0, 5.0], [10.0, 0.0, 0.0])
    """
    p = np.array(position, float)
    v = np.array(velocity, float)
    window = max(down_s, 0.0) + max(up_s, 0.0)
    if window <= 0.0:
        return p, v
    # the commands as the vehicle gets them: (arrival, velocity), autopilot seconds from the measurement
    arrivals = [(rate * (t - now_s) + down_s + up_s, None if c is None else np.asarray(c, float)) for t, c in sent]
    command, k = v.copy(), 0
    n = min(max(int(math.ceil(window / step_s)), 1), 200)  # a long window (a round trip after an outage) in 200
    dt = window / n
    tau = max(response_s, dt)
    for j in range(n):
        tau_j = j * dt
        while k < len(arrivals) and arrivals[k][0] <= tau_j + 1e-9:
            command = np.zeros(3) if arrivals[k][1] is None else arrivals[k][1]
            k += 1
        dv = (command - v) * (dt / tau)
        limit = accel_mps2 * dt
        norm = float(np.linalg.norm(dv))
        if norm > limit > 0.0:
            dv *= limit / norm
        p += (v + 0.5 * dv) * dt
        v += dv
    return p, v


def steer(path: SmoothPath, *, s_m: float, ref_s_m: float, position, velocity, ahead_s: float,
          accel_mps2: float, velocity_lag_s: float, heading_rad: float, limits: Limits | None = None,
          clearance_fn: ClearanceFn | None = None, previous_mps: float = 0.0, dt_s: float = 0.0,
          max_lead_mps: float = 2.0, brake_lag_s: float = 0.0, speed_cap_mps: float = math.inf,
          delay_s: float = 0.0, drag_1_s: float = 0.0) -> Setpoint:
    """The setpoint for a vehicle at ``position`` (map n, e, alt) moving at ``velocity`` (map n, e, up) that has
    reached arc length ``s_m``; ``ref_s_m`` is the previous setpoint's (setpoints never go back along the path).

    The feed-forward speed follows the path's schedule, speeding up from the previous command's
    ``previous_mps`` by at most ``accel_mps2`` over ``dt_s`` (a real autopilot lags its command: ramping on the
    measured speed would crawl), and never more than ``max_lead_mps`` beyond the measured speed plus what
    ``accel_mps2`` adds over the prediction, so the autopilot keeps acceleration to spare for the cross-track
    error (e.g. leaving an arc) and a blocked vehicle is not given a runaway command.

    ``speed_cap_mps`` caps the feed-forward (the mission's sensing limit,
    :meth:`~.replanning.ReplanningMixin._sight_cap_mps`; a vehicle over it is told as much under it); where it is
    below the schedule the target has no lead beyond ``delay_s`` (the part of ``ahead_s`` that is the link's delay
    and the poll: where the vehicle will be when the setpoint reaches it; a target behind that, 400 ms of round
    trip at 3-9 m/s, held an ArduPilot vehicle under its wide sectors' cap to 2-3 m/s, 1.9x the airborne time).
    The mission predicts ``position`` and ``velocity`` over the round trip first (:func:`predict_over_link`), so
    its ``delay_s`` is the poll alone.

    The feed-forward's direction is the path's ``velocity_lag_s`` ahead (the autopilot's velocity loop takes
    about that long to turn); its speed is the schedule's ``max(velocity_lag_s, brake_lag_s)`` ahead, so an
    autopilot that is slow to slow down (PX4, ~0.6 s) is told to brake that much earlier without turning early.

    ``drag_1_s`` > 0 (the vehicle's drag, :class:`~.drag.DragEstimate`) adds ``drag_1_s`` times the feed-forward
    velocity as a feed-forward acceleration: the lean that holds that speed against the drag, so the autopilot's
    integrator need not learn it on each leg (horizontal only; none with a plain position).
    """
    speed = float(np.linalg.norm(velocity))
    capped = speed_cap_mps < path.speed_at(s_m)  # the cap, not the schedule, sets the speed here
    # A capped vehicle gets no lead beyond the link's delay: a target ahead of it is what its position loop chases,
    # on top of the feed-forward, and would keep a vehicle that must slow down at its speed
    predicted = np.asarray(position, float) + np.asarray(velocity, float) * (min(delay_s, ahead_s) if capped
                                                                            else ahead_s)
    ref_s = path.project(predicted, max(s_m, ref_s_m))
    remaining_m = path.length_m - s_m
    if remaining_m <= FINAL_APPROACH_M or speed**2 / (2 * accel_mps2) > 2.0 * remaining_m + FINAL_APPROACH_M:
        ref_s = path.length_m  # the autopilot's position loop brakes to the goal from here (or it came in too fast)
    target, _ = path.point_at(ref_s)
    ff_s = min(ref_s + speed * velocity_lag_s, path.length_m)
    brake_s = min(ref_s + speed * max(velocity_lag_s, brake_lag_s), path.length_m)
    tangent = path.point_at(ff_s)[1]
    if math.hypot(tangent[0], tangent[1]) > 0.1:
        heading_rad = math.atan2(tangent[1], tangent[0]) % (2 * math.pi)
    if ref_s >= path.length_m:
        return Setpoint(target, None, heading_rad, ref_s)
    ramp = max(previous_mps + accel_mps2 * dt_s, speed + accel_mps2 * max(ahead_s, 0.1))
    # over the cap, as far under it: an autopilot that lags its command gets back under the cap sooner
    cap = max(min(speed_cap_mps, 2.0 * speed_cap_mps - speed), 0.0)
    wanted = min(path.speed_at(ff_s), path.speed_at(brake_s), ramp,
                 speed + accel_mps2 * max(ahead_s, 0.1) + max_lead_mps, cap)
    wanted = feedforward_cap_mps(limits, clearance_fn, target, tangent, wanted)
    velocity_ff = tangent * wanted
    lean = None
    if drag_1_s > 0:
        lean = np.array([drag_1_s * velocity_ff[0], drag_1_s * velocity_ff[1], 0.0])
    return Setpoint(target, velocity_ff, heading_rad, ref_s, lean)
