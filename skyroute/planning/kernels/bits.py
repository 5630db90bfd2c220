"""The occupancy grid as bits, 64 cells to a word, for jump point search's straight scans.

A straight scan looks for the first cell ahead that is blocked (a wall), the goal, or has a *forced* neighbour: a
free cell beside it whose cell one step back is blocked. With the row and its two neighbour rows as bits, one
word answers that for 64 cells at once (``stop = wall | (~side & side_behind)`` for both sides); precomputed per
direction with the index of the next word holding a stop (:func:`scan_tables`), a scan costs two or three word
reads and a trailing or leading zero count, however long the street it runs along. North-south scans use a
transposed copy (the grid's columns as bit rows).

The bit grids are padded like ``gridsearch``'s (one blocked cell round the map, added while packing); bits past a
row's end are set (blocked), so every scan ends inside its row.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core.extending import intrinsic

_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
_ONE = np.uint64(1)


@intrinsic
def trailing_zeros(typingctx, x):
    """Count of trailing zero bits of a nonzero ``uint64`` (LLVM ``cttz``)."""
    if x != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 1))

    return types.uint64(types.uint64), codegen


@intrinsic
def leading_zeros(typingctx, x):
    """Count of leading zero bits of a nonzero ``uint64`` (LLVM ``ctlz``)."""
    if x != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        return builder.ctlz(args[0], ir.Constant(ir.IntType(1), 1))

    return types.uint64(types.uint64), codegen


@njit(cache=True)
def pack_rows(grid):
    """The grid with a blocked border, as bits: ``(n + 2, ceil((m + 2) / 64))`` uint64 for an ``(n, m)`` bool grid.

    Bit ``k`` of word ``w`` in row ``r`` is padded cell ``(r, 64 w + k)``, i.e. grid cell ``(r - 1, 64 w + k - 1)``;
    the border and the bits past the row's end are set (blocked).
    """
    n, m = grid.shape
    words = (m + 2 + 63) // 64
    out = np.full((n + 2, words), _ALL)
    for i in range(n):
        for w in range(words):
            word = np.uint64(0)
            for k in range(64):
                c = 64 * w + k
                if c == 0 or c > m or grid[i, c - 1]:
                    word |= _ONE << np.uint64(k)
            out[i + 1, w] = word
    return out


@njit(cache=True)
def pack_columns(grid):
    """The transposed bits, border included: ``(m + 2, ceil((n + 2) / 64))`` uint64, row ``c`` holding padded
    column ``c``."""
    n, m = grid.shape
    words = (n + 2 + 63) // 64
    out = np.full((m + 2, words), _ALL)
    for w in range(words):  # 64 padded rows at a time, read column by column (they stay in cache)
        for j in range(m):
            word = np.uint64(0)
            for k in range(64):
                r = 64 * w + k
                if r == 0 or r > n or grid[r - 1, j]:
                    word |= _ONE << np.uint64(k)
            out[j + 1, w] = word
    return out


@njit(cache=True, inline="always")
def is_set(bits, row, index):
    """Bit ``index`` of bit row ``row`` (a cell blocked)."""
    return (bits[row, index >> 6] >> np.uint64(index & 63)) & _ONE != 0


@njit(cache=True, inline="always")
def _word(bits, row, w):
    """Word ``w`` of ``row``, all ones (blocked) outside it."""
    if 0 <= w < bits.shape[1]:
        return bits[row, w]
    return _ALL


@njit(cache=True)
def scan_tables(bits):
    """What the scans along the bit rows of ``bits`` need, precomputed: ``(walls, stop_up, stop_down, next_up,
    next_down)``.

    ``stop_up[r]`` has a bit at every cell where a scan towards higher indices stops: a wall, or a cell with a
    forced neighbour (``~side & side_behind`` in row ``r - 1`` or ``r + 1``); ``stop_down`` likewise towards lower
    indices. ``next_up[r, w]`` is the first word at or after ``w`` with a stop bit, ``next_down[r, w]`` the last at
    or before it (rows end in blocked padding, so there always is one). A scan then reads two or three words,
    however long the free run it crosses.
    """
    n, words = bits.shape
    stop_up = np.empty_like(bits)
    stop_down = np.empty_like(bits)
    next_up = np.empty((n, words), np.int32)
    next_down = np.empty((n, words), np.int32)
    for r in range(n):
        for w in range(words):
            here = bits[r, w]
            if r == 0 or r == n - 1:  # padding rows: never scanned along
                stop_up[r, w] = here
                stop_down[r, w] = here
                continue
            a, b = bits[r + 1, w], bits[r - 1, w]
            a_back = (a << _ONE) | (_word(bits, r + 1, w - 1) >> np.uint64(63))
            b_back = (b << _ONE) | (_word(bits, r - 1, w - 1) >> np.uint64(63))
            stop_up[r, w] = here | (~a & a_back) | (~b & b_back)
            a_back = (a >> _ONE) | (_word(bits, r + 1, w + 1) << np.uint64(63))
            b_back = (b >> _ONE) | (_word(bits, r - 1, w + 1) << np.uint64(63))
            stop_down[r, w] = here | (~a & a_back) | (~b & b_back)
        following = words - 1
        for w in range(words - 1, -1, -1):
            if stop_up[r, w] != 0:
                following = w
            next_up[r, w] = following
        preceding = 0
        for w in range(words):
            if stop_down[r, w] != 0:
                preceding = w
            next_down[r, w] = preceding
    return bits, stop_up, stop_down, next_up, next_down


@njit(cache=True, inline="always")
def scan_up(tables, row, start, target):
    """First index ``x > start`` along bit row ``row`` where a scan towards higher indices stops: ``x`` if it is
    ``target`` or has a forced neighbour in row ``row - 1`` or ``row + 1``; ``-1`` if a blocked cell comes first.
    ``target`` is -1 when the goal is not in this row. ``tables`` is :func:`scan_tables` of the bit grid."""
    walls, stop_up, _, next_up, _ = tables
    x0 = start + 1
    w = x0 >> 6
    word = stop_up[row, w] & (_ALL << np.uint64(x0 & 63))
    if word == 0:
        w = next_up[row, w + 1]
        word = stop_up[row, w]
    x = 64 * w + np.int64(trailing_zeros(word))
    if start < target <= x:
        return target
    if (walls[row, x >> 6] >> np.uint64(x & 63)) & _ONE:
        return -1
    return x


@njit(cache=True, inline="always")
def scan_down(tables, row, start, target):
    """As :func:`scan_up` towards lower indices: the first ``x < start`` where the scan stops, or -1 at a wall."""
    walls, _, stop_down, _, next_down = tables
    x0 = start - 1
    w = x0 >> 6
    word = stop_down[row, w] & (_ALL >> np.uint64(63 - (x0 & 63)))
    if word == 0:
        w = next_down[row, w - 1]
        word = stop_down[row, w]
    x = 64 * w + np.int64(np.uint64(63) - leading_zeros(word))
    if x <= target < start:
        return target
    if (walls[row, x >> 6] >> np.uint64(x & 63)) & _ONE:
        return -1
    return x
