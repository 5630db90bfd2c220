"""Keep off what the range sensor reads close, wherever the position estimate says the vehicle is.

The route keeps its margin from the map's buildings *in the estimate's frame*; the autopilot flies its estimate
along it, so the vehicle itself is off the route by the estimate's error (metres, for a GPS with a metre or two of
drift), and a street's wall can come much closer than the margin while the map says all is well. The live layer
cannot tell: a reading that close to one of the map's buildings is taken for that building, placed where the
estimate puts it. But the reading itself is relative to the vehicle, so it is right whatever the estimate says.

:class:`KeepOff` shifts the route (``shift_ne``, map north and east m) by as little as keeps ``keep_m`` between
each recent reading's point and the point the vehicle tracks, and the route ahead over the next second and a half
of flight (a building's corner is read before the vehicle turns round it, and the autopilot needs that long to
move over). The shift relaxes towards zero (``relax_s``) as far as the readings allow, so it lasts as long as
something stands too close. ArduPilot's own avoidance backs away the same way (AVOID_MARGIN, AVOID_BACKUP_SPD);
PX4's collision prevention only stops the approach (CP_DIST).

Only narrow sectors (PX4's 5 degrees) place a point well enough. ArduPilot's 45 degree ones put their nearest
point anywhere on a wide arc: kept off by the face through it normal to the sector's centre, at the vehicle only,
they shifted the route the wrong way at corners, where two sectors read close at once and their faces leave no
room (2 m drift, SF, six seeds: minimum clearance 3.11 m on average with, 3.30 m without; PX4's: 3.88 m with,
3.70 m without), so they are left to the scan matching and the live layer.

Below, the downward rangefinder does the same for what the horizontal sensor cannot see: a roof lower than the
flight altitude, which the route keeps the margin from sideways, is under the vehicle when the estimate is off.
While it reads less than ``keep_m``, the route is lifted (``lift_m``) until it reads that again (ArduCopter's
surface tracking climbs over what its rangefinder reads the same way).

The readings are kept as world points (the local frame), so a reading a few cycles old still says where the
face was: the vehicle's own motion since is taken out. Arrays in, arrays out; no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

#: A reading counts this long (autopilot seconds): a few of the sensor's 10 Hz cycles, short against the
#: estimate's drift and the vehicle's motion (its own motion since is taken out, the face's extent is not).
WINDOW_S = 0.5
#: A roof lifts the route once this many rangefinder readings in a row read it.
HEIGHT_VOTES = 3
#: Faces closer than kept on every side leave no room: this many passes of cyclic projections settle between.
PASSES = 12
#: A point's circle is taken as its tangent half-plane this many times, each facing the last answer.
TANGENT_ROUNDS = 3
#: The nearest point is sought on at most this many lines, the most violated one added at a time.
MAX_ACTIVE = 24
#: A constraint is met within this much (m).
TOLERANCE_M = 1e-7
#: The route ahead is kept off the readings' points over this much flight (autopilot s) ...
AHEAD_S = 1.5
#: ... sampled this finely (m).
AHEAD_STEP_M = 1.0
#: Sectors at most this wide (half width, rad) are taken.
NARROW_HALF_WIDTH_RAD = math.radians(3.0)


@dataclass
class KeepOff:
    """The sideways shift and the lift that keep the vehicle ``keep_m`` (m) from everything the sensors read.

    Parameters
    ----------
    keep_m : float
        The distance (m) to keep from every reading (the mission keeps 80 % of its planning margin: a route
        through the map keeps more, so only an estimate that is off brings a reading this close).
    relax_s : float
        Time constant (autopilot s) of the shift's return to zero where nothing is read that close.
    max_shift_m : float
        The shift never exceeds this (m); past it, the planning margin and the live layer must do.
    """

    keep_m: float
    relax_s: float = 3.0
    max_shift_m: float = 5.0
    shift_ne: np.ndarray = field(default_factory=lambda: np.zeros(2))
    lift_m: float = 0.0  # how far the route is lifted (m up)
    largest_m: float = 0.0  # the largest shift this flight (m), for the log
    highest_m: float = 0.0  # the largest lift this flight (m), for the log
    #: bearing (rounded rad) -> (north, east (local m), unit n, e, received s, how far off the point may be (m),
    #: distance read (m))
    _points: dict = field(default_factory=dict)
    _heights: deque = field(default_factory=lambda: deque(maxlen=8))  # (height m, received s)

    def observe(self, scan) -> None:
        """Take a horizontal scan (``RangeScan``, stamped with the local position it was read at): each sector's
        reading replaces that bearing's last one; an empty sector (nothing in range) forgets it. Sectors wider
        than :data:`NARROW_HALF_WIDTH_RAD` are not taken."""
        at = getattr(scan, "local_ne", None)
        half = float(scan.half_width_rad)
        if at is None or half > NARROW_HALF_WIDTH_RAD:
            return
        received = float(scan.received_s)
        for bearing, distance in zip(np.asarray(scan.bearings_rad, float), np.asarray(scan.distances_m, float)):
            key = round(float(bearing), 3)
            if math.isnan(distance):
                continue  # unknown: the last reading stands until it is too old
            if not math.isfinite(distance):
                self._points.pop(key, None)
                continue
            n, e = math.cos(bearing), math.sin(bearing)
            self._points[key] = (at[0] + distance * n, at[1] + distance * e, n, e, received,
                                 distance * math.sin(half), distance)

    def reset(self) -> None:
        """A new flight: no shift, no readings."""
        self.shift_ne, self.lift_m = np.zeros(2), 0.0
        self.forget()
        self._heights.clear()

    def forget(self) -> None:
        """Drop the readings (the local frame they are kept in moved: an estimator reset)."""
        self._points.clear()

    def nearest(self) -> tuple[float, float]:
        """The nearest point read in the window, from where it was read: distance (m) and bearing (deg)."""
        best = (math.inf, math.nan)
        for _, _, n, e, _, _, distance in self._points.values():
            if distance < best[0]:
                best = (distance, math.degrees(math.atan2(e, n)) % 360.0)
        return best

    def observe_height(self, reading) -> None:
        """Take a downward rangefinder reading (``HeightReading``); one outside its stated range says nothing."""
        h = float(reading.height_m)
        if math.isfinite(h) and float(reading.min_range_m) < h < float(reading.max_range_m):
            self._heights.append((h, float(reading.received_s)))

    def update_lift(self, above_m: float, *, now_s: float, rate: float, dt_s: float) -> float:
        """The new lift (m up): at least what keeps the tracked altitude ``keep_m`` over what the rangefinder
        reads below (the largest of its last :data:`HEIGHT_VOTES` readings in the window: a glitch does not lift
        the route, and climbing, the latest is the largest), else relaxing towards 0. ``above_m`` is how far the
        vehicle is above the lifted route's altitude now; the rest as :meth:`update`."""
        while self._heights and (now_s - self._heights[0][1]) * rate > WINDOW_S:
            self._heights.popleft()
        relax = math.exp(-max(dt_s, 0.0) / self.relax_s) if self.relax_s > 0 else 0.0
        lift = self.lift_m * relax
        if self._heights:
            below = max(h for h, _ in list(self._heights)[-HEIGHT_VOTES:])
            lift = max(lift, self.lift_m + self.keep_m - below + float(above_m))
        self.lift_m = min(max(lift, 0.0), self.max_shift_m)
        self.highest_m = max(self.highest_m, self.lift_m)
        return self.lift_m

    def update(self, local_ne, route_ne, *, now_s: float, rate: float, dt_s: float) -> np.ndarray:
        """The new shift (map north, east m).

        ``local_ne`` is where the vehicle is now (the autopilot's local frame, the readings' frame), ``route_ne``
        (K, 2) the shifted route relative to it (m): first the point it tracks, then the route ahead
        (:func:`ahead_distances_m`); ``now_s`` our clock (the readings' ``received_s``), ``rate`` autopilot
        seconds per second of it, ``dt_s`` autopilot seconds since the last update."""
        stale = [k for k, v in self._points.items() if (now_s - v[4]) * rate > WINDOW_S]
        for k in stale:
            del self._points[k]
        relax = 1.0 - math.exp(-max(dt_s, 0.0) / self.relax_s) if self.relax_s > 0 else 1.0
        want = -relax * self.shift_ne
        if self._points:
            want = self._keep_clear(want, np.array(list(self._points.values())), np.asarray(local_ne, float)[:2],
                                    np.asarray(route_ne, float).reshape(-1, 2))
        shift = self.shift_ne + want
        norm = float(np.hypot(*shift))
        if norm > self.max_shift_m:
            shift *= self.max_shift_m / norm
        self.shift_ne = shift
        self.largest_m = max(self.largest_m, min(norm, self.max_shift_m))
        return shift

    @property
    def idle(self) -> bool:
        """Nothing read, nothing shifted: an update would change nothing."""
        return not (self._points or self._heights or self.shift_ne.any() or self.lift_m)

    def _keep_clear(self, want: np.ndarray, pts: np.ndarray, local_ne: np.ndarray, route: np.ndarray) -> np.ndarray:
        """The change of shift nearest ``want`` that keeps ``route`` (K, 2, from the vehicle) ``keep_m`` off the
        readings ``pts`` (rows of ``_points``).

        Each point is kept off every point of the route: outside a circle, taken as the half-plane beyond its
        tangent facing the route point (inside the circle's complement whatever the change), found again
        :data:`TANGENT_ROUNDS` times from the last answer so the half-planes turn to face it. The point sits on
        the sector's centre line, up to ``distance * sin(half width)`` from where it was read (0.65 m at 15 m: a
        wall along the route, read obliquely, would seem that much nearer): the circle is that much smaller."""
        points = pts[:, :2] - local_ne  # the readings' points, from the vehicle
        keep = self.keep_m - pts[:, 5]
        y = np.zeros(2)
        for _ in range(TANGENT_ROUNDS):
            away = route[:, None, :] + y - points[None, :, :]
            dist = np.hypot(away[..., 0], away[..., 1])
            near = dist > 1e-6
            unit = away[near] / dist[near][:, None]
            room = dist[near] - np.broadcast_to(keep[None, :], dist.shape)[near] - unit @ y
            y = project_onto_half_planes(want, -unit, room)
            if np.array_equal(y, want):
                break  # nothing in the way: facing the answer changes nothing
        return y


def ahead_distances_m(speed_mps: float) -> np.ndarray:
    """Arc lengths (m) past the tracked point at which the route ahead is checked: :data:`AHEAD_S` of flight at
    ``speed_mps``, every :data:`AHEAD_STEP_M`."""
    reach = max(float(speed_mps), 0.0) * AHEAD_S
    return np.arange(AHEAD_STEP_M, reach + 1e-9, AHEAD_STEP_M)


def project_onto_half_planes(x: np.ndarray, normals: np.ndarray, room: np.ndarray) -> np.ndarray:
    """The point nearest ``x`` (2,) with ``normals[i] . y <= room[i]`` for every unit normal (N, 2).

    An active set: the nearest point meeting a few of the lines (the most violated first) is the answer once it
    meets the rest; else the line it violates most joins them. In the plane, the nearest point of a few is
    ``x`` itself, its projection onto one line, or where two cross. When no point meets them all (faces on both
    sides closer than kept), cyclic projections onto the lines taken so far settle between them.

    >>> project_onto_half_planes(np.zeros(2), np.array([[1.0, 0.0]]), np.array([-2.0])).tolist()
    [-2.0, 0.0]
    >>> project_onto_half_planes(np.zeros(2), np.array([[1.0, 0.0], [0.0, -1.0]]), np.array([-1.0, -3.0])).tolist()
    [-1.0, 3.0]
    """
    x = np.asarray(x, float)
    normals, room = np.asarray(normals, float).reshape(-1, 2), np.asarray(room, float).ravel()
    over = normals @ x - room
    if not len(over) or over.max() <= TOLERANCE_M:
        return x.copy()
    active = [int(np.argmax(over))]
    for _ in range(MAX_ACTIVE):
        y = _nearest_meeting(x, normals[active], room[active])
        if y is None:
            break
        over = normals @ y - room
        worst = int(np.argmax(over))
        if over[worst] <= TOLERANCE_M:
            return y
        active.append(worst)
    y = x.copy()
    for _ in range(PASSES):
        for k in active:
            excess = float(normals[k] @ y) - float(room[k])
            if excess > 0:
                y -= excess * normals[k]
    return y


def _nearest_meeting(x: np.ndarray, n: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """The point nearest ``x`` meeting the few half-planes ``n . y <= r``; None if none does."""
    candidates = [x[None, :], x - (n @ x - r)[:, None] * n]
    i, j = np.triu_indices(len(n), 1)
    det = n[i, 0] * n[j, 1] - n[i, 1] * n[j, 0]
    ok = np.abs(det) > 1e-9
    i, j, det = i[ok], j[ok], det[ok]
    if len(i):
        candidates.append(np.column_stack([(r[i] * n[j, 1] - r[j] * n[i, 1]) / det,
                                           (n[i, 0] * r[j] - n[j, 0] * r[i]) / det]))
    c = np.vstack(candidates)
    c = c[(c @ n.T - r <= TOLERANCE_M).all(axis=1)]
    if not len(c):
        return None
    return c[np.argmin(np.hypot(*(c - x).T))].copy()
