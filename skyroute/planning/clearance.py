"""Clearance along a straight line, and the surface under a point: exact geometry on the map's boxes.

The mission bounds what its last command can do (a crashed client, a cut link): the autopilot may carry on
along the command's velocity for a few seconds. :meth:`Clearance.ray_m` says how far a horizontal ray stays out
of every building's planning margin (Euclidean distance to the box, for buildings whose top plus the margin
reaches the altitude, as the configuration space counts them), so the mission can cap its feed-forward speed.
:meth:`Clearance.surface_m` is the height of what stands under a point (a roof, or the ground), for the
altitude datum.

Obstacles are the rows of ``colliders.csv``: ``[north_m, east_m, alt_m, d_north_m, d_east_m, d_alt_m]``
(centre and half sizes, map frame).
"""

from __future__ import annotations

import math

import numpy as np


class Clearance:
    """Geometry queries on one map's boxes with one safety margin.

    Parameters
    ----------
    obstacles : ndarray (N, 6)
        Box centres and half sizes (m, map frame).
    safety_m : float
        The planning margin (m).
    tolerance_m : float
        A ray counts as blocked where it comes closer than ``safety_m - tolerance_m`` to a building (planned
        paths run along the margin's edge; the tolerance keeps a parallel ray along it free).

    >>> c = Clearance(np.array([[30.0, 0.0, 10.0, 5.0, 5.0, 10.0]]), safety_m=5.0)
    >>> c.ray_m(0.0, 0.0, 5.0, 1.0, 0.0, 100.0)  # north into the box: its face at 25 m, margin 4 m before it
    21.0
    >>> c.ray_m(0.0, 20.0, 5.0, 1.0, 0.0, 100.0)  # a parallel street 15 m east of the box: clear
    100.0
    >>> c.surface_m(30.0, 0.0), c.surface_m(0.0, 0.0)
    (20.0, 0.0)
    """

    def __init__(self, obstacles: np.ndarray, safety_m: float, tolerance_m: float = 1.0, step_m: float = 0.25):
        boxes = np.asarray(obstacles, float).reshape(-1, 6)
        self.lo = boxes[:, :2] - boxes[:, 3:5]
        self.hi = boxes[:, :2] + boxes[:, 3:5]
        self.tops = boxes[:, 2] + boxes[:, 5]
        self.safety_m, self.tolerance_m, self.step_m = float(safety_m), float(tolerance_m), float(step_m)

    def _distances(self, points: np.ndarray, altitude_m: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(P,) horizontal distance from each point to the nearest of the given boxes."""
        if len(lo) == 0:
            return np.full(len(points), np.inf)
        gap = np.maximum(np.maximum(lo[None] - points[:, None], points[:, None] - hi[None]), 0.0)
        return np.sqrt((gap**2).sum(axis=2)).min(axis=1)

    def ray_m(self, north_m: float, east_m: float, altitude_m: float, dir_north: float, dir_east: float,
              max_m: float) -> float:
        """How far (m, up to ``max_m``) the horizontal ray from the point along the unit direction stays clear.

        Clear: not closer than ``safety_m - tolerance_m`` to a building reaching ``altitude_m - safety_m``; a ray
        that starts closer than that is blocked where it gets 0.5 m closer than at its start.
        """
        if not max_m > 0:
            return 0.0
        norm = math.hypot(dir_north, dir_east)
        if norm < 1e-9:
            return max_m
        d = np.array([dir_north, dir_east]) / norm
        start = np.array([north_m, east_m], float)
        end = start + d * max_m
        reach = self.safety_m + 1e-6
        near = ((self.tops + self.safety_m > altitude_m)
                & np.all(self.lo - reach <= np.maximum(start, end), axis=1)
                & np.all(self.hi + reach >= np.minimum(start, end), axis=1))
        lo, hi = self.lo[near], self.hi[near]
        s = np.arange(0.0, max_m + self.step_m, self.step_m)
        s[-1] = min(s[-1], max_m)
        dist = self._distances(start[None] + s[:, None] * d[None], altitude_m, lo, hi)
        limit = min(self.safety_m - self.tolerance_m, dist[0] - 0.5)
        blocked = np.nonzero(dist < limit)[0]
        if len(blocked) == 0:
            return float(max_m)
        return float(max(s[blocked[0]] - self.step_m, 0.0))

    def distance_m(self, points_ne: np.ndarray, altitude_m: float) -> np.ndarray:
        """Horizontal distance (m) from each map point ``(north_m, east_m)`` (N, 2) to the nearest building
        reaching ``altitude_m - safety_m`` (as :meth:`ray_m` counts them), ``(N,)``; ``inf`` where none stands
        within ``safety_m`` of the points' bounding box plus 50 m.

        >>> c = Clearance(np.array([[30.0, 0.0, 10.0, 5.0, 5.0, 10.0]]), safety_m=5.0)
        >>> c.distance_m(np.array([[0.0, 0.0], [30.0, 8.0]]), 5.0).tolist(), c.distance_m(np.zeros((1, 2)), 30.0)
        ([25.0, 3.0], array([inf]))
        """
        p = np.asarray(points_ne, float).reshape(-1, 2)
        if len(p) == 0:
            return np.empty(0)
        reach = self.safety_m + 50.0
        near = ((self.tops + self.safety_m > altitude_m) & np.all(self.lo - reach <= p.max(axis=0), axis=1)
                & np.all(self.hi + reach >= p.min(axis=0), axis=1))
        return self._distances(p, altitude_m, self.lo[near], self.hi[near])

    def highest_crossed(self, points_ne: np.ndarray, home_ne) -> tuple[float, tuple[float, float]]:
        """The top (m above the map's ground) of the highest box that a straight line from any of the points to
        ``home_ne`` crosses (an autopilot's return flies such a line), and that box's centre; ``(0.0, home)`` when
        none does. Exact: a slab test of every segment against every box.

        >>> c = Clearance(np.array([[30.0, 0.0, 10.0, 5.0, 5.0, 10.0], [0.0, 50.0, 20.0, 2.0, 2.0, 20.0]]), 5.0)
        >>> c.highest_crossed(np.array([[60.0, 0.0], [60.0, 20.0]]), (0.0, 0.0))  # over the first box only
        (20.0, (30.0, 0.0))
        >>> c.highest_crossed(np.array([[0.0, -40.0]]), (0.0, 0.0))
        (0.0, (0.0, 0.0))
        """
        p = np.asarray(points_ne, float).reshape(-1, 2)
        home = np.asarray(home_ne, float)
        if len(p) == 0 or len(self.tops) == 0:
            return 0.0, (float(home[0]), float(home[1]))
        d = home[None] - p  # (P, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (self.lo[None] - p[:, None]) / d[:, None]  # (P, B, 2)
            t2 = (self.hi[None] - p[:, None]) / d[:, None]
        flat = d[:, None] == 0.0  # a segment parallel to an axis: inside that slab or not at all
        inside = (self.lo[None] <= p[:, None]) & (p[:, None] <= self.hi[None])
        t_in = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=2)
        t_out = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=2)
        crossed = (t_out >= np.maximum(t_in, 0.0)) & (t_in <= 1.0)  # (P, B)
        hit = crossed.any(axis=0)
        if not hit.any():
            return 0.0, (float(home[0]), float(home[1]))
        k = int(np.flatnonzero(hit)[np.argmax(self.tops[hit])])
        centre = (self.lo[k] + self.hi[k]) / 2.0
        return float(self.tops[k]), (float(centre[0]), float(centre[1]))

    def surface_m(self, north_m: float, east_m: float) -> float:
        """Height (m above the map's ground) of the highest box whose footprint holds the point, else 0."""
        inside = np.all((self.lo <= (north_m, east_m)) & ((north_m, east_m) <= self.hi), axis=1)
        return float(self.tops[inside].max()) if inside.any() else 0.0
