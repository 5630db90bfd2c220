"""The configuration space as the project built it before the Euclidean margin, kept as a benchmark peer.

``create_grid_square_margin`` grows every footprint by the margin into a bigger rectangle (square corners,
Chebyshev distance) and paints the rectangles with one 2D difference array (``np.bincount`` and two cumulative
sums over the whole grid). Same signature and returns as ``planning_utils.create_grid``; it blocks a superset of
its cells (up to sqrt(2) times the margin at corners).
"""

from __future__ import annotations

import math

import numpy as np


def create_grid_square_margin(data: np.ndarray, drone_altitude: float, safety_distance: float):
    """``(grid, north_offset, east_offset)`` with footprints grown into rectangles by ``safety_distance``."""
    data = np.asarray(data, dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != 6 or len(data) == 0:
        raise ValueError(f"obstacle data must be a non-empty (N, 6) array, got shape {data.shape}")
    # NaN compares False with everything: unchecked, it would make every obstacle "low" and the grid all free.
    if math.isnan(drone_altitude) or not (math.isfinite(safety_distance) and safety_distance >= 0):
        raise ValueError(
            f"drone_altitude must not be NaN and safety_distance must be finite and >= 0, got {drone_altitude}, "
            f"{safety_distance}"
        )
    if not np.isfinite(data).all():
        raise ValueError("obstacle data contains NaN or infinite values")
    north, east, alt, d_north, d_east, d_alt = data.T
    north_offset = int(np.floor(np.min(north - d_north)))
    east_offset = int(np.floor(np.min(east - d_east)))
    north_size = int(np.ceil(np.max(north + d_north))) - north_offset
    east_size = int(np.ceil(np.max(east + d_east))) - east_offset

    tall = alt + d_alt + safety_distance > drone_altitude
    # Cell i intersects the open interval (a, b) iff floor(a) <= i < ceil(b) (a, b relative to the offset).
    n_lo = np.clip(np.floor(north[tall] - d_north[tall] - safety_distance - north_offset), 0, north_size)
    n_hi = np.clip(np.ceil(north[tall] + d_north[tall] + safety_distance - north_offset), 0, north_size)
    e_lo = np.clip(np.floor(east[tall] - d_east[tall] - safety_distance - east_offset), 0, east_size)
    e_hi = np.clip(np.ceil(east[tall] + d_east[tall] + safety_distance - east_offset), 0, east_size)
    n_lo, n_hi, e_lo, e_hi = (a.astype(np.int64) for a in (n_lo, n_hi, e_lo, e_hi))

    # 2D difference array: +1 at each rectangle's low corner, -1 past its edges, +1 past the far corner.
    width = east_size + 1
    corners = np.concatenate([n_lo * width + e_lo, n_hi * width + e_hi, n_lo * width + e_hi, n_hi * width + e_lo])
    signs = np.repeat(np.array([1, 1, -1, -1], dtype=np.int32), len(n_lo))
    diff = np.bincount(corners, weights=signs, minlength=(north_size + 1) * width).astype(np.int32)
    counts = diff.reshape(north_size + 1, width).cumsum(axis=0).cumsum(axis=1)
    return counts[:north_size, :east_size] > 0, north_offset, east_offset
