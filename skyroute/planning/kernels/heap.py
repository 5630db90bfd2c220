"""Binary min-heap of ``(f, g, node)`` in three parallel arrays, shared by every compiled search.

Ordered by ``f``, then by larger ``g``: among equal ``f`` the deeper node goes first, which finishes straight runs
instead of fanning out. The heap never deletes: a search pushes a node again when it finds a cheaper way to it and
skips the stale entry when it pops.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _less(hf, hg, a, b):
    return hf[a] < hf[b] or (hf[a] == hf[b] and hg[a] > hg[b])


@njit(cache=True, inline="always")
def _swap(hf, hg, hv, a, b):
    hf[a], hf[b] = hf[b], hf[a]
    hg[a], hg[b] = hg[b], hg[a]
    hv[a], hv[b] = hv[b], hv[a]


@njit(cache=True)
def heap_push(hf, hg, hv, size, f, g, v):
    """Push and return the (possibly grown) arrays and the new size."""
    if size == hf.shape[0]:
        hf = np.concatenate((hf, np.empty(size, np.float64)))
        hg = np.concatenate((hg, np.empty(size, np.float64)))
        hv = np.concatenate((hv, np.empty(size, np.int64)))
    k = size
    hf[k], hg[k], hv[k] = f, g, v
    while k > 0:
        p = (k - 1) // 2
        if not _less(hf, hg, k, p):
            break
        _swap(hf, hg, hv, k, p)
        k = p
    return hf, hg, hv, size + 1


@njit(cache=True)
def heap_pop(hf, hg, hv, size):
    """Remove the root; return its ``(node, f, g)`` and the new size."""
    v, f, g = hv[0], hf[0], hg[0]
    size -= 1
    hf[0], hg[0], hv[0] = hf[size], hg[size], hv[size]
    k = 0
    while True:
        c = 2 * k + 1
        if c >= size:
            break
        if c + 1 < size and _less(hf, hg, c + 1, c):
            c += 1
        if not _less(hf, hg, c, k):
            break
        _swap(hf, hg, hv, k, c)
        k = c
    return v, f, g, size


@njit(cache=True)
def new_heap():
    """Empty heap arrays ``(f, g, node)`` with room for 1024 entries (they grow on push)."""
    return np.empty(1024, np.float64), np.empty(1024, np.float64), np.empty(1024, np.int64)
