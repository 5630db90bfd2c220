"""The city: obstacle boxes from ``colliders.csv`` and the collision truth.

Frames
------
*Map frame*: the local tangent plane at the map header's ``(lat0, lon0)`` and altitude 0, with axes
north, east and **up** (metres). ``up`` is height above the map datum, which is also the altitude
reported as "AMSL" by the sim. Conversions to geodetic go through :mod:`pymap3d` (NED at alt 0).

Map file
--------
Line 1: ``lat0 37.792480, lon0 -122.397450``; line 2: ``posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ``;
then one box per row: centre north, east, up and half sizes along north, east, up (metres). The
rules and their error messages are :mod:`sim.mapfile`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from .mapfile import MapFormatError, read_colliders

log = logging.getLogger(__name__)

#: Edge of one spatial-index cell (m). Boxes in the SF map are at most 10 m wide.
CELL_M = 25.0
#: A box that covers more index cells than this goes to a short list checked on every query instead, so that
#: the index stays bounded (a 50 km box would otherwise fill four million cells).
MAX_CELLS_PER_BOX = 256
#: Distances beyond this (m) are not searched: :meth:`CityMap.nearest_box` returns this cap.
SEARCH_CAP_M = 50.0

__all__ = ["CELL_M", "SEARCH_CAP_M", "Box", "CityMap", "MapFormatError", "write_colliders"]


@dataclass(frozen=True)
class Box:
    """One obstacle as an axis-aligned box in the map frame (metres)."""

    index: int
    north_m: float
    east_m: float
    up_m: float
    half_north_m: float
    half_east_m: float
    half_up_m: float

    def as_dict(self) -> dict:
        return {
            "index": self.index,
            "north_m": self.north_m,
            "east_m": self.east_m,
            "up_m": self.up_m,
            "half_north_m": self.half_north_m,
            "half_east_m": self.half_east_m,
            "half_up_m": self.half_up_m,
        }


class CityMap:
    """Obstacle boxes with a uniform-grid spatial index.

    Parameters
    ----------
    lat0_deg, lon0_deg : float
        Geodetic origin of the map frame (degrees). The datum altitude is 0 m.
    boxes : ndarray, shape (N, 6)
        Rows of ``north, east, up, half_north, half_east, half_up`` (metres), centre and half sizes.
    """

    def __init__(self, lat0_deg: float, lon0_deg: float, boxes: np.ndarray) -> None:
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 6)
        self.lat0_deg = float(lat0_deg)
        self.lon0_deg = float(lon0_deg)
        self.boxes = boxes
        self.lo = boxes[:, 0:3] - boxes[:, 3:6]  # (N, 3) north, east, up minima
        self.hi = boxes[:, 0:3] + boxes[:, 3:6]
        self._cells: dict[tuple[int, int], np.ndarray] = {}
        buckets: dict[tuple[int, int], list[int]] = {}
        big: list[int] = []
        for i in range(len(boxes)):
            n0, e0 = self._cell(self.lo[i, 0], self.lo[i, 1])
            n1, e1 = self._cell(self.hi[i, 0], self.hi[i, 1])
            if (n1 - n0 + 1) * (e1 - e0 + 1) > MAX_CELLS_PER_BOX:
                big.append(i)
                continue
            for cn in range(n0, n1 + 1):
                for ce in range(e0, e1 + 1):
                    buckets.setdefault((cn, ce), []).append(i)
        self._cells = {k: np.array(v, dtype=np.intp) for k, v in buckets.items()}
        self._big = np.array(big, dtype=np.intp)
        self._empty = np.zeros(0, dtype=np.intp)

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_csv(cls, path: str | Path) -> CityMap:
        """Read and validate a ``colliders.csv`` map (rules: :mod:`sim.mapfile`).

        Raises
        ------
        MapFormatError
            One line naming the file, the line and why.
        OSError
            If the file cannot be read.
        """
        lat0, lon0, data = read_colliders(path)
        log.info("loaded %d boxes from %s", len(data), path)
        return cls(lat0, lon0, data)

    def extent(self) -> tuple[float, float, float, float]:
        """``(north_min, north_max, east_min, east_max)`` of all footprints and home (m)."""
        if len(self.boxes) == 0:
            return 0.0, 0.0, 0.0, 0.0
        return (min(0.0, float(self.lo[:, 0].min())), max(0.0, float(self.hi[:, 0].max())),
                min(0.0, float(self.lo[:, 1].min())), max(0.0, float(self.hi[:, 1].max())))

    def boot_point(self, start: tuple | None, radius_m: float, margin_m: float) -> np.ndarray:
        """Where a vehicle booting at ``start`` rests (map ``north, east, up``; see ``SimConfig.start``).

        Raises
        ------
        ValueError
            If the point lies more than ``margin_m`` outside the map's extent, or inside a building.
        """
        if start is None:
            n, e, alt = 0.0, 0.0, 0.0
        else:
            n, e, _ = self.geodetic_to_map(start[0], start[1], 0.0)
            alt = start[2] if len(start) == 3 else 0.0
        n0, n1, e0, e1 = self.extent()
        if not (n0 - margin_m <= n <= n1 + margin_m and e0 - margin_m <= e <= e1 + margin_m):
            raise ValueError(f"start {start[0]:.6f},{start[1]:.6f} is off the map: N {n:.0f} m, E {e:.0f} m from "
                             f"home; the map spans N {n0:.0f}..{n1:.0f} m, E {e0:.0f}..{e1:.0f} m "
                             f"(plus {margin_m:g} m)")
        point = np.array([n, e, self.ground_up_m(n, e, alt, radius_m)])
        inside = self.box_containing(point, radius_m)
        if inside >= 0:
            b = self.box(inside)
            where = "" if start is None else f"{start[0]:.6f},{start[1]:.6f} "
            raise ValueError(
                f"start {where}(N {n:.1f} m, E {e:.1f} m, up {point[2]:.1f} m) is inside box "
                f"{inside + 1} of the map (N {b.north_m - b.half_north_m:.1f}..{b.north_m + b.half_north_m:.1f} m, "
                f"E {b.east_m - b.half_east_m:.1f}..{b.east_m + b.half_east_m:.1f} m, "
                f"up {b.up_m - b.half_up_m:.1f}..{b.up_m + b.half_up_m:.1f} m); give LAT,LON,ALT with the roof's "
                "altitude to start on it")
        return point

    def box_containing(self, point_neu, radius_m: float = 0.0) -> int:
        """Row of a box that a sphere of ``radius_m`` resting on ``point_neu`` intersects, else -1."""
        centre = np.asarray(point_neu, dtype=float) + np.array([0.0, 0.0, radius_m])
        idx = self.candidates(centre[0], centre[1], radius_m)
        if idx.size == 0:
            return -1
        lo, hi = self.lo[idx], self.hi[idx]
        gap = np.maximum(np.maximum(lo - centre, centre - hi), 0.0)
        distance = np.sqrt(np.einsum("ij,ij->i", gap, gap))
        strictly_inside = np.all((lo < centre) & (centre < hi), axis=1)
        hit = strictly_inside | (distance < radius_m - 1e-9)
        return int(idx[np.argmax(hit)]) if hit.any() else -1

    # ------------------------------------------------------------------ frames
    def geodetic_to_map(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """Geodetic (deg, deg, m above datum) to map ``(north_m, east_m, up_m)``.

        North/east come from :func:`pymap3d.geodetic2ned`; ``up_m`` is the altitude itself (the
        tangent plane's curvature drop, about 8 cm at 1 km, is ignored in the vertical so that
        "altitude" and "height in the map" are the same number).
        """
        n, e, _d = pymap3d.geodetic2ned(lat_deg, lon_deg, 0.0, self.lat0_deg, self.lon0_deg, 0.0)
        return float(n), float(e), float(alt_m)

    def map_to_geodetic(self, north_m: float, east_m: float, up_m: float) -> tuple[float, float, float]:
        """Map ``(north_m, east_m, up_m)`` to geodetic ``(lat_deg, lon_deg, alt_m)`` (inverse of above)."""
        lat, lon, _alt = pymap3d.ned2geodetic(north_m, east_m, 0.0, self.lat0_deg, self.lon0_deg, 0.0)
        return float(lat), float(lon), float(up_m)

    def local_scale(self, autopilot: str) -> tuple[float, float]:
        """How an autopilot's local frame measures the map's metres, north and east (local metres per map metre).

        The real autopilots turn latitude and longitude differences into local metres on a sphere, not the WGS84
        ellipsoid: ArduPilot's Location::get_distance_NE uses the equatorial radius (LOCATION_SCALING_FACTOR),
        PX4's map projection (lib/geo) a 6371 km one. At SF's latitude ArduPilot's north is 0.29 % long and its
        east 0.13 % short; PX4's 0.18 % and 0.24 %. A client that takes LOCAL_POSITION_NED for true metres lands
        half a metre to a metre off a goal 460 m away; the sim reports its local frame the same way.
        """
        radius = {"ardupilot": 6378137.0, "px4": 6371000.0}[autopilot]
        a, e2 = 6378137.0, 6.69437999014e-3
        w = 1.0 - e2 * math.sin(math.radians(self.lat0_deg)) ** 2
        return radius * w**1.5 / (a * (1.0 - e2)), radius * math.sqrt(w) / a

    # ------------------------------------------------------------------ queries
    def _cell(self, north_m: float, east_m: float) -> tuple[int, int]:
        return math.floor(north_m / CELL_M), math.floor(east_m / CELL_M)

    def candidates(self, north_m: float, east_m: float, reach_m: float) -> np.ndarray:
        """Indices of boxes whose footprint may lie within ``reach_m`` of the point (may repeat)."""
        n0, e0 = self._cell(north_m - reach_m, east_m - reach_m)
        n1, e1 = self._cell(north_m + reach_m, east_m + reach_m)
        parts = [
            self._cells[(cn, ce)]
            for cn in range(n0, n1 + 1)
            for ce in range(e0, e1 + 1)
            if (cn, ce) in self._cells
        ]
        if self._big.size:
            parts.append(self._big)
        if not parts:
            return self._empty
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def nearest_box(self, point_neu: np.ndarray, cap_m: float = SEARCH_CAP_M) -> tuple[float, int]:
        """Euclidean distance from a point to the nearest box surface.

        Parameters
        ----------
        point_neu : ndarray, shape (3,)
            Map-frame point ``north, east, up`` (m).
        cap_m : float
            Search radius (m); nothing farther is looked at.

        Returns
        -------
        distance_m : float
            0 inside a box, ``cap_m`` if no box lies within ``cap_m``.
        index : int
            Row of the nearest box, -1 if none within ``cap_m``.

        Examples
        --------
        >>> city = CityMap(37.0, -122.0, np.array([[10.0, 0.0, 5.0, 1.0, 1.0, 5.0]]))
        >>> city.nearest_box(np.array([0.0, 0.0, 2.0]))
        (9.0, 0)
        """
        idx = self.candidates(point_neu[0], point_neu[1], cap_m)
        if idx.size == 0:
            return cap_m, -1
        gap = np.maximum(np.maximum(self.lo[idx] - point_neu, point_neu - self.hi[idx]), 0.0)
        dist = np.sqrt(np.einsum("ij,ij->i", gap, gap))
        k = int(np.argmin(dist))
        if dist[k] >= cap_m:
            return cap_m, -1
        return float(dist[k]), int(idx[k])

    def ground_up_m(self, north_m: float, east_m: float, below_up_m: float, radius_m: float = 0.0) -> float:
        """Height (m, map up) of the surface a vehicle at this point would land on.

        The surface is the highest box top that is not above ``below_up_m`` and whose footprint,
        grown by ``radius_m``, contains the point; the map ground (0 m) if there is none.

        Examples
        --------
        >>> city = CityMap(37.0, -122.0, np.array([[0.0, 0.0, 10.0, 5.0, 5.0, 10.0]]))
        >>> city.ground_up_m(0.0, 0.0, 50.0), city.ground_up_m(0.0, 0.0, 5.0)
        (20.0, 0.0)
        >>> city.ground_up_m(9.0, 0.0, 50.0)
        0.0
        """
        idx = self.candidates(north_m, east_m, radius_m)
        if idx.size == 0:
            return 0.0
        lo, hi = self.lo[idx], self.hi[idx]
        inside = (
            (lo[:, 0] - radius_m <= north_m)
            & (north_m <= hi[:, 0] + radius_m)
            & (lo[:, 1] - radius_m <= east_m)
            & (east_m <= hi[:, 1] + radius_m)
            & (hi[:, 2] <= below_up_m + 1e-6)
        )
        if not inside.any():
            return 0.0
        return max(0.0, float(hi[inside, 2].max()))

    def box(self, index: int) -> Box:
        """The box at row ``index``."""
        row = self.boxes[index]
        return Box(index, *(float(v) for v in row))

    def __len__(self) -> int:
        return len(self.boxes)


def write_colliders(path: str | Path, lat0_deg: float, lon0_deg: float, boxes: np.ndarray) -> Path:
    """Write boxes in the ``colliders.csv`` format (used by tests to make tiny maps)."""
    path = Path(path)
    lines = [f"lat0 {lat0_deg:.6f}, lon0 {lon0_deg:.6f}", "posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ"]
    lines += [",".join(f"{v:.6f}" for v in row) for row in np.asarray(boxes, dtype=float).reshape(-1, 6)]
    path.write_text("\n".join(lines) + "\n")
    return path
