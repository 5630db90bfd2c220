"""Compiled rasterising of obstacle footprints grown by a Euclidean margin (rounded corners) into 1 m cells.

Coordinates are map metres: cell ``(i, j)`` is the closed square ``[n0 + i, n0 + i + 1] x [e0 + j, e0 + j + 1]``
for the grid's whole-metre south-west corner ``(n0, e0)``, and a box footprint is ``[lo_n, hi_n] x [lo_e, hi_e]``.
The gap between a cell and a footprint along one axis is ``max(lo - (c0 + k + 1), (c0 + k) - hi)``: positive when
they are apart, zero when they touch, negative when they overlap (computed from the map coordinates, so the only
rounding is that of the box edges themselves). A cell is *covered* by a box grown by ``margin`` when

* ``margin > 0``: its square comes closer than ``margin`` to the footprint (Euclidean distance between the two
  rectangles ``hypot(max(gap_n, 0), max(gap_e, 0)) < margin``), so the grown footprint has rounded corners;
* ``margin == 0``: its square overlaps the footprint's interior (both gaps negative).

The work is row by row: boxes sorted by their first row enter an active list and leave it after their last, and
each active box adds one run of covered cells to the row. Cost ``O(cells + sum over boxes of their rows)``, memory
one row of counters besides the output; no per-box 2D slices.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _gap(lo, hi, corner):
    """Signed gap between the 1 m interval ``[corner, corner + 1]`` and ``[lo, hi]``."""
    return max(lo - (corner + 1.0), corner - hi)


@njit(cache=True, inline="always")
def covered(gap_n, gap_e, margin):
    """True if a cell with these signed gaps to a footprint is covered by the footprint grown by ``margin``."""
    if margin == 0.0:
        return gap_n < 0.0 and gap_e < 0.0
    if gap_n <= 0.0:
        return gap_e < margin
    if gap_e <= 0.0:
        return gap_n < margin
    return gap_n * gap_n + gap_e * gap_e < margin * margin


@njit(cache=True)
def row_run(i, lo_n, hi_n, lo_e, hi_e, n0, e0, margin, m):
    """Columns ``[j0, j1)`` (clipped to ``[0, m]``) of row ``i`` covered by one grown footprint."""
    gap_n = _gap(lo_n, hi_n, n0 + i)
    if gap_n >= margin:  # with no margin, only rows that overlap the footprint (gap < 0)
        return 0, 0
    if margin == 0.0 or gap_n <= 0.0:
        reach = margin
    else:
        reach = math.sqrt(margin * margin - gap_n * gap_n)
    # Columns with gap_e < reach, then settle the two ends with the exact test (sqrt may round either way).
    j0 = int(math.floor(lo_e - e0 - reach))
    j1 = int(math.ceil(hi_e - e0 + reach))
    while j0 < j1 and not covered(gap_n, _gap(lo_e, hi_e, e0 + j0), margin):
        j0 += 1
    while j1 > j0 and not covered(gap_n, _gap(lo_e, hi_e, e0 + j1 - 1), margin):
        j1 -= 1
    if j0 < j1:
        while covered(gap_n, _gap(lo_e, hi_e, e0 + j0 - 1), margin):
            j0 -= 1
        while covered(gap_n, _gap(lo_e, hi_e, e0 + j1), margin):
            j1 += 1
    return min(max(j0, 0), m), min(max(j1, 0), m)


@njit(cache=True)
def _row_bands(lo_n, hi_n, n0, margin, n):
    """First and one-past-last row each grown footprint can cover (one spare row each side), clipped to the grid."""
    first = np.empty(lo_n.shape[0], np.int64)
    last = np.empty(lo_n.shape[0], np.int64)
    for b in range(lo_n.shape[0]):
        first[b] = min(max(int(math.floor(lo_n[b] - n0 - margin)) - 1, 0), n)
        last[b] = min(max(int(math.ceil(hi_n[b] - n0 + margin)) + 1, 0), n)
    return first, last


@njit(cache=True)
def rasterise(lo_n, hi_n, lo_e, hi_e, n0, e0, margin, n, m):
    """``(n, m)`` bool grid with corner ``(n0, e0)``: True where some footprint grown by ``margin`` covers the cell."""
    out = np.zeros((n, m), np.bool_)
    first, last = _row_bands(lo_n, hi_n, n0, margin, n)
    order = np.argsort(first, kind="mergesort")
    active = np.empty(lo_n.shape[0], np.int64)
    n_active, p = 0, 0
    diff = np.zeros(m + 1, np.int32)  # +1 where a run starts, -1 past its end
    for i in range(n):
        while p < order.shape[0] and first[order[p]] <= i:
            active[n_active] = order[p]
            n_active += 1
            p += 1
        kept, lo, hi = 0, m, 0
        for a in range(n_active):
            b = active[a]
            if last[b] <= i:
                continue
            active[kept] = b
            kept += 1
            j0, j1 = row_run(i, lo_n[b], hi_n[b], lo_e[b], hi_e[b], n0, e0, margin, m)
            if j0 < j1:
                diff[j0] += 1
                diff[j1] -= 1
                lo, hi = min(lo, j0), max(hi, j1)
        n_active = kept
        count = 0
        for j in range(lo, hi):
            count += diff[j]
            diff[j] = 0
            out[i, j] = count > 0
        if lo < hi:
            diff[hi] = 0
    return out


@njit(cache=True, inline="always")
def _next_unpainted(nxt, j):
    while nxt[j] != j:
        nxt[j] = nxt[nxt[j]]  # path halving
        j = nxt[j]
    return j


@njit(cache=True)
def rasterise_max(lo_n, hi_n, lo_e, hi_e, value, n0, e0, margin, n, m):
    """``(n, m)`` float grid with corner ``(n0, e0)``: the largest ``value`` of the grown footprints covering each
    cell, ``-inf`` where none does.

    Per row the runs are painted in decreasing ``value``, each cell once: a "next unpainted column" array with
    path halving skips the cells a higher run already holds, so a row costs ``O(m + runs log runs)``.
    """
    out = np.full((n, m), -np.inf)
    first, last = _row_bands(lo_n, hi_n, n0, margin, n)
    order = np.argsort(first, kind="mergesort")
    active = np.empty(lo_n.shape[0], np.int64)
    run_lo = np.empty(lo_n.shape[0], np.int64)
    run_hi = np.empty(lo_n.shape[0], np.int64)
    run_value = np.empty(lo_n.shape[0], np.float64)
    nxt = np.arange(m + 1)
    n_active, p = 0, 0
    for i in range(n):
        while p < order.shape[0] and first[order[p]] <= i:
            active[n_active] = order[p]
            n_active += 1
            p += 1
        kept, runs, lo, hi = 0, 0, m, 0
        for a in range(n_active):
            b = active[a]
            if last[b] <= i:
                continue
            active[kept] = b
            kept += 1
            j0, j1 = row_run(i, lo_n[b], hi_n[b], lo_e[b], hi_e[b], n0, e0, margin, m)
            if j0 < j1:
                run_lo[runs], run_hi[runs], run_value[runs] = j0, j1, value[b]
                runs += 1
                lo, hi = min(lo, j0), max(hi, j1)
        n_active = kept
        if runs == 0:
            continue
        for r in np.argsort(-run_value[:runs]):
            j = _next_unpainted(nxt, run_lo[r])
            while j < run_hi[r]:
                out[i, j] = run_value[r]
                nxt[j] = j + 1
                j = _next_unpainted(nxt, j + 1)
        for j in range(lo, hi + 1):
            nxt[j] = j
    return out
