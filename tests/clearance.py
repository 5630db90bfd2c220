"""The tests' own collision check for flown routes, written here from the rule README and WRITEUP state, sharing
no code with the planners (no ``create_grid``, ``line_of_sight`` or ``legs_clear_of_boxes``).

The rule: a point at altitude ``z`` is too close to a box if it is below the box's top plus the margin
(``z < top + safety_m``, the flat lid) and its horizontal distance to the box's footprint is below ``safety_m``
(the Euclidean margin, rounded at the corners); with no margin, if it is inside the footprint and below the top.
Touching the margin is allowed. Each leg is checked at points every ``step_m`` (both ends included) with plain
point-to-rectangle distances, so a leg that cuts a margin by less than about ``step_m`` over a corner can pass;
the planners' exact checks have their own tests against hand-drawn cases.
"""

from __future__ import annotations

import numpy as np

#: Rounding slack: a route that touches a margin may come this much closer (m).
TOUCH_M = 1e-9


def sample_legs(points: np.ndarray, step_m: float) -> list[np.ndarray]:
    """Points along each leg of the polyline ``points`` ``(K, D)``, at most ``step_m`` apart, ends included."""
    points = np.asarray(points, dtype=np.float64)
    samples = []
    for a, b in zip(points[:-1], points[1:]):
        count = max(2, int(np.ceil(np.linalg.norm(b - a) / step_m)) + 1)
        samples.append(a + np.linspace(0.0, 1.0, count)[:, None] * (b - a))
    return samples


def too_close(points_nez: np.ndarray, obstacles: np.ndarray, safety_m: float) -> np.ndarray:
    """For each point ``(P, 3)`` ``[north_m, east_m, altitude_m]``: True if it breaks the rule above."""
    points_nez = np.asarray(points_nez, dtype=np.float64)
    obstacles = np.asarray(obstacles, dtype=np.float64)
    lo = obstacles[None, :, :2] - obstacles[None, :, 3:5]
    hi = obstacles[None, :, :2] + obstacles[None, :, 3:5]
    ne = points_nez[:, None, :2]
    below_lid = points_nez[:, None, 2] < obstacles[None, :, 2] + obstacles[None, :, 5] + safety_m - TOUCH_M
    if safety_m > 0:
        gap = np.maximum(np.maximum(lo - ne, ne - hi), 0.0)
        near = np.hypot(gap[..., 0], gap[..., 1]) < safety_m - TOUCH_M
    else:
        near = ((ne > lo + TOUCH_M) & (ne < hi - TOUCH_M)).all(axis=2)
    return (near & below_lid).any(axis=1)


def legs_too_close(waypoints: np.ndarray, obstacles: np.ndarray, safety_m: float, *, step_m: float = 0.05,
                   first_leg: int = 0) -> list[int]:
    """Indices of the legs of ``waypoints`` ``(K, >= 3)`` (north, east, altitude, ...) with a sampled point too
    close to a box; legs before ``first_leg`` are not checked (a snapped start's lead-in)."""
    legs = sample_legs(np.asarray(waypoints)[:, :3], step_m)
    return [k for k in range(first_leg, len(legs)) if too_close(legs[k], obstacles, safety_m).any()]


def legs_through_footprints(waypoints: np.ndarray, obstacles: np.ndarray, *, step_m: float = 0.05) -> list[int]:
    """Indices of the legs with a sampled point inside a box (footprint and below the top), no margin."""
    return legs_too_close(waypoints, obstacles, 0.0, step_m=step_m)
