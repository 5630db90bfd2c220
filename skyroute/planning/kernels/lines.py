"""Compiled line walks on the occupancy grid: the supercover of a segment, and line-of-sight pruning.

The grid here is an unpadded 2D ``bool`` array, True = blocked, indexed ``grid[north_idx, east_idx]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def walk_supercover(blocked, i0, j0, i1, j1, out):
    """Visit every cell that the segment between the centres of cells (i0, j0) and (i1, j1) touches.

    Integer-exact: crossing number ``a`` of a row boundary happens at t = (2a - 1) / (2 |di|), crossing ``b`` of
    a column boundary at t = (2b - 1) / (2 |dj|). When both happen at once the segment passes through a grid
    vertex and both side cells count as touched. ``blocked`` is an unpadded 2D grid here. If ``out`` has rows,
    visited cells are written to it and the count returned; otherwise the walk stops at the first blocked cell
    and returns -1 (0 if all are free).
    """
    record = out.shape[0] > 0
    ni, nj = abs(i1 - i0), abs(j1 - j0)
    si = 1 if i1 > i0 else -1
    sj = 1 if j1 > j0 else -1
    i, j = i0, j0
    a, b = 1, 1
    count = 0
    if record:
        out[count, 0], out[count, 1] = i, j
        count += 1
    elif blocked[i, j]:
        return -1
    while a <= ni or b <= nj:
        row_t = (2 * a - 1) * nj  # compare t_row = (2a-1)/(2ni) with t_col = (2b-1)/(2nj) without division
        col_t = (2 * b - 1) * ni
        if b > nj or (a <= ni and row_t < col_t):
            i += si
            a += 1
        elif a > ni or col_t < row_t:
            j += sj
            b += 1
        else:  # through a vertex: the two side cells touch the segment too
            if record:
                out[count, 0], out[count, 1] = i + si, j
                out[count + 1, 0], out[count + 1, 1] = i, j + sj
                count += 2
            elif blocked[i + si, j] or blocked[i, j + sj]:
                return -1
            i += si
            j += sj
            a += 1
            b += 1
        if record:
            out[count, 0], out[count, 1] = i, j
            count += 1
        elif blocked[i, j]:
            return -1
    return count


@njit(cache=True)
def prune_los_mask(grid, cells):
    """Greedy string pulling over a ``(K, 2)`` cell path: mark the cells to keep so every leg is visible."""
    no_output = np.empty((0, 2), np.int64)
    keep = np.zeros(cells.shape[0], np.bool_)
    keep[0] = True
    keep[-1] = True
    anchor = 0
    for k in range(2, cells.shape[0]):
        if walk_supercover(grid, cells[anchor, 0], cells[anchor, 1], cells[k, 0], cells[k, 1], no_output) != 0:
            anchor = k - 1
            keep[anchor] = True
    return keep
