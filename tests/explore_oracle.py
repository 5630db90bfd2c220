"""An independent judge of an exploration (issue 12), from the true map only; shared by the e2e test and the bench.

Nothing here imports the client: occupancy is rasterised here (a cell is occupied when its centre lies inside a
box that reaches above the altitude), the margin is scipy's Euclidean distance transform, the streets the vehicle
could reach are a flood fill of that, and the walls visible from them are found by casting rays (every degree,
0.25 m steps, up to the sensor's range) from points every ``sample_m`` across the reachable streets.

* ``recall``: share of the visible wall cells inside the explored disk with an occupied cell of the saved map
  within 1 m (centre to centre). A wall counts here only when it rises more than ``sensor_plane_m`` (0.5 m) above
  the altitude: a horizontal sensor carried at the altitude, held to within a few decimetres by the autopilot,
  sees over a pole whose top is 0.2 m above it on most passes (the bundled map has such poles), so no map made
  by that sensor can be required to hold it.
* ``precision``: share of the saved map's occupied cells within 1 m of a truly occupied cell.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage


def occupancy(boxes: np.ndarray, altitude_m: float, north0: int, east0: int, shape: tuple[int, int]) -> np.ndarray:
    """Cells ``[north_idx, east_idx]`` (1 m, cell (0, 0)'s corner at ``(north0, east0)``) whose centre is inside a
    box whose top is above ``altitude_m``."""
    occ = np.zeros(shape, bool)
    for n, e, a, dn, de, da in np.asarray(boxes, float).reshape(-1, 6):
        if a + da <= altitude_m:
            continue
        i0 = max(math.ceil(n - dn - north0 - 0.5), 0)
        i1 = min(math.floor(n + dn - north0 - 0.5), shape[0] - 1)
        j0 = max(math.ceil(e - de - east0 - 0.5), 0)
        j1 = min(math.floor(e + de - east0 - 0.5), shape[1] - 1)
        if i0 <= i1 and j0 <= j1:
            occ[i0:i1 + 1, j0:j1 + 1] = True
    return occ


def reachable(occ: np.ndarray, start_cell: tuple[int, int], safety_m: float, disk: np.ndarray) -> np.ndarray:
    """Cells in ``disk`` farther than ``safety_m`` from every occupied cell, 8-connected to the start."""
    free = ndimage.distance_transform_edt(~occ) > safety_m
    free &= disk
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    k = labels[start_cell]
    if k == 0:  # the start within a margin: its nearest free component
        dist, (ii, jj) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
        k = labels[ii[start_cell], jj[start_cell]]
    return labels == k


def visible_walls(occ: np.ndarray, streets: np.ndarray, range_m: float, sample_m: float = 3.0) -> np.ndarray:
    """Occupied cells first met by a ray from a street sample point (a sensor at the altitude)."""
    cells = np.argwhere(streets)
    keep = (cells[:, 0] % int(sample_m) == 0) & (cells[:, 1] % int(sample_m) == 0)
    points = cells[keep] + 0.5
    angles = np.radians(np.arange(0.0, 360.0, 1.0))
    steps = np.arange(0.25, range_m + 1e-9, 0.25)
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    seen = np.zeros_like(occ)
    n, m = occ.shape
    for p in points:
        ray = p[None, None, :] + steps[None, :, None] * dirs[:, None, :]  # (A, S, 2)
        ij = np.floor(ray).astype(np.int64)
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < n) & (ij[..., 1] >= 0) & (ij[..., 1] < m)
        ij = np.where(inside[..., None], ij, 0)
        hit = inside & occ[ij[..., 0], ij[..., 1]]
        first = np.argmax(hit, axis=1)
        any_hit = hit[np.arange(len(angles)), first]
        sel = ij[np.arange(len(angles)), first][any_hit]
        seen[sel[:, 0], sel[:, 1]] = True
    return seen


def score_map(true_boxes: np.ndarray, saved_boxes: np.ndarray, start_ne, radius_m: float, altitude_m: float,
              safety_m: float, range_m: float = 30.0, sensor_plane_m: float = 0.5) -> dict:
    """The saved map against the truth round ``start_ne`` (see the module notes)."""
    reach = int(math.ceil(radius_m + range_m + 5))
    north0, east0 = int(math.floor(start_ne[0])) - reach, int(math.floor(start_ne[1])) - reach
    shape = (2 * reach + 1, 2 * reach + 1)
    truth = occupancy(true_boxes, altitude_m, north0, east0, shape)
    saved = occupancy(saved_boxes, altitude_m, north0, east0, shape)
    ii, jj = np.mgrid[0:shape[0], 0:shape[1]]
    disk = np.hypot(ii + north0 + 0.5 - start_ne[0], jj + east0 + 0.5 - start_ne[1]) <= radius_m
    start_cell = (int(math.floor(start_ne[0])) - north0, int(math.floor(start_ne[1])) - east0)
    streets = reachable(truth, start_cell, safety_m, disk)
    clear_above = occupancy(true_boxes, altitude_m + sensor_plane_m, north0, east0, shape)
    walls = visible_walls(clear_above, streets, range_m) & disk  # the walls of the explored area
    near_saved = ndimage.distance_transform_edt(~saved) <= 1.0 if saved.any() else np.zeros_like(saved)
    near_truth = ndimage.distance_transform_edt(~truth) <= 1.0
    found = int((walls & near_saved).sum())
    correct = int((saved & near_truth).sum())
    return {"visible_wall_cells": int(walls.sum()), "found_wall_cells": found,
            "recall": found / max(int(walls.sum()), 1), "saved_cells": int(saved.sum()),
            "correct_saved_cells": correct, "precision": correct / max(int(saved.sum()), 1),
            "reachable_street_cells": int(streets.sum())}


def street_targets(true_boxes: np.ndarray, start_ne, radius_m: float, altitude_m: float, safety_m: float,
                   count: int, seed: int, min_from_start_m: float = 20.0) -> list[tuple[float, float]]:
    """``count`` held-out targets at random reachable street cells (clear of the margin at every height, so the
    vehicle may descend there), at least ``min_from_start_m`` from the start and 15 m from each other."""
    reach = int(math.ceil(radius_m + 5))
    north0, east0 = int(math.floor(start_ne[0])) - reach, int(math.floor(start_ne[1])) - reach
    shape = (2 * reach + 1, 2 * reach + 1)
    truth = occupancy(true_boxes, altitude_m, north0, east0, shape)
    ground = occupancy(true_boxes, 0.0, north0, east0, shape)
    ii, jj = np.mgrid[0:shape[0], 0:shape[1]]
    centre_n, centre_e = ii + north0 + 0.5, jj + east0 + 0.5
    r = np.hypot(centre_n - start_ne[0], centre_e - start_ne[1])
    disk = r <= radius_m - 3.0
    start_cell = (int(math.floor(start_ne[0])) - north0, int(math.floor(start_ne[1])) - east0)
    streets = reachable(truth, start_cell, safety_m + 1.0, disk)
    streets &= ndimage.distance_transform_edt(~ground) > safety_m + 1.0
    streets &= r >= min_from_start_m
    rng = np.random.default_rng(seed)
    cells = np.argwhere(streets)
    rng.shuffle(cells)
    out: list[tuple[float, float]] = []
    for i, j in cells:
        p = (float(centre_n[i, j]), float(centre_e[i, j]))
        if all(math.dist(p, q) >= 15.0 for q in out):
            out.append(p)
        if len(out) == count:
            break
    return out


def start_near_walls(true_boxes: np.ndarray, altitude_m: float, safety_m: float, wall_within_m: float = 15.0,
                     search_m: float = 120.0) -> tuple[float, float]:
    """The street cell nearest the map's home (within ``search_m``) that keeps ``safety_m + 2`` m from every
    building at any height and has a wall (at the altitude) within ``wall_within_m``: a start with something to map
    round it."""
    reach = int(math.ceil(search_m))
    shape = (2 * reach + 1, 2 * reach + 1)
    walls = occupancy(true_boxes, altitude_m, -reach, -reach, shape)
    ground = occupancy(true_boxes, 0.0, -reach, -reach, shape)
    to_wall = ndimage.distance_transform_edt(~walls)
    clear = ndimage.distance_transform_edt(~ground) > safety_m + 2.0
    ok = clear & (to_wall <= wall_within_m)
    ii, jj = np.mgrid[0:shape[0], 0:shape[1]]
    r = np.hypot(ii - reach + 0.5, jj - reach + 0.5)
    if not ok.any():
        raise ValueError("no street cell near home has a wall within reach")
    i, j = np.unravel_index(np.argmin(np.where(ok, r, np.inf)), shape)
    return float(i - reach + 0.5), float(j - reach + 0.5)
