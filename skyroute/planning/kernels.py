"""Compiled grid search kernels: A*, jump point search (JPS) and the supercover line walk.

Everything here works on a *padded, flattened* grid: the occupancy grid gets a one-cell blocked border and is
raveled, so a cell is one integer ``v = (i + 1) * width + (j + 1)`` and its neighbours are ``v +/- 1`` (east/west)
and ``v +/- width`` (north/south). The border means no bounds checks in the loops. ``search.GridPlanner``
owns the padding and the workspace; this module holds only the loops, compiled by numba (``cache=True``: the
machine code is stored on disk, so only the very first run pays the compile time).

Graph: 8-connected, straight cost 1, diagonal cost sqrt(2), a diagonal step only when both orthogonal cells it
passes are free. Both searches return optimal costs on that graph:

* :func:`astar` is the textbook algorithm with the octile heuristic (exact on an empty grid, consistent).
* :func:`jps` is A* that skips symmetric paths (Harabor & Grastien 2011, the variant without corner cutting):
  it only pushes "jump points" where an optimal path may turn, and scans the straight and diagonal runs between
  them without touching the heap. Same optimal cost, far fewer heap operations on city maps.

Workspace arrays ``g_cost``, ``parent``, ``seen`` and ``closed`` are reused across queries: ``seen[v] == query``
marks ``g_cost[v]``/``parent[v]`` valid for this query and ``closed[v] == query`` marks ``v`` expanded, so a
query touches only the cells it explores.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

SQRT2 = math.sqrt(2.0)


@njit(cache=True, inline="always")
def _octile(i, j, gi, gj):
    """Cost of the cheapest 8-connected path on an empty grid: the heuristic, and the cost of a JPS jump."""
    di = abs(i - gi)
    dj = abs(j - gj)
    return (SQRT2 - 1.0) * min(di, dj) + max(di, dj)


# ---------------------------------------------------------------------------------------------------------------
# Binary min-heap of (f, g, node) in three parallel arrays (shared with any_angle and grid3d),
# ordered by f then by larger g: among equal f the deeper node goes first,
# which finishes straight runs instead of fanning out. Stale entries are skipped on pop.


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


# ---------------------------------------------------------------------------------------------------------------
# A*


@njit(cache=True)
def astar(blocked, width, start, goal, query, g_cost, parent, seen, closed):
    """Textbook A* from flat cell ``start`` to ``goal``; returns ``(cost, expanded)``, cost < 0 if unreachable."""
    gi, gj = goal // width, goal % width
    # Neighbour offsets: 4 straight moves, then 4 diagonals as (north step, east step) pairs.
    d_north = np.array([width, -width, 0, 0, width, width, -width, -width])
    d_east = np.array([0, 0, 1, -1, 1, -1, 1, -1])
    hf, hg, hv = new_heap()
    g_cost[start], parent[start], seen[start] = 0.0, -1, query
    hf, hg, hv, size = heap_push(hf, hg, hv, 0, _octile(start // width, start % width, gi, gj), 0.0, start)
    expanded = 0
    while size > 0:
        v, _, gv, size = heap_pop(hf, hg, hv, size)
        if closed[v] == query or gv > g_cost[v]:
            continue  # a stale duplicate
        closed[v] = query
        expanded += 1
        if v == goal:
            return gv, expanded
        for n in range(8):
            w = v + d_north[n] + d_east[n]
            if blocked[w] or closed[w] == query:
                continue
            step = 1.0
            if n >= 4:  # diagonal: both orthogonal cells must be free (no corner cutting)
                if blocked[v + d_north[n]] or blocked[v + d_east[n]]:
                    continue
                step = SQRT2
            gw = gv + step
            if seen[w] == query and gw >= g_cost[w]:
                continue
            seen[w], g_cost[w], parent[w] = query, gw, v
            hf, hg, hv, size = heap_push(hf, hg, hv, size, gw + _octile(w // width, w % width, gi, gj), gw, w)
    return -1.0, expanded


# ---------------------------------------------------------------------------------------------------------------
# Jump point search


@njit(cache=True)
def _jump_straight(blocked, v, step, side, goal):
    """Scan from ``v`` along ``step`` (+-1 or +-width); return the first jump point, or -1 at a wall.

    A cell is a jump point when it is the goal or has a *forced* neighbour: a free side cell whose cell behind
    is blocked, so the side cell cannot be reached as cheaply by a diagonal that skips the current cell.
    """
    while True:
        v += step
        if blocked[v]:
            return -1
        if v == goal:
            return v
        if (not blocked[v + side] and blocked[v - step + side]) or (
            not blocked[v - side] and blocked[v - step - side]
        ):
            return v


@njit(cache=True)
def _jump_diagonal(blocked, v, step_n, step_e, goal):
    """Scan diagonally from ``v``; a cell is a jump point when it is the goal or a straight scan from it finds one."""
    while True:
        if blocked[v + step_n] or blocked[v + step_e]:
            return -1  # would cut a corner
        v += step_n + step_e
        if blocked[v]:
            return -1
        if v == goal:
            return v
        if (_jump_straight(blocked, v, step_n, step_e, goal) >= 0
                or _jump_straight(blocked, v, step_e, step_n, goal) >= 0):
            return v


@njit(cache=True)
def jps(blocked, width, start, goal, query, g_cost, parent, seen, closed):
    """Jump point search from flat cell ``start`` to ``goal``; returns ``(cost, expanded jump points)``.

    ``parent`` links consecutive jump points, which always lie on one straight or diagonal line; expand them
    with :func:`trace_path`.
    """
    gi, gj = goal // width, goal % width
    hf, hg, hv = new_heap()
    g_cost[start], parent[start], seen[start] = 0.0, -1, query
    hf, hg, hv, size = heap_push(hf, hg, hv, 0, _octile(start // width, start % width, gi, gj), 0.0, start)
    expanded = 0
    dirs_n = np.empty(8, np.int64)  # candidate directions at this node as (north, east) unit steps
    dirs_e = np.empty(8, np.int64)
    while size > 0:
        v, _, gv, size = heap_pop(hf, hg, hv, size)
        if closed[v] == query or gv > g_cost[v]:
            continue
        closed[v] = query
        expanded += 1
        if v == goal:
            return gv, expanded
        vi, vj = v // width, v % width
        p = parent[v]
        count = 0
        if p < 0:  # the start: every direction
            for a in range(-1, 2):
                for b in range(-1, 2):
                    if a != 0 or b != 0:
                        dirs_n[count], dirs_e[count] = a, b
                        count += 1
        else:
            a = np.sign(vi - p // width)
            b = np.sign(vj - p % width)
            if a != 0 and b != 0:  # arrived diagonally: continue diagonally or along either component
                dirs_n[0], dirs_e[0] = a, b
                dirs_n[1], dirs_e[1] = a, 0
                dirs_n[2], dirs_e[2] = 0, b
                count = 3
            elif a != 0:  # arrived northwards/southwards: ahead, both sides, and the diagonals between
                dirs_n[0], dirs_e[0] = a, 0
                dirs_n[1], dirs_e[1] = 0, 1
                dirs_n[2], dirs_e[2] = 0, -1
                dirs_n[3], dirs_e[3] = a, 1
                dirs_n[4], dirs_e[4] = a, -1
                count = 5
            else:  # arrived eastwards/westwards
                dirs_n[0], dirs_e[0] = 0, b
                dirs_n[1], dirs_e[1] = 1, 0
                dirs_n[2], dirs_e[2] = -1, 0
                dirs_n[3], dirs_e[3] = 1, b
                dirs_n[4], dirs_e[4] = -1, b
                count = 5
        for k in range(count):
            step_n, step_e = dirs_n[k] * width, dirs_e[k]
            if step_n != 0 and step_e != 0:
                w = _jump_diagonal(blocked, v, step_n, step_e, goal)
            elif step_n != 0:
                w = _jump_straight(blocked, v, step_n, 1, goal)
            else:
                w = _jump_straight(blocked, v, step_e, width, goal)
            if w < 0 or closed[w] == query:
                continue
            gw = gv + _octile(vi, vj, w // width, w % width)
            if seen[w] == query and gw >= g_cost[w]:
                continue
            seen[w], g_cost[w], parent[w] = query, gw, v
            hf, hg, hv, size = heap_push(hf, hg, hv, size, gw + _octile(w // width, w % width, gi, gj), gw, w)
    return -1.0, expanded


@functools.cache
def warm_up() -> None:
    """Load (or compile) every kernel once per process, so the first real query times only its search."""
    blocked = np.ones(16, np.bool_)
    blocked[5] = blocked[6] = False
    g, parent = np.empty(16), np.empty(16, np.int64)
    seen, closed = np.zeros(16, np.int32), np.zeros(16, np.int32)
    for search in (astar, jps):
        search(blocked, 4, 5, 6, 1, g, parent, seen, closed)
        seen[:] = closed[:] = 0
    trace_path(parent, 6, 4)
    grid = np.zeros((2, 2), np.bool_)
    walk_supercover(grid, 0, 0, 1, 1, np.empty((0, 2), np.int64))
    walk_supercover(np.zeros((1, 1), np.bool_), 0, 0, 1, 1, np.empty((4, 2), np.int64))
    prune_los_mask(grid, np.array([[0, 0], [1, 1]], np.int64))


@njit(cache=True)
def trace_path(parent, goal, width):
    """Follow ``parent`` links back from ``goal`` and fill in the straight/diagonal runs between them.

    Returns the flat cells from start to goal, one per step.
    """
    steps = 0
    v = goal
    while parent[v] >= 0:
        p = parent[v]
        steps += max(abs(v // width - p // width), abs(v % width - p % width))
        v = p
    out = np.empty(steps + 1, np.int64)
    k = steps
    v = goal
    out[k] = v
    while parent[v] >= 0:
        p = parent[v]
        step = np.sign(p // width - v // width) * width + np.sign(p % width - v % width)
        while v != p:
            v += step
            k -= 1
            out[k] = v
    return out


# ---------------------------------------------------------------------------------------------------------------
# Supercover line walk


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
