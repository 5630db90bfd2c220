"""Compiled search kernels for the non-grid planners: a binary heap, Lazy Theta* and A* over a CSR roadmap.

* :func:`lazy_theta_star` is any-angle search on the occupancy grid (Nash, Koenig & Tovey 2010): A* over the
  8-connected cells where a node's parent may be any cell it can see, so paths are not restricted to 45-degree
  steps. "Line of sight" is the supercover walk of ``kernels.walk_supercover`` (every cell the segment between
  two cell centres touches is free), the same test that checks every planner's legs, so each returned leg is
  collision-free by construction. Lazy: line of sight is checked once per expansion, not once per neighbour.
* :func:`roadmap_astar` is A* over a graph in CSR form (``indptr``, ``indices``, ``weights``) with per-query
  virtual start and goal nodes, so the medial-axis and Voronoi roadmaps are built once and queried without
  copying them.
* Both use the heap of ``kernels`` (``heap_push`` / ``heap_pop`` on three parallel arrays ``f, g, node``);
  among equal ``f`` the larger ``g`` pops first.

Grid convention as in ``cspace``: ``bool`` grid, True = blocked, indexed ``grid[north_idx, east_idx]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from skyroute.planning import kernels

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
# Lazy Theta*


@njit(cache=True)
def lazy_theta_star(grid, si, sj, gi, gj):
    """Any-angle path on ``grid`` from cell ``(si, sj)`` to ``(gi, gj)`` (both free, on the grid).

    Returns ``(cells, cost, expanded)``: the turning cells ``(K, 2)`` from start to goal, every consecutive pair
    mutually visible, the path length in cells (= metres at 1 m) and the number of expansions; ``cells`` is empty
    and ``cost`` is -1 when the goal is unreachable. Moves between neighbours follow the grid planner's graph
    (8-connected, no diagonal past a blocked orthogonal cell), so Theta* finds a path whenever the grid planner
    does.

    A wall across rows 0-3 of column 2; the route turns once, at the free cell next to the wall's end, in one
    straight leg each way (an 8-connected path would need 45-degree steps):

    >>> grid = np.zeros((6, 5), dtype=np.bool_)
    >>> grid[0:4, 2] = True
    >>> cells, cost, expanded = lazy_theta_star(grid, 0, 0, 0, 4)
    >>> cells.tolist()
    [[0, 0], [4, 1], [4, 3], [0, 4]]
    >>> round(float(cost), 3) == round(2 * math.hypot(4, 1) + 2, 3)
    True
    """
    n, m = grid.shape
    size = n * m
    g_cost = np.full(size, np.inf)
    parent = np.full(size, -1, np.int64)
    closed = np.zeros(size, np.bool_)
    start, goal = si * m + sj, gi * m + gj
    di = np.array([1, -1, 0, 0, 1, 1, -1, -1])
    dj = np.array([0, 0, 1, -1, 1, -1, 1, -1])
    hf, hg, hv = kernels.new_heap()
    g_cost[start] = 0.0
    parent[start] = start
    hf, hg, hv, hsize = kernels.heap_push(hf, hg, hv, 0, math.hypot(si - gi, sj - gj), 0.0, start)
    expanded = 0
    while hsize > 0:
        v, fv, gv, hsize = kernels.heap_pop(hf, hg, hv, hsize)
        if closed[v] or gv > g_cost[v]:
            continue
        vi, vj = v // m, v % m
        p = parent[v]
        if p != v and not visible(grid, p // m, p % m, vi, vj):
            # Lazy step: the assumed parent cannot see v; fall back to the best closed neighbour.
            best, best_parent = np.inf, -1
            for k in range(8):
                wi, wj = vi + di[k], vj + dj[k]
                if not (0 <= wi < n and 0 <= wj < m) or not closed[wi * m + wj]:
                    continue
                if k >= 4 and (grid[vi + di[k], vj] or grid[vi, vj + dj[k]]):
                    continue
                c = g_cost[wi * m + wj] + (SQRT2 if k >= 4 else 1.0)
                if c < best:
                    best, best_parent = c, wi * m + wj
            g_cost[v], parent[v] = best, best_parent
            gv = best
        closed[v] = True
        expanded += 1
        if v == goal:
            break
        p = parent[v]
        pi, pj = p // m, p % m
        for k in range(8):
            wi, wj = vi + di[k], vj + dj[k]
            if not (0 <= wi < n and 0 <= wj < m) or grid[wi, wj]:
                continue
            w = wi * m + wj
            if closed[w]:
                continue
            if k >= 4 and (grid[vi + di[k], vj] or grid[vi, vj + dj[k]]):
                continue
            # Path 2 of Theta*: straight from v's parent, assuming line of sight (checked when w is expanded).
            gw = g_cost[p] + math.hypot(wi - pi, wj - pj)
            if gw < g_cost[w]:
                g_cost[w], parent[w] = gw, p
                hf, hg, hv, hsize = kernels.heap_push(hf, hg, hv, hsize, gw + math.hypot(wi - gi, wj - gj), gw, w)
    if not closed[goal]:
        return np.empty((0, 2), np.int64), -1.0, expanded
    count = 1
    v = goal
    while v != start:
        v = parent[v]
        count += 1
    cells = np.empty((count, 2), np.int64)
    v = goal
    for k in range(count - 1, -1, -1):
        cells[k, 0], cells[k, 1] = v // m, v % m
        v = parent[v]
    return cells, g_cost[goal], expanded


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
