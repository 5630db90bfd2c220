"""The flight path: planned waypoints -> a path the vehicle can fly without stopping at every corner.

Pure geometry in the map frame (metres, ``north, east, altitude``), no vehicle and no clock; ``mission.py`` steers
along it. Each intermediate waypoint becomes an arc tangent to both legs whose middle stays ``corner_cut_m``
inside the corner, and the path carries a speed schedule: cruise on straights, ``sqrt(a_lat * r)`` on an arc of
radius ``r``, braking at ``accel_mps2`` before every slower part and before the goal.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np


def leg_headings(waypoints: np.ndarray, initial_rad: float = 0.0, min_leg_m: float = 0.5) -> np.ndarray:
    """Heading (rad, from north, clockwise) to fly at each waypoint: along the leg that arrives there.

    The first waypoint takes the first leg's heading (turn on the spot before leaving); legs shorter than
    ``min_leg_m`` keep the previous heading.

    >>> np.round(leg_headings(np.array([[0, 0, 5, 0], [10, 0, 5, 0], [10, 10, 5, 0]])), 3).tolist()
    [0.0, 0.0, 1.571]
    """
    headings = np.empty(len(waypoints))
    previous = initial_rad
    for i in range(len(waypoints)):
        j = max(i, 1)
        if j < len(waypoints):
            d_north, d_east = waypoints[j, :2] - waypoints[j - 1, :2]
            if math.hypot(d_north, d_east) >= min_leg_m:
                previous = math.atan2(d_east, d_north) % (2 * math.pi)
        headings[i] = previous
    return headings


def corner_radius_m(turn_rad: float, corner_cut_m: float, max_tangent_m: float) -> float:
    """Radius (m) of the arc that rounds a corner turning by ``turn_rad``, tangent to both legs.

    The arc's farthest point from the legs (its middle) is ``r * (1 - cos(turn / 2))`` from each of them, so
    ``r = corner_cut_m / (1 - cos(turn / 2))`` keeps the rounded path within ``corner_cut_m`` of the planned legs;
    its tangent points lie ``r * tan(turn / 2)`` from the corner, and a smaller radius is used when that exceeds
    ``max_tangent_m`` (e.g. half the shorter leg, so neighbouring arcs do not overlap). ``inf`` for a straight
    line; ``0`` for a full reversal (the path stops there).

    >>> round(corner_radius_m(math.pi / 2, 0.5, 100.0), 4), round(corner_radius_m(math.pi / 2, 0.5, 1.0), 4)
    (1.7071, 1.0)
    """
    if turn_rad < 1e-6:
        return math.inf
    half = min(turn_rad, math.pi) / 2
    if half >= math.pi / 2 - 1e-9:
        return 0.0
    radius = corner_cut_m / (1.0 - math.cos(half))
    return min(radius, max_tangent_m / math.tan(half))


def corner_cut_m(turn_rad: float, radius_m: float) -> float:
    """How far (m) the middle of an arc of ``radius_m`` rounding a ``turn_rad`` corner lies from both legs.

    >>> round(corner_cut_m(math.pi / 2, 1.0), 4)
    0.2929
    """
    return 0.0 if not math.isfinite(radius_m) else radius_m * (1.0 - math.cos(min(turn_rad, math.pi) / 2))


#: ``room_fn(points_ne, altitude_m)``: the horizontal distance (m) from each map point ``(north_m, east_m)`` (N, 2)
#: to the nearest obstacle standing at ``altitude_m`` (m above the map's ground), ``(N,)``.
RoomFn = Callable[[np.ndarray, float], np.ndarray]
#: ``(M, 2)`` unit horizontal directions (north, east) -> ``(M,)`` the fastest ground speed along each (m/s).
SpeedCapFn = Callable[[np.ndarray], np.ndarray]


def _arc(corner: np.ndarray, u_in: np.ndarray, u_out: np.ndarray, turn_rad: float, radius_m: float,
         step_m: float) -> np.ndarray:
    """Points (n+1, 3) every ``step_m`` or less along the arc of ``radius_m`` rounding ``corner`` (3,) from the
    unit direction ``u_in`` to ``u_out``: from the tangent point on the leg in to the one on the leg out."""
    p1 = corner - radius_m * math.tan(turn_rad / 2) * u_in
    centre = p1 + radius_m * (u_out - u_in * float(u_in @ u_out)) / math.sin(turn_rad)
    e1 = (p1 - centre) / radius_m
    n = max(2, math.ceil(radius_m * turn_rad / step_m))
    phi = turn_rad * np.arange(n + 1) / n
    return centre + radius_m * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * u_in)


def widest_radius_m(corner: np.ndarray, u_in: np.ndarray, u_out: np.ndarray, turn_rad: float, radius_m: float,
                    max_radius_m: float, room_fn: RoomFn, room_m: float, growth: float = 1.25,
                    step_m: float = 1.0) -> float:
    """The widest radius (m), from ``radius_m`` up to ``max_radius_m`` in steps of ``growth``, whose arc rounding
    ``corner`` (map ``north, east, altitude``; the legs' unit directions ``u_in``, ``u_out``) keeps every point
    ``room_m`` or more from the obstacles (``room_fn``, checked every ``step_m``); ``radius_m`` when none wider does.
    The search stops at the first radius that fails: a wider arc reaches deeper into the corner.

    >>> room = lambda p, alt: np.hypot(p[:, 0] - 2.0, p[:, 1] - 8.0) - 1.0  # a post of 1 m inside the turn
    >>> corner, u_in, u_out = np.array([10.0, 0.0, 5.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    >>> round(widest_radius_m(corner, u_in, u_out, math.pi / 2, 1.7, 20.0, room, 4.5), 2)  # north, then east
    12.67
    >>> widest_radius_m(corner, u_in, u_out, math.pi / 2, 1.7, 20.0, lambda p, alt: np.full(len(p), 9.0), 4.5)
    20.0
    """
    best = radius_m
    while best < max_radius_m - 1e-9:
        radius = min(best * growth, max_radius_m)
        arc = _arc(corner, u_in, u_out, turn_rad, radius, step_m)
        if float(np.min(room_fn(arc[:, :2], float(corner[2])))) < room_m:
            break
        best = radius
    return best


@dataclass(frozen=True)
class _Corner:
    """A point of the polyline :func:`smooth_path` rounds: a waypoint, or (``count`` 2) the corner that stands for
    a close pair of them, with the narrowest radius (m) whose arc leaves the outer legs before the pair and the
    room its arcs are checked against (:func:`_merge_close_pairs`)."""

    point: np.ndarray
    count: int = 1
    min_radius_m: float = 0.0
    room_fn: RoomFn | None = None


def _distance_to_polyline(points_ne: np.ndarray, polyline_ne: np.ndarray) -> np.ndarray:
    """(N,) distance (m) from each point (N, 2) to the nearest segment of ``polyline_ne`` (K, 2)."""
    best = np.full(len(points_ne), np.inf)
    for a, b in zip(polyline_ne[:-1], polyline_ne[1:]):
        leg = b - a
        f = np.clip(((points_ne - a) @ leg) / max(float(leg @ leg), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(a + f[:, None] * leg - points_ne).T))
    return best


def _merge_close_pairs(pts: np.ndarray, room_fn: RoomFn, room_m: float, max_cut_m: float,
                       short_m: float = 10.0) -> list[_Corner]:
    """The polyline's points, each level pair of waypoints ``B, C`` less than ``short_m`` apart that turn the same
    way made one corner where the outer legs (``A -> B`` and ``C -> D``) meet: grid pruning leaves such pairs where a
    route rounds a building's corner, and each of the two arcs may use only half the short leg between them (turns
    of 41 and 26 degrees 3.6 m apart were flown at 3.6 and 4.6 m/s). A pair is merged when the narrowest arc round the
    meeting point whose tangent points lie before ``B`` and after ``C`` keeps ``room_m`` from the obstacles and
    stays within ``max_cut_m`` of the legs ``A-B-C-D`` (checked, as every wider arc is, by the room function the
    corner carries)."""
    out = [_Corner(pts[0])]
    i = 1
    while i < len(pts) - 1:
        a, b = out[-1].point, pts[i]
        merged = None
        if i + 2 < len(pts):
            c, d = pts[i + 1], pts[i + 2]
            merged = _merged_pair(a, b, c, d, room_fn, room_m, max_cut_m, short_m)
        if merged is None:
            out.append(_Corner(b))
            i += 1
        else:
            out.append(merged)
            i += 2
    if len(pts) > 1:
        out.append(_Corner(pts[-1]))
    return out


def _merged_pair(a, b, c, d, room_fn: RoomFn, room_m: float, max_cut_m: float, short_m: float) -> _Corner | None:
    """The corner standing for waypoints ``b, c`` between ``a`` and ``d`` (see :func:`_merge_close_pairs`), or None."""
    if np.ptp([a[2], b[2], c[2], d[2]]) > 1e-6 or not 1e-6 < float(np.linalg.norm(c - b)) <= short_m:
        return None
    u_in, mid, u_out = b - a, c - b, d - c
    if min(np.linalg.norm(u_in), np.linalg.norm(u_out)) < 1e-6:
        return None
    u_in, u_out = u_in / np.linalg.norm(u_in), u_out / np.linalg.norm(u_out)
    cross = lambda p, q: float(p[0] * q[1] - p[1] * q[0])  # noqa: E731
    if cross(u_in, mid) * cross(mid, u_out) <= 0.0:  # not both turning the same way
        return None
    turn = math.acos(max(-1.0, min(1.0, float(u_in @ u_out))))
    det = cross(u_in, u_out)
    if not 1e-3 < turn < math.pi - 0.1 or abs(det) < 1e-9:
        return None
    t = cross(mid, u_out) / det  # the outer legs meet at b + t u_in = c - s u_out (t u_in + s u_out = c - b)
    s = cross(u_in, mid) / det
    if t < 0.0 or s < 0.0:
        return None
    x = b + t * u_in
    min_radius = max(t, s) / math.tan(turn / 2)
    if min_radius * math.tan(turn / 2) > 0.5 * min(float(np.linalg.norm(x - a)), float(np.linalg.norm(d - x))):
        return None
    legs = np.array([a[:2], b[:2], c[:2], d[:2]])

    def room(points_ne: np.ndarray, altitude_m: float) -> np.ndarray:
        near = room_fn(points_ne, altitude_m)
        if math.isinf(max_cut_m):
            return near
        return np.minimum(near, room_m + max_cut_m - _distance_to_polyline(points_ne, legs))

    arc = _arc(x, u_in, u_out, turn, max(min_radius, 1e-3), 1.0)
    if float(np.min(room(arc[:, :2], float(x[2])))) < room_m:
        return None
    return _Corner(x, 2, min_radius, room)


#: :meth:`SmoothPath.project` looks at this many segments or fewer in Python floats, more with NumPy
_FEW_SEGMENTS = 8


@dataclass(frozen=True)
class SmoothPath:
    """The planned polyline with rounded corners and the speed to fly at each point of it (map frame).

    ``points`` (N, 3) are ``[north_m, east_m, altitude_m]``: the straight legs' ends and samples of each corner's
    arc; ``s_m`` (N,) the arc length at each point; ``segment_speed_mps`` (N-1,) the most each segment allows
    (cruise, ``sqrt(lateral_accel * r)`` on an arc of radius r, the vertical limit on climbing/descending legs);
    ``point_speed_mps`` (N,) the speed at each point once braking at ``accel_mps2`` for everything ahead is
    included (0 at the end); ``waypoint_s_m`` (K,) where each input waypoint counts as passed (the middle of its
    corner's arc). Build one with :func:`smooth_path`.
    """

    points: np.ndarray
    s_m: np.ndarray
    segment_speed_mps: np.ndarray
    point_speed_mps: np.ndarray
    waypoint_s_m: np.ndarray
    accel_mps2: float
    #: (N-1,) each segment's arc radius (m; ``inf`` on a straight leg), to schedule the speeds again
    radius_m: np.ndarray | None = None

    def rescheduled(self, *, cruise_mps: float, accel_mps2: float, lateral_accel_mps2: float,
                    vertical_mps: float, speed_cap_fn: SpeedCapFn | None = None) -> SmoothPath:
        """The same path with its speeds scheduled again (see :func:`smooth_path`), e.g. for a wind that leaves
        the vehicle less to turn and brake with (:mod:`~skyroute.flight.tilt`); arc lengths and waypoints as they
        were, so progress along it carries over."""
        radii = self.radius_m if self.radius_m is not None else np.full(max(len(self.points) - 1, 0), np.inf)
        seg, speed = _schedule(self.points, radii, cruise_mps=cruise_mps, accel_mps2=accel_mps2,
                               lateral_accel_mps2=lateral_accel_mps2, vertical_mps=vertical_mps,
                               speed_cap_fn=speed_cap_fn)
        return SmoothPath(self.points, self.s_m, seg, speed, self.waypoint_s_m, float(accel_mps2), radii)

    @cached_property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    # The follower asks these at every poll: Python floats and bisect, not NumPy scalars (a few times faster).
    @cached_property
    def _s_list(self) -> list[float]:
        return self.s_m.tolist()

    @cached_property
    def _point_rows(self) -> list[list[float]]:
        return self.points.tolist()

    @cached_property
    def _speeds(self) -> tuple[list[float], list[float]]:
        return self.segment_speed_mps.tolist(), self.point_speed_mps.tolist()

    def _segment(self, s_m: float) -> int:
        j = bisect.bisect_right(self._s_list, s_m) - 1
        return min(max(j, 0), max(len(self.points) - 2, 0))

    def speed_at(self, s_m: float) -> float:
        """Speed (m/s) to fly at arc length ``s_m``: the segment's limit, and braking for every limit ahead."""
        if len(self.points) < 2 or s_m >= self.length_m:
            return 0.0
        j = self._segment(s_m)
        segment_speed, point_speed = self._speeds
        braking = math.sqrt(point_speed[j + 1] ** 2 + 2.0 * self.accel_mps2 * max(self._s_list[j + 1] - s_m, 0.0))
        return float(min(segment_speed[j], braking))

    def point_at(self, s_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) and unit tangent (3,) at arc length ``s_m`` (clamped to the path)."""
        if len(self.points) < 2:
            return self.points[0].copy(), np.zeros(3)
        s_m = min(max(s_m, 0.0), self.length_m)
        j = self._segment(s_m)
        a, b = self._point_rows[j], self._point_rows[j + 1]
        s = self._s_list
        ds = s[j + 1] - s[j]
        if ds > 1e-12:
            tangent = [(b[0] - a[0]) / ds, (b[1] - a[1]) / ds, (b[2] - a[2]) / ds]
        else:
            tangent = [0.0, 0.0, 0.0]
        along = s_m - s[j]
        point = [a[0] + tangent[0] * along, a[1] + tangent[1] * along, a[2] + tangent[2] * along]
        return np.array(point), np.array(tangent)

    def project(self, position, from_s_m: float = 0.0, window_m: float = 30.0) -> float:
        """Arc length of the path point closest to ``position`` (3,), searching from ``from_s_m`` to ``window_m``
        beyond it: forward only, so progress stays monotonic where the path passes near itself."""
        p = np.asarray(position, float)
        if len(self.points) < 2:
            return 0.0
        s = self.s_m
        j0 = self._segment(from_s_m)
        j1 = bisect.bisect_right(self._s_list, from_s_m + window_m, 0, len(s) - 1)  # segments starting in the window
        if j1 <= j0:
            return from_s_m
        if j1 - j0 <= _FEW_SEGMENTS:
            return self._project_few(p.tolist(), from_s_m, j0, j1)
        a = self.points[j0:j1]
        ab, ds, some, safe = self._legs
        ab, ds, some, safe = ab[j0:j1], ds[j0:j1], some[j0:j1], safe[j0:j1]
        lowest = np.where(some, np.maximum(0.0, (from_s_m - s[j0:j1]) / safe), 0.0)  # not behind from_s_m
        f = np.where(some, np.minimum(np.maximum(np.einsum("ij,ij->i", p - a, ab) / safe**2, lowest), 1.0), 0.0)
        gap = a + f[:, None] * ab - p
        d = np.sqrt(np.einsum("ij,ij->i", gap, gap))
        best_d, best_k = math.inf, -1
        for k, dk in enumerate(d.tolist()):  # the first of near-equal distances wins, as the path runs
            if dk < best_d - 1e-9:
                best_d, best_k = dk, k
        return float(s[j0 + best_k] + f[best_k] * ds[best_k]) if best_k >= 0 else from_s_m

    def _project_few(self, p: list[float], from_s_m: float, j0: int, j1: int) -> float:
        """:meth:`project` over segments ``j0:j1`` in Python floats: on a straight leg the window holds one or two,
        where NumPy's per-call cost is most of the work."""
        s, rows = self._s_list, self._point_rows
        best_d, best_s = math.inf, from_s_m
        for j in range(j0, j1):
            a, b = rows[j], rows[j + 1]
            ds = s[j + 1] - s[j]
            if ds > 1e-12:
                ab = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
                dot = (p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1] + (p[2] - a[2]) * ab[2]
                f = min(max(dot / ds**2, max(0.0, (from_s_m - s[j]) / ds)), 1.0)
            else:
                ab, f = (0.0, 0.0, 0.0), 0.0
            gap = (a[0] + f * ab[0] - p[0], a[1] + f * ab[1] - p[1], a[2] + f * ab[2] - p[2])
            d = math.sqrt(gap[0] ** 2 + gap[1] ** 2 + gap[2] ** 2)
            if d < best_d - 1e-9:  # the first of near-equal distances wins, as the path runs
                best_d, best_s = d, s[j] + f * ds
        return float(best_s)

    @cached_property
    def _legs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each segment's vector (N-1, 3), arc length, whether it has any, and the length to divide by."""
        ds = self.s_m[1:] - self.s_m[:-1]
        some = ds > 1e-12
        return self.points[1:] - self.points[:-1], ds, some, np.where(some, ds, 1.0)


def smooth_path(waypoints: np.ndarray, *, corner_cut_m: float = 0.5, cruise_mps: float = 10.0,
                accel_mps2: float = 3.0, lateral_accel_mps2: float = 3.0, vertical_mps: float = 1.5,
                arc_step_m: float = 0.5, room_fn: RoomFn | None = None, room_m: float = 0.0,
                max_cut_m: float = math.inf, speed_cap_fn: SpeedCapFn | None = None) -> SmoothPath:
    """Round each corner of ``waypoints`` (rows ``[north_m, east_m, altitude_m, ...]``) and schedule the speed.

    Each interior waypoint becomes an arc tangent to both legs with the :func:`corner_radius_m` that keeps it within
    ``corner_cut_m`` of them (tangent points at most half of either leg from the corner), sampled every
    ``arc_step_m``. Speeds: ``cruise_mps`` on straights, ``sqrt(lateral_accel_mps2 * r)`` on an arc, at most
    ``vertical_mps`` vertically, at most ``speed_cap_fn(directions)`` over the ground along each segment's
    horizontal direction (``(M, 2)`` unit north, east rows to ``(M,)`` m/s: what the wind leaves the tilt,
    :mod:`~skyroute.flight.tilt`), braking at ``accel_mps2`` before each slower part and to a stop at the last
    waypoint.

    With ``room_fn`` (what stands around the path), a level corner's arc is widened as far as the obstacles let it
    (:func:`widest_radius_m`: every point of the arc ``room_m`` or more from them, the tangent points within half
    of either leg, the arc's middle at most ``max_cut_m`` from them, no wider than cruise speed needs):
    ``corner_cut_m`` is the bound when nothing is known of what stands around, and a street corner with room to
    spare was flown at 4-6 m/s where 8-10 m/s keeps the margin. ``max_cut_m`` bounds what ``room_fn`` cannot
    know: an obstacle nobody has seen yet, standing a margin from the legs, stays that much less from the arc.

    >>> p = smooth_path(np.array([[0, 0, 5], [20, 0, 5], [20, 20, 5]]), corner_cut_m=0.5, lateral_accel_mps2=3.0)
    >>> round(float(p.segment_speed_mps.min()), 3), p.speed_at(0.0), round(p.speed_at(p.length_m - 1.5), 3)
    (2.263, 10.0, 3.0)
    """
    pts = np.asarray(waypoints, float)[:, :3]
    if room_fn is None:
        corners = [_Corner(p) for p in pts]
    else:
        corners = _merge_close_pairs(pts, room_fn, room_m, max_cut_m)
    out: list[np.ndarray] = [pts[0]]
    radii: list[float] = []  # one per segment of ``out``
    wp_index = [0]
    for i in range(1, len(corners) - 1):
        a, b, c = corners[i - 1].point, corners[i].point, corners[i + 1].point
        leg_in, leg_out = float(np.linalg.norm(b - a)), float(np.linalg.norm(c - b))
        turn = 0.0
        if leg_in > 1e-9 and leg_out > 1e-9:
            u_in, u_out = (b - a) / leg_in, (c - b) / leg_out
            turn = math.acos(max(-1.0, min(1.0, float(u_in @ u_out))))
        max_tangent_m = 0.5 * min(leg_in, leg_out)
        radius = corner_radius_m(turn, corner_cut_m, max_tangent_m)
        if not math.isfinite(radius) or radius < 1e-6:
            out.append(b)
            radii.append(math.inf)
            wp_index.extend([len(out) - 1] * corners[i].count)
            continue
        merged = corners[i].room_fn is not None
        if merged:  # a pair's corner: from the narrowest arc that leaves the outer legs before the pair
            radius = corners[i].min_radius_m
        if room_fn is not None and abs(a[2] - b[2]) < 1e-6 and abs(c[2] - b[2]) < 1e-6:
            widest = min(max_tangent_m / math.tan(turn / 2), cruise_mps**2 / lateral_accel_mps2,
                         math.inf if merged else max_cut_m / (1.0 - math.cos(turn / 2)))
            radius = widest_radius_m(b, u_in, u_out, turn, radius, widest, corners[i].room_fn or room_fn, room_m)
        arc = _arc(b, u_in, u_out, turn, radius, arc_step_m)
        out.append(arc[0])
        radii.append(math.inf)
        for k in range(1, len(arc)):
            out.append(arc[k])
            radii.append(radius)
            if k == (len(arc) - 1) // 2:
                wp_index.extend([len(out) - 1] * corners[i].count)
    if len(pts) > 1:
        out.append(pts[-1])
        radii.append(math.inf)
        wp_index.append(len(out) - 1)
    points = np.array(out, float)
    s_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    radius_m = np.array(radii, float)
    seg, speed = _schedule(points, radius_m, cruise_mps=cruise_mps, accel_mps2=accel_mps2,
                           lateral_accel_mps2=lateral_accel_mps2, vertical_mps=vertical_mps,
                           speed_cap_fn=speed_cap_fn)
    return SmoothPath(points, s_m, seg, speed, s_m[wp_index], float(accel_mps2), radius_m)


def _schedule(points: np.ndarray, radii: np.ndarray, *, cruise_mps: float, accel_mps2: float,
              lateral_accel_mps2: float, vertical_mps: float,
              speed_cap_fn: SpeedCapFn | None) -> tuple[np.ndarray, np.ndarray]:
    """``(segment_speed_mps, point_speed_mps)`` for the polyline ``points`` whose segments have arc ``radii``."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    seg = np.full(len(steps), float(cruise_mps))
    for j, (step, radius) in enumerate(zip(steps, radii, strict=True)):
        if math.isfinite(radius):
            seg[j] = min(seg[j], math.sqrt(lateral_accel_mps2 * radius))
        climb = abs(points[j + 1, 2] - points[j, 2])
        if step > 1e-12 and climb > 1e-9:
            seg[j] = min(seg[j], vertical_mps * step / climb)
    if speed_cap_fn is not None and len(steps):
        along = np.diff(points[:, :2], axis=0)
        level = np.hypot(along[:, 0], along[:, 1])
        moving = level > 1e-9
        if moving.any():  # a cap on the ground speed: on a climbing segment only its level share is capped
            caps = np.asarray(speed_cap_fn(along[moving] / level[moving, None]), float)
            seg[moving] = np.minimum(seg[moving], caps * steps[moving] / level[moving])
    speed = np.empty(len(points))
    speed[0] = seg[0] if len(seg) else 0.0
    speed[1:-1] = np.minimum(seg[:-1], seg[1:])
    speed[-1] = 0.0
    for j in range(len(points) - 2, -1, -1):
        speed[j] = min(speed[j], math.sqrt(speed[j + 1] ** 2 + 2.0 * accel_mps2 * steps[j]))
    return seg, speed


def path_length_m(points: np.ndarray) -> float:
    """3D length of a polyline given as rows whose first three columns are north, east, altitude (m)."""
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(np.asarray(points, float)[:, :3], axis=0), axis=1).sum())
