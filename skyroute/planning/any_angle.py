"""Compiled kernels for the non-grid planners: line of sight, the any-angle string puller, A* over a roadmap.

* :func:`taut_path` turns an 8-connected grid route into an any-angle one: after line-of-sight pruning, every turn
  of the route is slid to the nearby free cell (within ``radius`` cells) that most shortens its two legs while
  both stay visible, and a turn whose neighbours see each other is dropped, sweep after sweep until nothing
  changes. The result is locally shortest among cell-centre polylines in the grid route's homotopy class: it
  hugs the corners the grid route goes round, without the grid's 45-degree steps. "Visible" is the supercover
  walk of ``kernels.walk_supercover`` (every cell the segment between two cell centres touches is free), the same
  test that checks every planner's legs, so each returned leg is collision-free by construction.
* :func:`roadmap_astar` is A* over a graph in CSR form (``indptr``, ``indices``, ``weights``) with per-query
  virtual start and goal nodes, so the medial-axis and Voronoi roadmaps are built once and queried without
  copying them.
* The searches use the heap of ``kernels`` (``heap_push`` / ``heap_pop`` on three parallel arrays ``f, g, node``);
  among equal ``f`` the larger ``g`` pops first.

Grid convention as in ``cspace``: ``bool`` grid, True = blocked, indexed ``grid[north_idx, east_idx]``.
"""

from __future__ import annotations

import math

import numpy as np

from skyroute.planning import kernels
from skyroute.planning.kernels import njit

SQRT2 = math.sqrt(2.0)


# --------------------------------------------------------------------------------------------------------------
# Line of sight on the grid


@njit(cache=True)
def visible(grid, i0, j0, i1, j1):
    """True if the segment between the centres of cells ``(i0, j0)`` and ``(i1, j1)`` touches only free cells."""
    no_output = np.empty((0, 2), np.int64)
    return kernels.walk_supercover(grid, i0, j0, i1, j1, no_output) == 0


@njit(cache=True)
def segments_visible(grid, cells_a, cells_b):
    """Batch :func:`visible` over ``(E, 2)`` cell pairs, ``(E,)`` bool; cells off the grid are not visible."""
    n, m = grid.shape
    out = np.zeros(cells_a.shape[0], np.bool_)
    for k in range(cells_a.shape[0]):
        i0, j0, i1, j1 = cells_a[k, 0], cells_a[k, 1], cells_b[k, 0], cells_b[k, 1]
        if 0 <= i0 < n and 0 <= j0 < m and 0 <= i1 < n and 0 <= j1 < m:
            out[k] = visible(grid, i0, j0, i1, j1)
    return out


# --------------------------------------------------------------------------------------------------------------
# Any-angle: string pulling with sliding turns


@njit(cache=True)
def _best_turn(grid, ai, aj, ci, cj, bi, bj, radius):
    """The free cell within ``radius`` of turn ``(ci, cj)`` that both ends ``a``, ``b`` see and that makes
    ``|a c| + |c b|`` shortest (the turn itself if none is shorter by more than 1e-9 cells)."""
    n, m = grid.shape
    best = math.hypot(ci - ai, cj - aj) + math.hypot(bi - ci, bj - cj)
    best_i, best_j = ci, cj
    for di in range(-radius, radius + 1):
        for dj in range(-radius, radius + 1):
            qi, qj = ci + di, cj + dj
            if (di == 0 and dj == 0) or not (0 <= qi < n and 0 <= qj < m) or grid[qi, qj]:
                continue
            length = math.hypot(qi - ai, qj - aj) + math.hypot(bi - qi, bj - qj)
            if length < best - 1e-9 and visible(grid, ai, aj, qi, qj) and visible(grid, qi, qj, bi, bj):
                best, best_i, best_j = length, qi, qj
    return best_i, best_j


@njit(cache=True)
def taut_path(grid, cells, radius=3, max_sweeps=10_000):
    """Shorten a route of cells ``(K, 2)`` whose consecutive cells see each other; returns ``(cells, sweeps)``.

    Each sweep visits the turns in order: a turn whose neighbours see each other is dropped, otherwise it moves
    to :func:`_best_turn`. Every change shortens the route, so the sweeps end (``max_sweeps`` is a backstop); the
    first and last cells never move. Consecutive returned cells see each other.

    A wall across rows 0-3 of column 2; the 8-connected route hugs it, the taut one turns once each side of the
    wall's end, in straight legs (an 8-connected path would need 45-degree steps):

    >>> grid = np.zeros((6, 5), dtype=np.bool_)
    >>> grid[0:4, 2] = True
    >>> route = np.array([[0, 0], [1, 1], [2, 1], [3, 1], [4, 1], [4, 2], [4, 3], [3, 3], [2, 3], [1, 3], [0, 4]])
    >>> taut_path(grid, route)[0].tolist()
    [[0, 0], [4, 1], [4, 3], [0, 4]]
    """
    pts = cells.copy()
    count = pts.shape[0]
    keep = np.ones(count, np.bool_)
    sweeps = 0
    changed = True
    while changed and sweeps < max_sweeps:
        changed = False
        sweeps += 1
        prev = 0
        for k in range(1, count - 1):
            if not keep[k]:
                continue
            nxt = k + 1
            while not keep[nxt]:
                nxt += 1
            ai, aj, bi, bj = pts[prev, 0], pts[prev, 1], pts[nxt, 0], pts[nxt, 1]
            if visible(grid, ai, aj, bi, bj):
                keep[k] = False
                changed = True
                continue
            ci, cj = _best_turn(grid, ai, aj, pts[k, 0], pts[k, 1], bi, bj, radius)
            if ci != pts[k, 0] or cj != pts[k, 1]:
                pts[k, 0], pts[k, 1] = ci, cj
                changed = True
            prev = k
    return pts[keep], sweeps


# --------------------------------------------------------------------------------------------------------------
# A* over a CSR roadmap


@njit(cache=True)
def roadmap_astar(indptr, indices, weights, coords, start_nodes, start_costs, goal_costs, goal_xy, direct_cost):
    """A* over a roadmap with a virtual start and goal.

    ``coords`` ``(M, 2)`` are node positions (any unit), ``weights`` edge lengths in the same unit (never shorter
    than the straight line, so the Euclidean heuristic is admissible). The virtual start links to
    ``start_nodes`` at ``start_costs``; node ``v`` links to the virtual goal at ``goal_costs[v]`` (``inf`` = no
    link); ``direct_cost`` is a start-goal link (``inf`` if none).

    Returns ``(nodes, cost, expanded)``: the roadmap nodes between start and goal (possibly none, for the direct
    link) and the cost; ``cost`` is -1 when the goal is unreachable.
    """
    size = coords.shape[0]
    g_cost = np.full(size, np.inf)
    parent = np.full(size, -1, np.int64)
    closed = np.zeros(size, np.bool_)
    hf, hg, hv = kernels.new_heap()
    hsize = 0
    gx, gy = goal_xy[0], goal_xy[1]
    for k in range(start_nodes.shape[0]):
        v = start_nodes[k]
        if start_costs[k] < g_cost[v]:
            g_cost[v], parent[v] = start_costs[k], -1
            h = math.hypot(coords[v, 0] - gx, coords[v, 1] - gy)
            hf, hg, hv, hsize = kernels.heap_push(hf, hg, hv, hsize, start_costs[k] + h, start_costs[k], v)
    best, best_last = direct_cost, -1
    expanded = 0
    while hsize > 0:
        v, fv, gv, hsize = kernels.heap_pop(hf, hg, hv, hsize)
        if fv >= best:
            break
        if closed[v] or gv > g_cost[v]:
            continue
        closed[v] = True
        expanded += 1
        if gv + goal_costs[v] < best:
            best, best_last = gv + goal_costs[v], v
        for e in range(indptr[v], indptr[v + 1]):
            w = indices[e]
            gw = gv + weights[e]
            if closed[w] or gw >= g_cost[w]:
                continue
            g_cost[w], parent[w] = gw, v
            h = math.hypot(coords[w, 0] - gx, coords[w, 1] - gy)
            hf, hg, hv, hsize = kernels.heap_push(hf, hg, hv, hsize, gw + h, gw, w)
    if best == np.inf:
        return np.empty(0, np.int64), -1.0, expanded
    count = 0
    v = best_last
    while v >= 0:
        count += 1
        v = parent[v]
    nodes = np.empty(count, np.int64)
    v = best_last
    for k in range(count - 1, -1, -1):
        nodes[k] = v
        v = parent[v]
    return nodes, best, expanded
