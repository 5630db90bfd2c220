"""A search's per-query state in a hash table, so its memory grows with the cells it touches, not with the grid.

A table is four parallel arrays ``(keys, g, parent, closed)`` of one power-of-two capacity: ``keys[s]`` is the flat
cell stored in slot ``s`` (-1 = empty), ``g[s]`` its best cost so far, ``parent[s]`` the flat cell it was reached
from (-1 for the start) and ``closed[s]`` whether it has been expanded. Open addressing with linear probing and a
multiplicative hash; the table doubles when it is half full. A query on a 10 km grid that expands a thousand
cells allocates tables of a few thousand slots, where arrays indexed by cell would take gigabytes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: 2**64 / golden ratio, as a signed 64-bit integer (multiplication wraps around).
_GOLDEN = -7046029254386353131
EMPTY = -1


@njit(cache=True)
def new_table(capacity):
    """An empty table with ``capacity`` slots (a power of two)."""
    keys = np.full(capacity, EMPTY, np.int64)
    return keys, np.empty(capacity, np.float64), np.empty(capacity, np.int64), np.zeros(capacity, np.bool_)


@njit(cache=True, inline="always")
def _home(key, mask):
    x = key * _GOLDEN
    return (x ^ (x >> 31)) & mask


@njit(cache=True)
def find(keys, key):
    """Slot holding ``key``, or -1 if it is not stored."""
    mask = keys.shape[0] - 1
    s = _home(key, mask)
    while True:
        k = keys[s]
        if k == key:
            return s
        if k == EMPTY:
            return -1
        s = (s + 1) & mask


@njit(cache=True)
def _probe(keys, key):
    """Slot holding ``key`` or the empty slot where it would go."""
    mask = keys.shape[0] - 1
    s = _home(key, mask)
    while keys[s] != key and keys[s] != EMPTY:
        s = (s + 1) & mask
    return s


@njit(cache=True)
def _grown(keys, g, parent, closed):
    new_keys, new_g, new_parent, new_closed = new_table(2 * keys.shape[0])
    for s in range(keys.shape[0]):
        if keys[s] != EMPTY:
            t = _probe(new_keys, keys[s])
            new_keys[t], new_g[t], new_parent[t], new_closed[t] = keys[s], g[s], parent[s], closed[s]
    return new_keys, new_g, new_parent, new_closed


@njit(cache=True)
def claim(keys, g, parent, closed, count, key):
    """The slot of ``key``, storing it (cost inf, no parent, open) if it is new.

    Returns the possibly grown arrays, the new count of stored keys and the slot.
    """
    s = _probe(keys, key)
    if keys[s] == key:
        return keys, g, parent, closed, count, s
    if 2 * (count + 1) > keys.shape[0]:
        keys, g, parent, closed = _grown(keys, g, parent, closed)
        s = _probe(keys, key)
    keys[s], g[s], parent[s], closed[s] = key, np.inf, EMPTY, False
    return keys, g, parent, closed, count + 1, s
