"""Compiled optimal grid searches: textbook A* and jump point search (JPS).

Both work on a *padded, flattened* grid: the occupancy grid gets a one-cell blocked border, so a cell is one
integer ``v = (i + 1) * width + (j + 1)`` and its neighbours are ``v +/- 1`` (east/west) and ``v +/- width``
(north/south). The border means no bounds checks in the loops. A* reads the padded grid as bytes; JPS reads only
its bit tables (``bits``), an eighth of the bytes and built without a padded copy. ``search.GridPlanner`` owns
both.

Graph: 8-connected, straight cost 1, diagonal cost sqrt(2), a diagonal step only when both orthogonal cells it
passes are free. Both searches return optimal costs on that graph:

* :func:`astar` is the textbook algorithm with the octile heuristic (exact on an empty grid, consistent).
* :func:`jps` is A* that skips symmetric paths (Harabor & Grastien 2011, the variant without corner cutting):
  it only pushes "jump points" where an optimal path may turn, and scans the straight and diagonal runs between
  them without touching the heap. Same optimal cost, far fewer heap operations on city maps.

Per-query state (cost, parent, expanded) lives in a hash table (``table``) that grows with the cells the search
stores, so a query's memory does not depend on the grid's size. ``max_cost`` bounds a search: it stops, as
unreachable, once every remaining path would cost at least that much (pass ``inf`` for no bound).

Each search returns ``(path, cost, expanded, slots)``: the flat cells from start to goal (one per step), the
optimal cost (-1 and an empty path if the goal is unreachable within ``max_cost``), the number of expanded nodes
and the final table capacity (the memory the query used, in entries).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from skyroute.planning.kernels.bits import is_set, scan_down, scan_up
from skyroute.planning.kernels.heap import heap_pop, heap_push, new_heap
from skyroute.planning.kernels.table import EMPTY, claim, find, new_table

SQRT2 = math.sqrt(2.0)
_FIRST_SLOTS = 256


@njit(cache=True, inline="always")
def octile(i, j, gi, gj):
    """Cost of the cheapest 8-connected path on an empty grid: the heuristic, and the cost of a JPS jump."""
    di = abs(i - gi)
    dj = abs(j - gj)
    return (SQRT2 - 1.0) * min(di, dj) + max(di, dj)


@njit(cache=True)
def _trace(keys, parent, goal, width):
    """Follow parent links from ``goal`` back to the start and fill in the straight/diagonal runs between them."""
    steps = 0
    v = goal
    p = parent[find(keys, v)]
    while p != EMPTY:
        steps += max(abs(v // width - p // width), abs(v % width - p % width))
        v = p
        p = parent[find(keys, v)]
    out = np.empty(steps + 1, np.int64)
    k = steps
    v = goal
    out[k] = v
    p = parent[find(keys, v)]
    while p != EMPTY:
        step = np.sign(p // width - v // width) * width + np.sign(p % width - v % width)
        while v != p:
            v += step
            k -= 1
            out[k] = v
        p = parent[find(keys, v)]
    return out


# ---------------------------------------------------------------------------------------------------------------
# A*


@njit(cache=True)
def astar(blocked, width, start, goal, max_cost):
    """Textbook A* from flat cell ``start`` to ``goal``: ``(path, cost, expanded, slots)``."""
    return _astar(blocked, np.empty(0), width, start, goal, max_cost)


@njit(cache=True, nogil=True)
def weighted_astar(blocked, weight, width, start, goal, max_cost):
    """A* where entering and leaving a cell costs its ``weight`` (flat like ``blocked``, every value >= 1): a
    step costs its length times the mean weight of its two cells. The octile heuristic stays admissible (weights
    >= 1), so the path is optimal for those costs: ``(path, cost, expanded, slots)`` as :func:`astar`. It releases
    the GIL: the mission runs it on a worker thread while it flies on."""
    return _astar(blocked, weight, width, start, goal, max_cost)


@njit(cache=True, nogil=True)
def _astar(blocked, weight, width, start, goal, max_cost):
    """Both of the above: ``weight`` empty for unit costs."""
    weighted = weight.shape[0] > 0
    gi, gj = goal // width, goal % width
    # Neighbour offsets: 4 straight moves, then 4 diagonals as (north step, east step) pairs.
    d_north = np.array([width, -width, 0, 0, width, width, -width, -width])
    d_east = np.array([0, 0, 1, -1, 1, -1, 1, -1])
    keys, g, parent, closed = new_table(_FIRST_SLOTS)
    keys, g, parent, closed, count, s = claim(keys, g, parent, closed, 0, start)
    g[s] = 0.0
    hf, hg, hv = new_heap()
    hf, hg, hv, size = heap_push(hf, hg, hv, 0, octile(start // width, start % width, gi, gj), 0.0, start)
    expanded = 0
    while size > 0:
        v, fv, gv, size = heap_pop(hf, hg, hv, size)
        if fv >= max_cost:
            break
        s = find(keys, v)
        if closed[s] or gv > g[s]:
            continue  # a stale duplicate
        closed[s] = True
        expanded += 1
        if v == goal:
            return _trace(keys, parent, goal, width), gv, expanded, keys.shape[0]
        for n in range(8):
            w = v + d_north[n] + d_east[n]
            if blocked[w]:
                continue
            step = 1.0
            if n >= 4:  # diagonal: both orthogonal cells must be free (no corner cutting)
                if blocked[v + d_north[n]] or blocked[v + d_east[n]]:
                    continue
                step = SQRT2
            if weighted:
                step *= 0.5 * (weight[v] + weight[w])
            gw = gv + step
            keys, g, parent, closed, count, t = claim(keys, g, parent, closed, count, w)
            if closed[t] or gw >= g[t]:
                continue
            g[t], parent[t] = gw, v
            hf, hg, hv, size = heap_push(hf, hg, hv, size, gw + octile(w // width, w % width, gi, gj), gw, w)
    return np.empty(0, np.int64), -1.0, expanded, keys.shape[0]


# ---------------------------------------------------------------------------------------------------------------
# Jump point search


@njit(cache=True, inline="always")
def _scan(rows, columns, r, c, a, b, gr, gc):
    """Jump from padded cell ``(r, c)`` one way along a row or column (``(a, b)`` a unit step, one of them 0):
    the first jump point's row and column, or ``(-1, -1)`` at a wall.

    A cell is a jump point when it is the goal or has a *forced* neighbour: a free side cell whose cell behind
    is blocked, so the side cell cannot be reached as cheaply by a diagonal that skips the current cell. The scan
    runs over the bit grids (``bits``), 64 cells a word: east-west in ``rows``, north-south in ``columns``.
    """
    if a == 0:
        target = gc if gr == r else -1
        x = scan_up(rows, r, c, target) if b > 0 else scan_down(rows, r, c, target)
        return (r, x) if x >= 0 else (-1, -1)
    target = gr if gc == c else -1
    x = scan_up(columns, c, r, target) if a > 0 else scan_down(columns, c, r, target)
    return (x, c) if x >= 0 else (-1, -1)


@njit(cache=True)
def _jump(rows, columns, width, v, a, b, goal):
    """From flat cell ``v``, the first jump point in direction ``(a, b)`` (north, east unit steps), or -1.

    Diagonally, a cell is a jump point when it is the goal or a straight scan from it (along either component)
    finds one; the diagonal never passes a blocked corner.
    """
    r, c = v // width, v % width
    gr, gc = goal // width, goal % width
    if a == 0 or b == 0:
        jr, jc = _scan(rows, columns, r, c, a, b, gr, gc)
        return -1 if jr < 0 else jr * width + jc
    walls = rows[0]
    while True:
        if is_set(walls, r + a, c) or is_set(walls, r, c + b):
            return -1  # would cut a corner
        r += a
        c += b
        if is_set(walls, r, c):
            return -1
        if r == gr and c == gc:
            return goal
        if _scan(rows, columns, r, c, a, 0, gr, gc)[0] >= 0 or _scan(rows, columns, r, c, 0, b, gr, gc)[0] >= 0:
            return r * width + c


@njit(cache=True)
def _directions(v, p, width, dirs_n, dirs_e):
    """Fill the (north, east) unit steps JPS scans from ``v`` reached from ``p`` (-1 = the start); their count."""
    if p < 0:  # the start: every direction
        count = 0
        for a in range(-1, 2):
            for b in range(-1, 2):
                if a != 0 or b != 0:
                    dirs_n[count], dirs_e[count] = a, b
                    count += 1
        return count
    a = np.sign(v // width - p // width)
    b = np.sign(v % width - p % width)
    if a != 0 and b != 0:  # arrived diagonally: continue diagonally or along either component
        dirs_n[0], dirs_e[0] = a, b
        dirs_n[1], dirs_e[1] = a, 0
        dirs_n[2], dirs_e[2] = 0, b
        return 3
    if a != 0:  # arrived northwards/southwards: ahead, both sides, and the diagonals between
        dirs_n[0], dirs_e[0] = a, 0
        dirs_n[1], dirs_e[1] = 0, 1
        dirs_n[2], dirs_e[2] = 0, -1
        dirs_n[3], dirs_e[3] = a, 1
        dirs_n[4], dirs_e[4] = a, -1
        return 5
    dirs_n[0], dirs_e[0] = 0, b  # arrived eastwards/westwards
    dirs_n[1], dirs_e[1] = 1, 0
    dirs_n[2], dirs_e[2] = -1, 0
    dirs_n[3], dirs_e[3] = 1, b
    dirs_n[4], dirs_e[4] = -1, b
    return 5


@njit(cache=True)
def jps(rows, columns, width, start, goal, max_cost):
    """Jump point search from flat cell ``start`` to ``goal``: ``(path, cost, expanded jump points, slots)``.

    ``rows`` and ``columns`` are the scan tables of the padded grid as bits (``bits.scan_tables`` of
    ``bits.pack_rows(grid)`` and of ``bits.pack_columns(grid)``); the search reads nothing else of the grid.
    Flat cells are those of the padded grid, ``width`` its row length. Parent links join consecutive jump points,
    which always lie on one straight or diagonal line; the returned path fills in the cells between them.
    """
    gi, gj = goal // width, goal % width
    keys, g, parent, closed = new_table(_FIRST_SLOTS)
    keys, g, parent, closed, count, s = claim(keys, g, parent, closed, 0, start)
    g[s] = 0.0
    hf, hg, hv = new_heap()
    hf, hg, hv, size = heap_push(hf, hg, hv, 0, octile(start // width, start % width, gi, gj), 0.0, start)
    expanded = 0
    dirs_n = np.empty(8, np.int64)
    dirs_e = np.empty(8, np.int64)
    while size > 0:
        v, fv, gv, size = heap_pop(hf, hg, hv, size)
        if fv >= max_cost:
            break
        s = find(keys, v)
        if closed[s] or gv > g[s]:
            continue
        closed[s] = True
        expanded += 1
        if v == goal:
            return _trace(keys, parent, goal, width), gv, expanded, keys.shape[0]
        vi, vj = v // width, v % width
        for k in range(_directions(v, parent[s], width, dirs_n, dirs_e)):
            w = _jump(rows, columns, width, v, dirs_n[k], dirs_e[k], goal)
            if w < 0:
                continue
            gw = gv + octile(vi, vj, w // width, w % width)
            keys, g, parent, closed, count, t = claim(keys, g, parent, closed, count, w)
            if closed[t] or gw >= g[t]:
                continue
            g[t], parent[t] = gw, v
            hf, hg, hv, size = heap_push(hf, hg, hv, size, gw + octile(w // width, w % width, gi, gj), gw, w)
    return np.empty(0, np.int64), -1.0, expanded, keys.shape[0]
