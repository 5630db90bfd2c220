"""The live occupancy layer: what the obstacle sensor sees, over the planning grid of one altitude and margin.

Arrays in, arrays out (planning never imports the vehicle): a scan is the sensor's position (map north, east m),
its sectors' centre bearings (rad clockwise from north), their half width and the distance to the nearest
obstacle in each (``inf`` nothing within range, ``NaN`` unknown). Grids are indexed ``[north_idx, east_idx]`` like
every planning grid (:mod:`.cspace`).

What a sector reading means, and what :meth:`LiveMap.add_scan` does with it
-----------------------------------------------------------------------------
A reading ``d`` in a wedge says: nothing in the wedge is closer than ``d`` (those cells are *seen free*), and some
obstacle point lies on the arc at ``d``. PX4's 5 degree sectors make that arc short (2.6 m at 30 m); ArduPilot's
45 degree ones make it long (24 m at 30 m), so the arc alone would smear street walls into the street. The map
explains most readings: the layer keeps the map's footprint grid (the obstacles at this altitude without margin)
and computes, per sector, the distance the map predicts; a reading within ``explain_tolerance_m`` of that (or
farther) is the map's own building and adds nothing. Only a reading clearly *shorter* than the map predicts is a
new obstacle: its arc's cells get a hit, except cells within ``explain_tolerance_m`` of the map's footprint (centre
to centre). That second test is what survives an error in the vehicle's position estimate: looking along a street
at a grazing angle, half a metre of sideways error moves the predicted range by metres, but the reading's point
still lies on the building's face, displaced by the error. A scan placed at a position that may be off by more
(``position_error_m``: three times the GPS receiver's reported accuracy) uses that as its tolerance in both tests,
up to 70 % of the safety margin: with 1.5 m of GPS noise, the map's own buildings were read as new ones along
every street and closed them. A new obstacle closer than the tolerance to a map building keeps at least the rest of
the margin (the tolerance is taken off it). A cell is an observed obstacle while it has been hit in ``confirm_hits``
scans or more and not seen free ``free_to_clear`` times more often than hit, counted over the whole flight: a cell
dropped as noise comes back only when the hits catch up, not two scans later (reset at each drop, a cell beside a
wall's end flickered in and out at the sensor rate and its margin closed and opened a corridor the truth leaves
open). A cell once dropped also takes an arc's hit only when no other cell of that arc can (``once_dropped``): an arc
across a wall's end would otherwise mark the free cell beside it again each time the vehicle came back.

Observed obstacle cells are inflated by the safety margin with the map's own Euclidean rule
(:func:`.kernels.rasterise`, each hit cell a 1 m box: a cell is blocked when its square comes closer than the
margin to the hit cell's square), and the planning grid is the map's C-space OR that layer. Map buildings are
never removed, however often their cells are seen free (counted in ``map_cells_seen_free``): a building missing
from the truth only costs a detour, and removing one on a few noisy readings could cost a collision.

The layer also keeps what exploration needs (issue 12): ``known`` (cells seen free or hit) and the counts.

>>> base = np.zeros((40, 40), bool); footprint = np.zeros_like(base)
>>> live = LiveMap(base, footprint, 0, 0, safety_m=2.0, confirm_hits=1)
>>> update = live.add_scan(5.5, 20.5, np.radians(np.arange(0, 360, 5.0)), np.radians(2.5),
...                        np.where(np.arange(72) == 0, 10.0, np.inf), 30.0)
>>> update.new_hits > 0, bool(live.hits[15, 20]), bool(live.grid[13, 20]), bool(live.grid[12, 20])
(True, True, True, False)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyroute.planning import kernels
from skyroute.planning.cspace import nearest_free_cell, snap_start_cell

_TWO_PI = 2.0 * math.pi
#: Sectors this narrow (half width, rad) or narrower place an oblique reading's hit at the edge towards the
#: nearer neighbour (:meth:`LiveMap._hit_spans`); a neighbour is nearer when it reads this much (m) shorter.
FINE_HALF_RAD, NEIGHBOUR_MARGIN_M = math.radians(2.6), 0.5
#: Arc (m) marked at the shared edge when the face is seen to cross it (a run of three readings, each shorter
#: towards the same side): the edge point itself, give or take the range's centimetre.
EDGE_POINT_ARC_M = 0.05
#: A scan's position error widens the explaining tolerance up to this share of the safety margin: a new obstacle
#: taken for the map building it stands beside keeps the rest of the margin (3.5 m of 5 m, issue 11's clearance).
MAX_TOLERANCE_PER_MARGIN = 0.7
#: Offsets of the five points of a cell sampled for the map's predicted range: centre and corners.
_SAMPLES = np.array([[0.5, 0.5], [0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]])


@dataclass(frozen=True)
class ScanUpdate:
    """What one scan changed: ``new_hits`` cells newly confirmed as obstacles, ``cleared`` hits dropped,
    ``explained`` sectors the map accounts for, ``unexplained`` sectors that showed a new obstacle, ``changed``
    whether the planning grid changed."""

    new_hits: int
    cleared: int
    explained: int
    unexplained: int
    changed: bool


def _wrap(angle):
    """Angles (rad, a float or an array) into [-pi, pi)."""
    return (angle + math.pi) % _TWO_PI - math.pi


def _along_face(edge_rad: np.ndarray, far_edge_rad: np.ndarray, range_m: np.ndarray, far_range_m: np.ndarray,
                dist_m: np.ndarray, centre_rad: np.ndarray, half: float) -> np.ndarray:
    """Bearing (rad) at which the line through the points at ``(edge_rad, range_m)`` and ``(far_edge_rad,
    far_range_m)``, carried on past the first towards the wedge ``centre_rad +- half``, comes to ``dist_m`` from the
    sensor; NaN unless those readings recede from the wedge (each at least a neighbour margin farther) and that
    bearing lies in the wedge."""
    with np.errstate(invalid="ignore"):
        receding = (np.isfinite(range_m) & np.isfinite(far_range_m) & (range_m >= dist_m)
                    & (far_range_m > range_m + NEIGHBOUR_MARGIN_M))
    r1 = np.where(receding, range_m, 1.0)
    r2 = np.where(receding, far_range_m, 2.0)
    p1 = r1[:, None] * np.column_stack([np.cos(edge_rad), np.sin(edge_rad)])
    p2 = r2[:, None] * np.column_stack([np.cos(far_edge_rad), np.sin(far_edge_rad)])
    v = p1 - p2
    length = np.hypot(v[:, 0], v[:, 1])
    v = v / np.maximum(length, 1e-9)[:, None]
    b = (p1 * v).sum(axis=1)
    disc = b * b - (r1 * r1 - dist_m * dist_m)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    x = p1 + t[:, None] * v
    bearing = np.arctan2(x[:, 1], x[:, 0])
    inside = np.abs(_wrap(bearing - centre_rad)) <= half
    return np.where(receding & (length > 1e-6) & (disc >= 0.0) & (t >= 0.0) & inside, bearing, np.nan)


def _face_edge(reading: dict, centre_of: dict, k: int, side: int, half: float, count: int,
               d: float) -> float | None:
    """The bearing (rad) of wedge ``k``'s edge on ``side`` (-1 towards lower indices) when wedge ``k``'s reading
    ``d`` is one straight face's point there (see :meth:`LiveMap._face_spans`); else None."""
    def r(j: int) -> float:
        return reading.get(j % count, math.nan)

    if not r(k + side) < d - NEIGHBOUR_MARGIN_M:  # the neighbour clearly nearer, then falling to the least
        return None
    run = [k, k + side]
    while len(run) <= count // 2 and r(run[-1] + side) <= r(run[-1]):  # equal: the foot at their shared edge
        run.append(run[-1] + side)
    if len(run) < 3:  # the foot's wedge and one between at least
        return None
    foot, p = run[-1], r(run[-1])
    if not (math.isfinite(p) and p > 0) or (run[-1] % count) not in centre_of or (k % count) not in centre_of:
        return None

    def edge_towards_foot(j: int) -> float:
        return centre_of[k % count] + (j - k) * 2.0 * half + side * half

    nearest = run[-2]  # the foot's bearing from the wedge next to it: its reading is the face at its edge
    if r(nearest) < p:
        return None
    foot_bearing = edge_towards_foot(nearest) + side * math.acos(min(p / r(nearest), 1.0))
    if abs(_wrap(foot_bearing - centre_of[k % count] - (foot - k) * 2.0 * half)) > half + 1e-9:
        return None  # the foot is not in the least wedge: not one face
    for j in run[:-1]:
        angle = abs(_wrap(edge_towards_foot(j) - foot_bearing))
        if angle >= 0.5 * math.pi - 1e-6 or abs(p / math.cos(angle) - r(j)) > NEIGHBOUR_MARGIN_M:
            return None
    return float(edge_towards_foot(k))


def _distance_to(cells: np.ndarray) -> np.ndarray:
    """Distance (m, float32) from each 1 m cell's centre to the nearest True cell's centre (0 on them; inf when
    there is none).

    >>> _distance_to(np.array([[False, False, False, True]])).tolist()
    [[3.0, 2.0, 1.0, 0.0]]
    """
    from scipy import ndimage

    if not cells.any():
        return np.full(cells.shape, np.inf, np.float32)
    return ndimage.distance_transform_edt(~cells).astype(np.float32)


class LiveMap:
    """Observed obstacles and free space over one planning grid (see the module notes).

    Parameters
    ----------
    base_grid : (n, m) bool array
        The map's configuration space at this altitude and margin (True = blocked); never changed.
    footprint : (n, m) bool array or None
        The map's obstacles at this altitude without margin (``create_grid(data, altitude, 0)``), for the
        predicted ranges; None: no prediction, every finite reading is a hit.
    north_offset, east_offset : int
        Map metres of cell ``(0, 0)``'s south-west corner.
    safety_m : float
        Margin round observed obstacles (m), as the map's.
    confirm_hits, free_to_clear : int
        Scans that must hit a cell before it counts; how many more times a cell must be seen free than hit (over
        the whole flight) before it no longer counts.
    explain_tolerance_m : float
        A reading no shorter than the map's prediction minus this is the map's building.
    """

    def __init__(self, base_grid: np.ndarray, footprint: np.ndarray | None, north_offset: int, east_offset: int,
                 safety_m: float, *, confirm_hits: int = 2, free_to_clear: int = 3,
                 explain_tolerance_m: float = 1.5, arc_step_m: float = 0.5) -> None:
        self.base = np.asarray(base_grid, dtype=bool)
        self.footprint = None if footprint is None else np.asarray(footprint, dtype=bool)
        if self.footprint is not None and self.footprint.shape != self.base.shape:
            raise ValueError(f"footprint {self.footprint.shape} and base grid {self.base.shape} differ in shape")
        self.north_offset, self.east_offset = int(north_offset), int(east_offset)
        self.safety_m = float(safety_m)
        self.margin_m = self.safety_m  # round observed obstacles: the safety margin unless narrowed (set_margin)
        self.confirm_hits, self.free_to_clear = int(confirm_hits), int(free_to_clear)
        self.explain_tolerance_m, self.arc_step_m = float(explain_tolerance_m), float(arc_step_m)
        self._map_distance = None if self.footprint is None else _distance_to(self.footprint)
        shape = self.base.shape
        self.hit_count = np.zeros(shape, np.uint16)
        self.free_count = np.zeros(shape, np.uint16)
        self.hits = np.zeros(shape, bool)
        self.inflated = np.zeros(shape, bool)
        self.known = np.zeros(shape, bool)
        self.once_dropped = np.zeros(shape, bool)  # hit cells once dropped as noise (seen free more often than hit)
        self._grid = self.base.copy()
        self.version = 0
        self.scans = 0
        self.map_cells_seen_free = 0
        self.wide_sectors = False  # a scan's sectors were wider than FINE_HALF_RAD (their whole arcs are marked)
        self._layout: tuple[tuple[bytes, float], bool] | None = None  # the last scan's sector layout, side by side?

    @classmethod
    def for_grid_map(cls, grid_map, footprint: np.ndarray | None, **kwargs) -> LiveMap:
        """The layer over a :class:`~.grid.GridMap`'s grid (``footprint``: its obstacles without margin)."""
        return cls(grid_map.grid, footprint, grid_map.north_offset, grid_map.east_offset, grid_map.safety_m,
                   **kwargs)

    @property
    def grid(self) -> np.ndarray:
        """The planning grid: the map's C-space or the inflated observed obstacles (do not modify)."""
        return self._grid

    @property
    def shape(self) -> tuple[int, int]:
        return self.base.shape

    def cell_of(self, north_m: float, east_m: float) -> tuple[int, int]:
        return int(math.floor(north_m - self.north_offset)), int(math.floor(east_m - self.east_offset))

    def way_out(self, cell: tuple[int, int]) -> tuple[int, int] | None:
        """Where a vehicle in ``cell`` (inside a margin on :attr:`grid`) joins the free space: the nearest free cell
        whose straight leg crosses no observed obstacle or map building (the nearest free cell when none such);
        None when no cell is free."""
        solid = self.hits if self.footprint is None else self.hits | self.footprint
        return snap_start_cell(self.grid, solid, cell) or nearest_free_cell(self.grid, cell)

    def hit_cells_ne(self) -> np.ndarray:
        """Map ``(north_m, east_m)`` of every observed obstacle cell's centre, ``(K, 2)``."""
        cells = np.argwhere(self.hits)
        return cells + (self.north_offset + 0.5, self.east_offset + 0.5)

    def hit_boxes(self, altitude_m: float, height_m: float | None = None) -> np.ndarray:
        """Observed obstacle cells as ``colliders.csv`` boxes ``(K, 6)``, 1 m square, standing on the ground up to
        ``height_m`` (default: twice the altitude: the sensor saw them at the altitude, not their tops)."""
        top = 2.0 * altitude_m if height_m is None else height_m
        centres = self.hit_cells_ne()
        out = np.empty((len(centres), 6))
        out[:, :2] = centres
        out[:, 2] = out[:, 5] = top / 2.0
        out[:, 3] = out[:, 4] = 0.5
        return out

    def _ray(self, north_m: float, east_m: float, direction_north: float, direction_east: float, max_m: float,
             step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Samples every ``step_m`` along a ray, up to ``max_m``: ``(steps, on, i, j)``, the distances, whether each
        sample is on the grid, and its cell (``(0, 0)`` where off the grid)."""
        steps = np.arange(0.0, float(max_m) + 1e-9, step_m)
        i = np.floor(north_m + direction_north * steps - self.north_offset).astype(np.int64)
        j = np.floor(east_m + direction_east * steps - self.east_offset).astype(np.int64)
        n, m = self.shape
        on = (i >= 0) & (i < n) & (j >= 0) & (j < m)
        return steps, on, np.where(on, i, 0), np.where(on, j, 0)

    def clearance_m(self, north_m: float, east_m: float, direction_north: float, direction_east: float,
                    max_m: float, step_m: float = 0.25) -> float:
        """How far (m, up to ``max_m``) the ray from the map point along the unit direction stays out of the
        observed obstacles' margin (the inflated layer; the map's own buildings are not looked at). From a point
        within a margin, the ray may leave it: then it is stopped by an obstacle cell, or by a margin it enters
        again.

        >>> live = LiveMap(np.zeros((20, 20), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
        >>> _ = live.add_scan(2.5, 10.5, np.radians([0.0]), np.radians(1.0), np.array([10.0]), 30.0)
        >>> live.clearance_m(2.5, 10.5, 1.0, 0.0, 30.0), live.clearance_m(2.5, 10.5, 0.0, 1.0, 5.0)
        (7.5, 5.0)
        >>> live.clearance_m(11.5, 10.5, -1.0, 0.0, 30.0), live.clearance_m(11.5, 10.5, 1.0, 0.0, 30.0)  # in the margin
        (30.0, 0.5)
        """
        steps, on, ii, jj = self._ray(north_m, east_m, direction_north, direction_east, max_m, step_m)
        near = on & self.inflated[ii, jj]
        # A ray from within a margin (a vehicle that braked there) may fly out of it: the margin counts again once
        # left, the obstacle itself at once (given no way out, a vehicle that stopped there could never move again)
        outside = np.flatnonzero(~near)
        near[: outside[0] if len(outside) else len(near)] = False
        blocked = near | (on & self.hits[ii, jj])
        return float(steps[int(np.argmax(blocked))]) if blocked.any() else float(max_m)

    def seen_free_m(self, north_m: float, east_m: float, direction_north: float, direction_east: float,
                    max_m: float, step_m: float = 0.5) -> float:
        """How far (m, up to ``max_m``) the ray from the map point along the unit direction runs through cells the
        sensor has seen free: up to the first sample in a cell never seen (or off the grid, or a hit). What lies
        beyond is unknown, a new obstacle could stand there (the map's own buildings are never seen free).

        >>> live = LiveMap(np.zeros((40, 40), bool), None, 0, 0, safety_m=2.0, confirm_hits=1)
        >>> live.seen_free_m(5.5, 20.5, 1.0, 0.0, 30.0)
        0.0
        >>> _ = live.add_scan(5.5, 20.5, np.radians(np.arange(0, 360, 5.0)), np.radians(2.5), np.full(72, 20.0), 20.0)
        >>> live.seen_free_m(5.5, 20.5, 1.0, 0.0, 30.0)  # free to 20 m less a cell's diagonal and half a metre
        18.5
        """
        steps, on, ii, jj = self._ray(north_m, east_m, direction_north, direction_east, max_m, step_m)
        clear = on & self.known[ii, jj] & ~self.hits[ii, jj]
        if clear.all():
            return float(max_m)
        return float(steps[int(np.argmin(clear))])

    # ------------------------------------------------------------------------------------------ scans
    def _window(self, north_m: float, east_m: float, reach_m: float) -> tuple[int, int, int, int]:
        n, m = self.shape
        i, j = self.cell_of(north_m, east_m)
        r = int(math.ceil(reach_m)) + 1
        return max(i - r, 0), min(i + r + 1, n), max(j - r, 0), min(j + r + 1, m)

    def _wedge_window(self, p: np.ndarray, centres: np.ndarray, half_width: float,
                      reach_m: float) -> tuple[int, int, int, int]:
        """The window round the wedges ``centres +- half_width`` (rad) out to ``reach_m`` from ``p``: all round
        when they cover the circle, else their bounding box (a cell to spare). ArduPilot sends one 45 degree
        sector per message: its wedge's box is about a fifth of the square round the sensor, and a scan's cost
        goes with the cells it looks at."""
        full = self._window(float(p[0]), float(p[1]), reach_m)
        if len(centres) == 0 or len(centres) * 2.0 * half_width >= _TWO_PI - 1e-6:
            return full
        steps = max(2, int(math.ceil(2.0 * half_width / math.radians(2.0))) + 1)
        angles = (centres[:, None] + np.linspace(-half_width, half_width, steps)[None, :]).ravel()
        north = np.concatenate([[p[0]], p[0] + reach_m * np.cos(angles)])
        east = np.concatenate([[p[1]], p[1] + reach_m * np.sin(angles)])
        i0 = int(math.floor(north.min() - self.north_offset)) - 1
        i1 = int(math.floor(north.max() - self.north_offset)) + 2
        j0 = int(math.floor(east.min() - self.east_offset)) - 1
        j1 = int(math.floor(east.max() - self.east_offset)) + 2
        return max(i0, full[0]), min(i1, full[1]), max(j0, full[2]), min(j1, full[3])

    def _sector_of(self, bearings: np.ndarray, centres: np.ndarray, half_width: float) -> np.ndarray:
        """Sector index of each bearing (-1 when in none)."""
        k = len(centres)
        if k * 2.0 * half_width >= _TWO_PI - 1e-6 and k > 1:  # contiguous, equal sectors from centres[0]
            index = np.floor(((bearings - centres[0] + half_width) % _TWO_PI) / (2.0 * half_width)).astype(np.int64)
            return np.minimum(index, k - 1)
        diff = np.abs(_wrap(bearings[:, None] - centres[None, :]))
        inside = diff <= half_width + 1e-12
        return np.where(inside.any(axis=1), inside.argmax(axis=1), -1)

    def _predicted(self, p: np.ndarray, window, centres: np.ndarray, half_width: float,
                   range_m: float, bearing_error: float = 0.0) -> np.ndarray:
        """The map's predicted range in each sector (inf where its footprint has nothing within ``range_m``): the
        nearest footprint point in the sector widened by ``bearing_error`` on each side (rad: how far the sector
        itself may be turned, e.g. a heading-relative sensor's heading lag)."""
        out = np.full(len(centres), np.inf)
        if self.footprint is None:
            return out
        i0, i1, j0, j1 = window
        cells = np.argwhere(self.footprint[i0:i1, j0:j1]) + (i0, j0)
        if len(cells) == 0:
            return out
        half_width = half_width + bearing_error
        corner = cells + (self.north_offset, self.east_offset)
        near = np.clip(p, corner, corner + 1.0)
        dist = np.hypot(*(near - p).T)
        pts = corner[:, None, :] + _SAMPLES[None, :, :]  # (C, 5, 2)
        rel = pts - p
        bearing = np.arctan2(rel[..., 1], rel[..., 0]).ravel()
        d = np.repeat(dist, len(_SAMPLES))
        within = d <= range_m
        bearing, d = bearing[within], d[within]
        if bearing_error > 0:  # widened sectors overlap: a point counts in every sector it is in
            inside = np.abs(_wrap(bearing[:, None] - centres[None, :])) <= half_width + 1e-12
            if len(d):
                out = np.where(inside, d[:, None], np.inf).min(axis=0)
        else:
            sector = self._sector_of(bearing, centres, half_width)
            ok = sector >= 0
            np.minimum.at(out, sector[ok], d[ok])
        # A building that only grazes a sector (its corner inside the wedge, no sample point of it there) meets
        # one of the sector's edges: the range along both edge rays bounds the sector's minimum from above.
        k = len(centres)
        if self._side_by_side(centres, half_width):
            # Sectors side by side round the circle share their edges: each ray is marched once.
            lower = self._ray_ranges(p, window, centres - half_width, range_m)
            return np.minimum(out, np.minimum(lower, np.roll(lower, -1)))
        edges = self._ray_ranges(p, window, np.concatenate([centres - half_width, centres + half_width]), range_m)
        return np.minimum(out, np.minimum(edges[:k], edges[k:]))

    def _side_by_side(self, centres: np.ndarray, half_width: float) -> bool:
        """Whether the sectors ``centres +- half_width`` (rad) lie side by side round the whole circle, each one's
        upper edge the next one's lower edge (a sensor's fixed layout: the last answer is kept)."""
        key = (centres.tobytes(), half_width)
        if self._layout is None or self._layout[0] != key:
            k = len(centres)
            gaps = _wrap(np.roll(centres, -1) - centres)
            self._layout = (key, k > 1 and float(np.abs(gaps - 2.0 * half_width).max()) <= 1e-9)
        return self._layout[1]

    def _ray_ranges(self, p: np.ndarray, window, bearings: np.ndarray, range_m: float) -> np.ndarray:
        """Distance along each bearing from ``p`` to the first footprint cell inside ``window`` (marched at a
        quarter metre; inf when none within ``range_m``)."""
        i0, i1, j0, j1 = window
        steps = np.arange(0.0, range_m + 1e-9, 0.25)
        pts_n = p[0] + np.cos(bearings)[:, None] * steps[None, :]
        pts_e = p[1] + np.sin(bearings)[:, None] * steps[None, :]
        ci = np.floor(pts_n - self.north_offset).astype(np.int64)
        cj = np.floor(pts_e - self.east_offset).astype(np.int64)
        on = (ci >= i0) & (ci < i1) & (cj >= j0) & (cj < j1)
        hit = on & self.footprint[np.where(on, ci, i0), np.where(on, cj, j0)]
        first = hit.argmax(axis=1)
        return np.where(hit.any(axis=1), steps[first], np.inf)

    def add_scan(self, north_m: float, east_m: float, bearings_rad, half_width_rad: float, distances_m,
                 max_range_m: float, bearing_error_rad: float = 0.0, position_error_m: float = 0.0) -> ScanUpdate:
        """Take one scan from the sensor at map ``(north_m, east_m)`` (see the module notes); ``bearing_error_rad``:
        how far off the sectors' bearings may be (a reading the map explains within that turn is the map's);
        ``position_error_m``: how far off the position may be (the explaining tolerance, if larger)."""
        tolerance = self.explain_tolerance_m
        if position_error_m > 0:  # never so far that an obstacle beside a building keeps less than 70 % of the margin
            tolerance = max(tolerance, min(float(position_error_m), MAX_TOLERANCE_PER_MARGIN * self.safety_m))
        centres = np.asarray(bearings_rad, dtype=float) % _TWO_PI
        dist = np.asarray(distances_m, dtype=float)
        half = float(half_width_rad)
        self.wide_sectors |= half > FINE_HALF_RAD
        p = np.array([north_m, east_m], dtype=float)
        window = self._wedge_window(p, centres, half + max(float(bearing_error_rad), 0.0), max_range_m)
        i0, i1, j0, j1 = window
        self.scans += 1
        if i0 >= i1 or j0 >= j1:
            return ScanUpdate(0, 0, 0, 0, False)
        predicted = self._predicted(p, window, centres, half, max_range_m, float(bearing_error_rad))
        reach = np.where(np.isinf(dist), max_range_m, dist)  # NaN stays NaN: nothing seen
        # Seen free: cells wholly closer than the reading (with half a metre to spare) in a known sector.
        cn, ce = np.ogrid[i0:i1, j0:j1]
        cn = cn + self.north_offset + 0.5 - p[0]
        ce = ce + self.east_offset + 0.5 - p[1]
        r = np.hypot(cn, ce)
        sector = self._sector_of(np.arctan2(ce, cn).ravel(), centres, half).reshape(r.shape)
        limit = np.where(sector >= 0, reach[np.maximum(sector, 0)], np.nan)
        free = (sector >= 0) & (r + 0.71 + 0.5 < limit) & (r <= max_range_m)
        fi, fj = np.nonzero(free)
        fi, fj = fi + i0, fj + j0
        self.free_count[fi, fj] = np.minimum(self.free_count[fi, fj].astype(np.int64) + 1, 65535)
        self.known[fi, fj] = True
        if self.footprint is not None:
            self.map_cells_seen_free += int(self.footprint[fi, fj].sum())
        # New obstacles: readings clearly shorter than the map predicts.
        finite = np.isfinite(dist)
        unexplained = finite & (dist < predicted - tolerance)
        explained = int((finite & ~unexplained).sum())
        lo, hi = self._hit_spans(centres, half, dist, unexplained)
        hit_cells = self._arc_cells(p, lo, hi, dist[unexplained], tolerance)
        if len(hit_cells):
            hi, hj = hit_cells[:, 0], hit_cells[:, 1]
            i0, i1 = min(i0, int(hi.min())), max(i1, int(hi.max()) + 1)  # an arc's cell at a wedge's rim
            j0, j1 = min(j0, int(hj.min())), max(j1, int(hj.max()) + 1)
            self.hit_count[hi, hj] = np.minimum(self.hit_count[hi, hj].astype(np.int64) + 1, 65535)
            self.known[hi, hj] = True
        sub = (slice(i0, i1), slice(j0, j1))
        before = self.hits[sub].copy()
        counts = self.hit_count[sub].astype(np.int64)
        outweighed = self.free_count[sub].astype(np.int64) >= counts + self.free_to_clear
        dropped = before & outweighed
        self.once_dropped[sub] |= dropped
        after = (counts >= self.confirm_hits) & ~outweighed
        self.hits[sub] = after
        changed = after != before
        new_hits = int((after & ~before).sum())
        cleared = int((before & ~after).sum())
        grid_changed = False
        if changed.any():
            grid_changed = self._reinflate(np.argwhere(changed) + (i0, j0))
        return ScanUpdate(new_hits, cleared, explained, int(unexplained.sum()), grid_changed)

    def _hit_spans(self, centres: np.ndarray, half: float, dist: np.ndarray,
                   unexplained: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bearings ``(lo, hi)`` of each unexplained sector's arc that may hold the obstacle point.

        A sector's reading is its nearest obstacle point, somewhere on the arc at that range; the whole arc is
        marked, except in fine sectors (PX4's 5 degrees, ``half <= FINE_HALF_RAD``) where one neighbour reads
        clearly shorter and the other does not: a surface seen obliquely comes closer towards that neighbour, so
        the nearest point of this wedge is at the edge they share, and only the quarter of the arc next to it is
        marked; when the next neighbour on that side reads shorter still (the face crosses both edges), only the
        edge point. Where neither neighbour reads nearer, a corner (or a face seen square on) is the nearest
        point; when a neighbour and the next one read a face receding from this wedge, the point is placed on
        that face's line at the reading's range (where both sides see one they must agree within half a metre),
        else the whole arc is marked. Marked whole, that arc lies up to 2.5 m in front of a face seen at 30 m and
        60 degrees, and inflated by the margin it closed a street the truth left open; across a wall's corner it
        reaches a metre past the end, into the way round it."""
        c, d = centres[unexplained], dist[unexplained]
        lo, hi = c - half, c + half
        if len(c) == 0:
            return lo, hi
        if half > FINE_HALF_RAD:
            return self._face_spans(centres, half, dist, unexplained, lo, hi)
        width = 2.0 * half
        count = max(int(round(_TWO_PI / width)), 1)
        index = np.round((centres - centres.min()) / width).astype(np.int64) % count  # neighbours differ by 1
        reading = dict(zip(index.tolist(), dist.tolist()))
        mine = index[unexplained]
        left = np.array([reading.get(int((k - 1) % count), math.nan) for k in mine])
        right = np.array([reading.get(int((k + 1) % count), math.nan) for k in mine])
        with np.errstate(invalid="ignore"):
            left_nearer, right_nearer = left < d - NEIGHBOUR_MARGIN_M, right < d - NEIGHBOUR_MARGIN_M
        nearer_left, nearer_right = left_nearer & ~right_nearer, right_nearer & ~left_nearer
        # A run of three (the next neighbour on that side reads shorter still): a face crossing both shared edges,
        # so this wedge's nearest point is the edge point itself. The quarter arc at a grazing angle lies up to
        # 0.6 m in front of the face, a cell too near: one such cell closed a passage one cell wide past a wall's
        # end, and the mission ended in a false "no path".
        far_left = np.array([reading.get(int((k - 2) % count), math.nan) for k in mine])
        far_right = np.array([reading.get(int((k + 2) % count), math.nan) for k in mine])
        with np.errstate(invalid="ignore"):
            run = ((nearer_left & (far_left < left - NEIGHBOUR_MARGIN_M))
                   | (nearer_right & (far_right < right - NEIGHBOUR_MARGIN_M)))
        point = np.minimum(EDGE_POINT_ARC_M / np.maximum(d, 1.0), 0.5 * half)
        edge = np.where(run, point, 0.5 * half)
        hi = np.where(nearer_left, lo + edge, hi)
        lo = np.where(nearer_right, hi - edge, lo)
        # Neither neighbour nearer: a corner (or a face seen square on) is the wedge's nearest point. Where a
        # neighbour and the next one read a face receding from this wedge, that face's line through their edge
        # points, carried on into this wedge to the reading's range, is where its corner stands.
        from_left = _along_face(c - half, c - 3.0 * half, left, far_left, d, c, half)
        from_right = _along_face(c + half, c + 3.0 * half, right, far_right, d, c, half)
        both = np.isfinite(from_left) & np.isfinite(from_right)
        agree = both & (np.abs(_wrap(from_left - from_right)) * d <= 0.5)
        corner = np.where(agree, from_left + 0.5 * _wrap(from_right - from_left),
                          np.where(both, np.nan, np.where(np.isfinite(from_left), from_left, from_right)))
        located = ~left_nearer & ~right_nearer & np.isfinite(corner)
        lo = np.where(located, corner - 0.5 * point, lo)
        hi = np.where(located, corner + 0.5 * point, hi)
        return lo, hi

    @staticmethod
    def _face_spans(centres: np.ndarray, half: float, dist: np.ndarray, unexplained: np.ndarray,
                    lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Wide sectors (ArduPilot's 45 degrees): an unexplained reading ``d`` is the nearest point of its wedge,
        somewhere on the arc at ``d``; marked whole, that arc lies across the street in front of a wall seen
        obliquely and round a wall's end (from 5.5 m beside a wall a wedge's edge meets it 14.4 m on, and the arc
        there closed the way past its end: three held-out model missions gave their reachable goals up).

        One straight face seen across several wedges is recognised instead: readings falling towards one side to
        a least one (the wedge holding the face's foot, at distance ``p``); the next wedge's reading at its edge
        towards the foot gives the foot's bearing, every wedge of the run between must read the face's distance at
        its own edge towards the foot, and this wedge's reading must be the face's distance at its edge
        (``p / cos``, within a neighbour margin). Then the wedge's nearest point is that edge point, and only it
        is marked: anything else in the wedge stands no nearer, and shows once it is the nearest. A run that is
        not one face (another obstacle nearer in a wedge, a corner) fails a check and keeps the whole arc. The
        check uses angles between the wedges only, so a heading error turns the point with the wedges."""
        width = 2.0 * half
        count = max(int(round(_TWO_PI / width)), 1)
        index = np.round((centres - centres.min()) / width).astype(np.int64) % count
        reading = dict(zip(index.tolist(), dist.tolist()))
        centre_of = {int(k): float(v) for k, v in zip(index.tolist(), centres.tolist())}
        lo, hi = lo.copy(), hi.copy()
        for n, (k, d) in enumerate(zip(index[unexplained].tolist(), dist[unexplained].tolist())):
            for side in (-1, 1):
                edge = _face_edge(reading, centre_of, int(k), side, half, count, float(d))
                if edge is not None:
                    point = min(EDGE_POINT_ARC_M / max(d, 1.0), 0.5 * half)
                    lo[n], hi[n] = (edge, edge + point) if side < 0 else (edge - point, edge)
                    break
        return lo, hi

    def _arc_cells(self, p: np.ndarray, lo: np.ndarray, hi: np.ndarray, dist: np.ndarray,
                   tolerance_m: float) -> np.ndarray:
        """Unique cells (on the grid, not within ``tolerance_m`` of the map's footprint) on the arcs at ``dist``
        between bearings ``lo`` and ``hi`` (rad)."""
        if len(dist) == 0:
            return np.empty((0, 2), np.int64)
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        d = np.maximum(np.asarray(dist, float), 0.0)
        steps = np.maximum(2, np.ceil((hi - lo) * np.maximum(d, 1.0) / self.arc_step_m).astype(np.int64) + 1)
        arc = np.repeat(np.arange(len(d)), steps)
        first = np.cumsum(steps) - steps
        along = np.arange(len(arc)) - first[arc]  # each sample's index on its arc: np.linspace's arithmetic
        angles = along * ((hi - lo) / (steps - 1))[arc] + lo[arc]
        angles[first + steps - 1] = hi  # the arc's last sample is its end bearing exactly
        ne = np.column_stack([np.cos(angles), np.sin(angles)])
        pts = p + d[arc, None] * ne
        cells = np.floor(pts - (self.north_offset, self.east_offset)).astype(np.int64)
        n, m = self.shape
        on = (cells[:, 0] >= 0) & (cells[:, 0] < n) & (cells[:, 1] >= 0) & (cells[:, 1] < m)
        cells, arc = cells[on], arc[on]
        if self._map_distance is not None and len(cells):
            keep = self._map_distance[cells[:, 0], cells[:, 1]] > tolerance_m
            cells, arc = cells[keep], arc[keep]
        # A cell once dropped as noise takes an arc's hit only when no other cell of that arc can: the reading
        # says some point of the arc is an obstacle, and cells seen free more often than hit are the least
        # likely to hold it. Without this, an arc across a wall's end re-marked the free cell beside it each time
        # the vehicle came back, and its margin closed the street again: a vehicle flew to and fro for good.
        dropped = self.once_dropped[cells[:, 0], cells[:, 1]]
        if dropped.any():
            others = np.bincount(arc[~dropped], minlength=len(dist)) > 0
            cells = cells[~dropped | ~others[arc]]
        if not len(cells):
            return np.empty((0, 2), np.int64)
        flat = np.unique(cells[:, 0] * m + cells[:, 1])  # row-major: np.unique(cells, axis=0)'s order, faster
        return np.column_stack([flat // m, flat % m])

    def set_margin(self, margin_m: float) -> bool:
        """Inflate the observed obstacles by ``margin_m`` (m, at most the safety margin) from now on, every one
        already seen included; True if the planning grid changed. The map's own buildings keep the safety margin.

        A hit cell counts whole, and an arc seen obliquely lies up to a metre in front of the face it saw: the
        inflated layer overstates an observed obstacle by up to that much, and beside a wall's end it can close a
        gap the true wall leaves open at the full margin. :meth:`~.replan.Replanner.replan` narrows the margin
        (down to a floor) only when the goal is out of reach without it."""
        margin_m = float(margin_m)
        if not 0.0 <= margin_m <= self.safety_m:
            raise ValueError(f"the margin round observed obstacles must lie in [0, {self.safety_m:g}] m, "
                             f"not {margin_m:g}")
        if margin_m == self.margin_m:
            return False
        self.margin_m = margin_m
        cells = np.argwhere(self.hits)
        return bool(len(cells)) and self._reinflate(cells)

    def _reinflate(self, changed_cells: np.ndarray) -> bool:
        """Recompute the inflated layer round changed hit cells; True if the planning grid changed."""
        reach = int(math.ceil(self.safety_m)) + 2
        n, m = self.shape
        i0 = max(int(changed_cells[:, 0].min()) - reach, 0)
        i1 = min(int(changed_cells[:, 0].max()) + reach + 1, n)
        j0 = max(int(changed_cells[:, 1].min()) - reach, 0)
        j1 = min(int(changed_cells[:, 1].max()) + reach + 1, m)
        # Every hit that can reach the window, as 1 m boxes in map metres.
        a0, a1, b0, b1 = max(i0 - reach, 0), min(i1 + reach, n), max(j0 - reach, 0), min(j1 + reach, m)
        cells = np.argwhere(self.hits[a0:a1, b0:b1]) + (a0, b0)
        lo_n = (cells[:, 0] + self.north_offset).astype(np.float64)
        lo_e = (cells[:, 1] + self.east_offset).astype(np.float64)
        window = kernels.rasterise(lo_n, lo_n + 1.0, lo_e, lo_e + 1.0, float(self.north_offset + i0),
                                   float(self.east_offset + j0), self.margin_m, i1 - i0, j1 - j0)
        window |= self.hits[i0:i1, j0:j1]
        sub = (slice(i0, i1), slice(j0, j1))
        self.inflated[sub] = window
        new = self.base[sub] | window
        grid_changed = bool((new != self._grid[sub]).any())
        if grid_changed:
            self._grid[sub] = new
            self.version += 1
        return grid_changed
