"""Scan matching: how far the position estimate is off, read from where the map's own buildings show in the scans.

A GPS position estimate drifts by metres over tens of seconds (the receiver states it: GPS_RAW_INT ``h_acc``); the
horizontal range sensor sees the map's buildings where they stand *relative to the vehicle*. Placed at the
estimate, a scan of a street's walls lands beside the map's walls by the estimate's error. Shifting it until it
fits them again measures that error, in every direction the buildings in view constrain (along a straight street
only across it). Arrays in, arrays out (planning never imports the vehicle or the mission).

* :class:`MapSurface`: the map's boxes that cut the sensor's plane, with signed distances (m) to their faces.
* :func:`match_scan`: the shift (map north, east m) that puts one scan's readings on those faces, with its
  information matrix (how well each direction is constrained); readings far from every face (a new obstacle, a
  building the map lacks) do not pull it.
* :class:`DriftEstimate`: the correction over time, a Kalman filter on a first-order Gauss-Markov error (the
  stated accuracy as its stationary spread, ``correlation_s`` its time constant): without matches it relaxes to
  0 with the stated accuracy as its spread, as the estimate itself.
* :class:`PositionFix`: the two together, fed scan by scan: ``correction_ne`` is what to add to the estimate (map
  frame) and ``bound_m`` how far off the corrected position may still be (:data:`SIGMAS` of its spread).

A reading is the nearest point anywhere in its sector, so its arc is sampled every :data:`ARC_STEP_RAD`: PX4's
5 degree sectors in five samples, ArduPilot's 45 degree ones in 31. ArduPilot sends one message per sector, and
eight readings are too few for a fit: :class:`PositionFix` gathers the sectors of :data:`GATHER_S` (a few sensor
cycles, each placed where it was read) and matches them together.

>>> boxes = np.array([[0.0, 20.0, 10.0, 50.0, 5.0, 10.0], [0.0, -20.0, 10.0, 50.0, 5.0, 10.0]])  # a street
>>> surface = MapSurface(boxes, altitude_m=5.0)
>>> float(surface.signed_distance(np.array([[0.0, 12.0]]), surface.near(0.0, 0.0, 30.0))[0][0])
3.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

#: The bound is this many standard deviations (equal to ``skyroute.vehicle.sensors.POSITION_ERROR_PER_ACCURACY``,
#: the factor a scan's ``position_error_m`` carries: a test keeps them equal).
SIGMAS = 3.0
#: Sectors wider than this (half width, rad) are not matched (ArduPilot's proximity sectors are 22.5).
MAX_HALF_WIDTH_RAD = math.radians(23.0)
#: A reading's arc is sampled at least this finely (rad).
ARC_STEP_RAD = math.radians(1.5)
#: Single-sector readings (ArduPilot's DISTANCE_SENSOR) are gathered this long (s) and matched together: a few of
#: its 10 Hz cycles, short against the estimate's drift.
GATHER_S = 0.25
#: A box whose top may be under the sensor and that cuts this far (m) into a reading's arc was passed over by
#: the reading (:meth:`MapSurface.arc_distance`).
PASSED_OVER_M = 0.3
#: Scans from below or above the fix's altitude (climbing after the takeoff, coming down to land) are matched
#: against the map's boxes at their own altitude, to this step (m).
SURFACE_STEP_M = 1.0
#: A match needs this many readings on the map's faces.
MIN_INLIERS = 10
#: A direction is constrained by a scan when at least this many readings' faces face it (the eigenvalues of the
#: sum of their unit normals' outer products count readings).
MIN_DIRECTION_READINGS = 4.0
#: How far the scan's bearings may be turned by the heading estimate's error (rad, one standard deviation).
HEADING_SIGMA_RAD = math.radians(2.0)
#: Readings in one scan are not independent (the map's boxes are approximations, the sectors overlap the same
#: faces): a scan weighs as this many independent readings at most.
EFFECTIVE_READINGS = 5.0
#: ... and readings of sectors wider than ``NARROW_HALF_WIDTH_RAD`` gathered over a few cycles (ArduPilot's 45
#: degrees: each touches its faces at a point the fit must find along 24 m of arc) as one: measured along routes
#: through the bundled map with a 1.5 m drift, the stated bound held 88-97 % of the time at 5, 95-99.8 % at 1.
WIDE_EFFECTIVE_READINGS, NARROW_HALF_WIDTH_RAD = 1.0, math.radians(3.0)


class MapSurface:
    """The map's boxes that stand through the sensor's plane at ``altitude_m`` (bottom at or below it, top at
    most ``below_m`` under it: the vehicle flies that much low at times, and then reads them), for signed distances
    to their faces. A face that is not read costs nothing (only readings are matched to faces), but a reading of a
    box left out here could be taken for the nearest face that is in, so err on the side of keeping boxes.

    Parameters
    ----------
    obstacles : (N, 6) array
        The map's boxes: centre north, east, altitude (m), half sizes north, east, up (m).
    altitude_m : float
        The sensor's plane (m above the map's ground).
    below_m : float
        How far below the plane a box's top may be.
    above_m : float
        A box whose top is less than this far above the plane may be under the sensor (the vehicle flies that
        much high at times, and the sensor sits above the vehicle's reference point): it is *uncertain*, its faces
        count where a reading lands on them, never where a reading passes over it (:meth:`arc_distance`).
    bucket_m : float
        Side of the square buckets that index the boxes (m).
    """

    def __init__(self, obstacles: np.ndarray, altitude_m: float, *, below_m: float = 1.0, above_m: float = 1.0,
                 bucket_m: float = 16.0) -> None:
        obs = np.asarray(obstacles, float).reshape(-1, 6)
        self.altitude_m = float(altitude_m)
        keep = (obs[:, 2] + obs[:, 5] >= altitude_m - below_m) & (obs[:, 2] - obs[:, 5] <= altitude_m)
        self.centres = obs[keep, :2].copy()
        self.halves = obs[keep, 3:5].copy()
        self.certain = obs[keep, 2] + obs[keep, 5] >= altitude_m + above_m
        self.bucket_m = float(bucket_m)
        self._buckets: dict[tuple[int, int], list[int]] = {}
        lo = np.floor((self.centres - self.halves) / self.bucket_m).astype(int)
        hi = np.floor((self.centres + self.halves) / self.bucket_m).astype(int)
        for k, ((n0, e0), (n1, e1)) in enumerate(zip(lo, hi)):
            for i in range(n0, n1 + 1):
                for j in range(e0, e1 + 1):
                    self._buckets.setdefault((i, j), []).append(k)

    def __len__(self) -> int:
        return len(self.centres)

    def near(self, north_m: float, east_m: float, reach_m: float) -> np.ndarray:
        """Indices of the boxes that may lie within ``reach_m`` of the point (a superset: whole buckets)."""
        b = self.bucket_m
        i0, i1 = math.floor((north_m - reach_m) / b), math.floor((north_m + reach_m) / b)
        j0, j1 = math.floor((east_m - reach_m) / b), math.floor((east_m + reach_m) / b)
        found: set[int] = set()
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                found.update(self._buckets.get((i, j), ()))
        return np.fromiter(sorted(found), int, len(found))

    def signed_distance(self, points_ne: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m; negative inside a box) from each point (``(..., 2)`` map north, east m) to the
        nearest face of the boxes ``boxes`` (indices from :meth:`near`), and its gradient (``(..., 2)``, the unit
        direction away from that face). ``inf`` and a zero gradient where there are no boxes."""
        pts = np.asarray(points_ne, float)
        if len(boxes) == 0:
            return np.full(pts.shape[:-1], np.inf), np.zeros(pts.shape)
        rel = pts[..., None, :] - self.centres[boxes]  # (..., B, 2)
        q = np.abs(rel) - self.halves[boxes]
        outside = np.hypot(np.maximum(q[..., 0], 0.0), np.maximum(q[..., 1], 0.0))
        inside = np.minimum(np.maximum(q[..., 0], q[..., 1]), 0.0)
        sd = outside + inside  # (..., B)
        k = np.argmin(sd, axis=-1)[..., None]
        best = np.take_along_axis(sd, k, axis=-1)[..., 0]
        qk = np.take_along_axis(q, k[..., None], axis=-2)[..., 0, :]
        sign = np.sign(np.take_along_axis(rel, k[..., None], axis=-2)[..., 0, :])
        sign[sign == 0] = 1.0
        out = np.maximum(qk, 0.0)
        norm = np.hypot(out[..., 0], out[..., 1])
        grad = np.where(norm[..., None] > 1e-9, out / np.maximum(norm, 1e-9)[..., None], 0.0)
        along_north = qk[..., 0] >= qk[..., 1]
        inner = np.stack([along_north, ~along_north], axis=-1).astype(float)
        grad = np.where((norm > 1e-9)[..., None], grad, inner) * sign
        return best, grad

    def arc_distance(self, arcs_ne: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per reading, the least signed distance (m) along its arc (``(K, S, 2)``: S samples of each of K
        readings' arcs, map north and east m) to the faces of ``boxes``, its gradient (``(K, 2)``) and the sample
        it is at (``(K,)``). A box whose top may be under the sensor (not :attr:`certain`) that cuts into an arc
        by more than :data:`PASSED_OVER_M` was passed over by that reading, not missed by it: the reading is
        measured against the certain boxes alone. Without that, the walls read beyond a row of roofs 5 m high
        (the flight altitude; the sensor sits above it) were pulled towards the roofs, and a hovering vehicle's
        correction settled 0.4 m off with nothing wrong with its estimate (the bundled map's (97, -193))."""
        boxes = np.asarray(boxes, int)
        certain = self.certain[boxes]
        sd, grad = self.signed_distance(arcs_ne, boxes[certain])  # (K, S), (K, S, 2)
        if not certain.all():
            sd_u, grad_u = self.signed_distance(arcs_ne, boxes[~certain])
            landed_on = (sd_u.min(axis=1) >= -PASSED_OVER_M)[:, None] & (sd_u < sd)
            sd, grad = np.where(landed_on, sd_u, sd), np.where(landed_on[..., None], grad_u, grad)
        rows = np.arange(len(sd))
        k = np.argmin(sd, axis=1)
        return sd[rows, k], grad[rows, k], k


@dataclass(frozen=True)
class Match:
    """One scan's fit: ``offset_ne`` (m, map north and east) is where the scan fits the map's faces best relative
    to where it was placed, ``information`` (2x2, 1/m^2) how well each direction is constrained, ``inliers`` the
    readings on a face and ``rms_m`` their distance from it after the shift."""

    offset_ne: np.ndarray
    information: np.ndarray
    inliers: int
    rms_m: float


def _residuals(surface: MapSurface, boxes: np.ndarray, north_m: float, east_m: float, dist: np.ndarray,
               angles: np.ndarray, shift: np.ndarray, turn_rad: float):
    """Per reading, with the scan moved by ``shift`` and turned by ``turn_rad`` about the sensor: the least signed
    distance along its arc (0 when the arc touches a face and nothing in the sector is nearer, negative when a face
    cuts into it; :meth:`MapSurface.arc_distance`), that sample's gradient (``(K, 2)``) and the residual's rate of
    change with the turn (m/rad)."""
    a = angles + turn_rad
    pts = np.stack([north_m + shift[0] + dist[:, None] * np.cos(a), east_m + shift[1] + dist[:, None] * np.sin(a)],
                   axis=-1)  # north_m, east_m: scalars, or (K, 1) for readings taken at several places
    r, g, k = surface.arc_distance(pts, boxes)
    ak = a[np.arange(len(a)), k]
    turn = dist * (g[:, 1] * np.cos(ak) - g[:, 0] * np.sin(ak))
    return r, g, turn


def match_scan(surface: MapSurface, north_m: float | np.ndarray, east_m: float | np.ndarray, bearings_rad,
               half_width_rad: float, distances_m, max_range_m: float, *, start_ne=(0.0, 0.0), search_m: float = 0.0,
               inlier_m: float = 1.5, sigma_m: float = 0.4, turn_sigma_rad: float = HEADING_SIGMA_RAD,
               iterations: int = 8) -> Match | None:
    """Fit one scan taken at the map position ``(north_m, east_m)`` (or readings taken at several: arrays, one
    position per reading) to the map's faces.

    Each reading (a sector's nearest obstacle at ``distances_m``, in ``bearings_rad`` clockwise from north, half
    width ``half_width_rad``) says that the arc at that distance across the sector touches a face and that no face
    cuts into it (it would be nearer); sampled at its ends, centre and between, its residual is the least signed
    distance along it (a face seen at a grazing angle is nearest at an end of the arc, which is sampled). From
    ``start_ne`` (m) the shift is searched on a 0.5 m grid within ``search_m`` (the truncated cost, readings beyond
    ``inlier_m`` of every face counting as ``inlier_m``), then refined by Gauss-Newton with Huber weights
    (``sigma_m``), readings beyond ``inlier_m`` left out. The bearings carry the heading's error (a scan in the
    body frame turned by the estimated heading, or the autopilot's own rotation to north): the fit also turns the
    scan about the sensor (spread ``turn_sigma_rad`` round none), so that error does not pass for a shift, and the
    shift's information is what is left once the turn is unknown.

    Returns None when the sectors are too wide (:data:`MAX_HALF_WIDTH_RAD`), fewer than :data:`MIN_INLIERS`
    readings lie on a face, or those lie farther from them than ``sigma_m`` (root mean square): a poor fit.

    >>> boxes = np.array([[0.0, 20.0, 10.0, 50.0, 5.0, 10.0], [0.0, -20.0, 10.0, 50.0, 5.0, 10.0]])
    >>> surface = MapSurface(boxes, altitude_m=5.0)
    >>> b = np.radians(np.arange(0.0, 360.0, 5.0))
    >>> east = np.abs(np.sin(b[:, None] + np.radians([-2.5, 0.0, 2.5]))).max(axis=1)  # the sector's nearest point
    >>> d = np.where(east > 0.3, 15.0 / np.maximum(east, 0.3), np.inf)  # of walls 15 m east and west
    >>> m = match_scan(surface, 0.0, 1.0, b, math.radians(2.5), d, 30.0, search_m=2.0)  # placed 1 m east
    >>> round(float(m.offset_ne[1]), 1), bool(m.information[1, 1] > 100 * m.information[0, 0])
    (-1.0, True)
    """
    if half_width_rad > MAX_HALF_WIDTH_RAD:
        return None
    bearings = np.asarray(bearings_rad, float)
    dist = np.asarray(distances_m, float)
    ok = np.isfinite(dist) & (dist > 0.3) & (dist < 0.999 * max_range_m)
    if ok.sum() < MIN_INLIERS:
        return None
    d = dist[ok]
    places = np.broadcast_to(np.column_stack(np.broadcast_arrays(np.asarray(north_m, float),
                                                                 np.asarray(east_m, float))), (len(dist), 2))[ok]
    centre = places.mean(axis=0)
    spread = float(np.hypot(*(places - centre).T).max())
    north_m, east_m = (float(centre[0]), float(centre[1])) if spread == 0.0 else (places[:, :1], places[:, 1:])
    samples = max(5, 2 * math.ceil(half_width_rad / ARC_STEP_RAD) + 1)
    angles = bearings[ok][:, None] + np.linspace(-1.0, 1.0, samples) * half_width_rad  # (K, S)
    shift, turn = np.asarray(start_ne, float).copy(), 0.0
    boxes = surface.near(centre[0] + shift[0], centre[1] + shift[1], max_range_m + search_m + spread + 1.0)
    if len(boxes) == 0:
        return None
    if search_m > 0.25:
        steps = np.arange(-search_m, search_m + 1e-9, max(0.5, search_m / 5.0))
        grid = np.stack(np.meshgrid(steps, steps, indexing="ij"), axis=-1).reshape(-1, 2)
        grid = grid[np.hypot(grid[:, 0], grid[:, 1]) <= search_m + 1e-9]
        a = angles[:, ::2]  # the search reads each arc at its ends and centre only
        coarse = np.stack([north_m + shift[0] + d[:, None] * np.cos(a), east_m + shift[1] + d[:, None] * np.sin(a)],
                          axis=-1)
        arcs = coarse[None] + grid[:, None, None, :]  # (G, K, S, 2)
        sd = surface.arc_distance(arcs.reshape(-1, *arcs.shape[2:]), boxes)[0].reshape(len(grid), -1)
        shift = shift + grid[int(np.argmin(np.minimum(np.square(sd), inlier_m ** 2).sum(axis=1)))]
    prior = np.diag([0.0, 0.0, 1.0 / max(turn_sigma_rad, 1e-6) ** 2])
    for _ in range(iterations):
        r, g, jt = _residuals(surface, boxes, north_m, east_m, d, angles, shift, turn)
        inl = np.abs(r) <= inlier_m
        if inl.sum() < MIN_INLIERS:
            return None
        w = np.where(inl, np.minimum(1.0, sigma_m / np.maximum(np.abs(r), 1e-9)), 0.0)
        jac = np.column_stack([g, jt])
        h = (jac * w[:, None]).T @ jac
        h += prior * sigma_m ** 2 + np.diag([1e-6 + 1e-3 * np.trace(h[:2, :2])] * 2 + [0.0])
        step = -np.linalg.solve(h, (jac * w[:, None]).T @ r + prior[:, 2] * sigma_m ** 2 * turn)
        shift, turn = shift + step[:2], turn + float(step[2])
        if float(np.hypot(*step[:2])) < 0.01 and abs(float(step[2])) < 1e-4:
            break
    r, g, jt = _residuals(surface, boxes, north_m, east_m, d, angles, shift, turn)
    inl = np.abs(r) <= inlier_m
    rms = float(np.sqrt(np.mean(np.square(r[inl])))) if inl.any() else math.inf
    if inl.sum() < MIN_INLIERS or rms > sigma_m:  # too few readings on the faces, or a poor fit of them
        return None
    gi = g[inl]
    # Only directions that several readings constrain carry information: in a weak one (one face end in view)
    # the shift is where the search started, and fusing that as a measurement would only confirm the start.
    counts, axes = np.linalg.eigh(gi.T @ gi)
    kept = axes[:, counts >= MIN_DIRECTION_READINGS]
    if kept.shape[1] == 0:
        return None
    jac = np.column_stack([gi, jt[inl]])
    effective = EFFECTIVE_READINGS if half_width_rad <= NARROW_HALF_WIDTH_RAD else WIDE_EFFECTIVE_READINGS
    full = jac.T @ jac / sigma_m ** 2 * min(1.0, effective / len(gi)) + prior
    shift_info = full[:2, :2] - np.outer(full[:2, 2], full[2, :2]) / full[2, 2]  # the turn left unknown
    information = kept @ (kept.T @ shift_info @ kept) @ kept.T
    return Match(shift, information, int(inl.sum()), rms)


class DriftEstimate:
    """The correction to the position estimate over time (map north, east m): a Kalman filter whose state, like
    the estimate's error, is a first-order Gauss-Markov process (spread ``sigma_m`` from the stated accuracy,
    time constant ``correlation_s``) observed by :class:`Match` es.

    A match that disagrees beyond the chi-square gate (``gate``, 2 degrees of freedom) is set aside; after
    ``reset_after`` in a row (the estimate jumped: a GPS glitch, a reset) the filter starts again from the prior."""

    def __init__(self, *, correlation_s: float = 20.0, gate: float = 13.8, reset_after: int = 10) -> None:
        self.correlation_s, self.gate, self.reset_after = float(correlation_s), float(gate), int(reset_after)
        self.correction = np.zeros(2)
        self.covariance: np.ndarray | None = None
        self.time_s = math.nan
        self.accepted = self.rejected = self.resets = 0
        self._in_a_row = 0

    def predict(self, time_s: float, sigma_m: float) -> None:
        """Carry the estimate to ``time_s`` (s); ``sigma_m`` the stated accuracy now (one standard deviation)."""
        prior = sigma_m ** 2 * np.eye(2)
        if self.covariance is None:
            self.covariance, self.time_s = prior, time_s
            return
        dt = time_s - self.time_s if math.isfinite(self.time_s) and math.isfinite(time_s) else 0.0
        a = math.exp(-max(dt, 0.0) / self.correlation_s)
        self.correction = a * self.correction
        self.covariance = a * a * self.covariance + (1.0 - a * a) * prior
        if math.isfinite(time_s):
            self.time_s = time_s

    def update(self, match: Match, sigma_m: float) -> bool:
        """Fuse ``match`` (its offset is the correction it measures); False when it was set aside."""
        assert self.covariance is not None, "predict first"
        h = match.information
        innovation = match.offset_ne - self.correction
        # The innovation's covariance: the filter's plus the match's, only in the directions it constrains.
        s = self.covariance + np.linalg.pinv(h + 1e-9 * np.eye(2), rcond=1e-6)
        if float(innovation @ np.linalg.solve(s, innovation)) > self.gate:
            self.rejected += 1
            self._in_a_row += 1
            if self._in_a_row >= self.reset_after:
                self.correction, self.covariance = np.zeros(2), sigma_m ** 2 * np.eye(2)
                self.resets += 1
                self._in_a_row = 0
            return False
        self._in_a_row = 0
        info = np.linalg.inv(self.covariance)
        self.covariance = np.linalg.inv(info + h)
        self.correction = self.covariance @ (info @ self.correction + h @ match.offset_ne)
        self.accepted += 1
        return True

    @property
    def sigma_m(self) -> float:
        """The spread of the correction in its worst direction (m), NaN before the first prediction."""
        if self.covariance is None:
            return math.nan
        return math.sqrt(max(float(np.linalg.eigvalsh(self.covariance)[-1]), 0.0))


class _Reading(NamedTuple):
    """One message's readings, as :meth:`PositionFix.observe` got them."""

    time_s: float
    north_m: float
    east_m: float
    bearings_rad: np.ndarray
    half_width_rad: float
    distances_m: np.ndarray
    max_range_m: float
    position_error_m: float
    bearing_error_rad: float
    surface: MapSurface | None = None


class PositionFix:
    """Scan matching against ``surface`` and the drift estimate, fed one scan at a time (:meth:`observe`).

    ``correction_ne`` (m, map north and east) is what to add to the position estimate; it never exceeds the
    scan's own bound (``position_error_m``: :data:`SIGMAS` times the stated accuracy), and it is zero while no
    scan states an accuracy (nothing says the estimate may be off)."""

    def __init__(self, surface: MapSurface, *, obstacles: np.ndarray | None = None, correlation_s: float = 20.0,
                 search_every_s: float = 1.0) -> None:
        self.surface = surface
        self._obstacles = None if obstacles is None else np.asarray(obstacles, float).reshape(-1, 6)
        self._surfaces: dict[int, MapSurface] = {}
        self.estimate = DriftEstimate(correlation_s=correlation_s)
        self.search_every_s = float(search_every_s)
        self._limit_m = 0.0
        self._searched_s = -math.inf
        self._gathered: list[_Reading] = []  # single-sector readings waiting to be matched together

    @property
    def active(self) -> bool:
        return self.estimate.covariance is not None

    @property
    def correction_ne(self) -> tuple[float, float]:
        """What to add to the position estimate (m, map north and east), capped at the latest scan's bound."""
        c = self.estimate.correction
        norm = float(np.hypot(*c))
        k = 1.0 if norm <= self._limit_m or norm == 0.0 else self._limit_m / norm
        return float(c[0] * k), float(c[1] * k)

    @property
    def bound_m(self) -> float:
        """How far off the corrected position may be (m): :data:`SIGMAS` spreads; NaN before any scan."""
        return SIGMAS * self.estimate.sigma_m if self.active else math.nan

    def describe(self) -> str:
        """One line: the correction, its bound, and what the matches did."""
        cn, ce = self.correction_ne
        e = self.estimate
        return (f"correction ({cn:+.2f} N, {ce:+.2f} E) m, bound {self.bound_m:.2f} m; {e.accepted} scans matched, "
                f"{e.rejected} set aside, {e.resets} restarts")

    def surface_at(self, altitude_m: float | None) -> MapSurface:
        """The map's boxes at ``altitude_m`` (m above the map's ground, to :data:`SURFACE_STEP_M`): the surface
        the fix was made with when None, within half a step of its altitude, or without the map's boxes."""
        if altitude_m is None or self._obstacles is None \
                or abs(altitude_m - self.surface.altitude_m) < 0.5 * SURFACE_STEP_M:
            return self.surface
        key = max(round(altitude_m / SURFACE_STEP_M), 0)
        if key not in self._surfaces:
            self._surfaces[key] = MapSurface(self._obstacles, key * SURFACE_STEP_M)
        return self._surfaces[key]

    def observe(self, time_s: float, north_m: float, east_m: float, bearings_rad, half_width_rad: float,
                distances_m, max_range_m: float, position_error_m: float, *,
                bearing_error_rad: float = 0.0, altitude_m: float | None = None) -> Match | None:
        """One scan placed at the uncorrected map position ``(north_m, east_m)`` at ``time_s`` (s, any clock that
        runs with the vehicle's), whose placement may be off by ``position_error_m`` (0: unknown, nothing done) and
        whose bearings by ``bearing_error_rad`` beyond the heading estimate's own error, taken at ``altitude_m``
        (m above the map's ground; None: the fix's own, :meth:`surface_at`). A scan of fewer readings than a match
        needs (ArduPilot's one sector per message) is gathered with those that follow it for :data:`GATHER_S`,
        each at its own position, and matched with them: the match is returned then."""
        surface = self.surface_at(altitude_m)
        if not position_error_m > 0 or half_width_rad > MAX_HALF_WIDTH_RAD or len(surface) == 0:
            return None
        bearings = np.atleast_1d(np.asarray(bearings_rad, float))
        if len(bearings) >= MIN_INLIERS:
            return self._match(surface, time_s, north_m, east_m, bearings, half_width_rad, distances_m, max_range_m,
                               position_error_m, bearing_error_rad)
        g = self._gathered
        if g and (g[0].half_width_rad != half_width_rad or g[0].max_range_m != max_range_m
                  or not 0.0 <= time_s - g[0].time_s < 2 * GATHER_S or g[0].surface is not surface):
            g.clear()  # another sensor, a gap in the stream, another altitude: start again
        g.append(_Reading(time_s, north_m, east_m, bearings, half_width_rad,
                          np.atleast_1d(np.asarray(distances_m, float)), max_range_m, position_error_m,
                          bearing_error_rad, surface))
        if time_s - g[0].time_s < GATHER_S:
            return None
        self._gathered = []
        counts = [len(r.bearings_rad) for r in g]
        return self._match(surface, time_s, np.repeat([r.north_m for r in g], counts),
                           np.repeat([r.east_m for r in g], counts),
                           np.concatenate([r.bearings_rad for r in g]), half_width_rad,
                           np.concatenate([r.distances_m for r in g]), max_range_m,
                           max(r.position_error_m for r in g), max(r.bearing_error_rad for r in g))

    def _match(self, surface: MapSurface, time_s: float, north_m, east_m, bearings: np.ndarray,
               half_width_rad: float, distances_m, max_range_m: float, position_error_m: float,
               bearing_error_rad: float) -> Match | None:
        sigma = position_error_m / SIGMAS
        self._limit_m = position_error_m
        self.estimate.predict(time_s, sigma)
        # While the correction is loose (at first, or along a street that leaves it free), search round it at most
        # once every search_every_s (a few ms); between searches Gauss-Newton tracks it from where it is.
        search = min(SIGMAS * self.estimate.sigma_m, position_error_m, 4.0)
        if search <= 1.0 or not time_s - self._searched_s >= self.search_every_s:
            search = 0.0
        else:
            self._searched_s = time_s
        match = match_scan(surface, north_m, east_m, bearings, half_width_rad, distances_m, max_range_m,
                           start_ne=self.estimate.correction, search_m=search,
                           turn_sigma_rad=math.hypot(HEADING_SIGMA_RAD, bearing_error_rad))
        if match is not None:
            self.estimate.update(match, sigma)
        return match
