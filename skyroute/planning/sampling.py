"""Probabilistic roadmap (``prm``) sampled in (north, east, altitude) over the 2.5D height map.

Build: draw uniform samples over the map's cells (at cell centres) and altitudes
``[altitude_m, altitude_m + altitude_span_m]``, keep those whose cell is free at their altitude (one vectorised
lookup in ``grid3d.floor_map``, no loop over obstacles) until ``n_samples`` nodes are kept, link each node
to its ``k`` nearest with scipy's ``cKDTree``, and keep the links that pass ``grid3d.leg_free`` (over
every cell of its 2D supercover the leg is at or above the cell's floor). The roadmap is a networkx graph
weighted by 3D length.

Query: link the start and goal to the nearest nodes they can reach by a free leg (or by a vertical leg and a
level one, for ends outside the sampled altitude band such as a rooftop), A* (networkx, Euclidean heuristic),
then string-pull with the same leg test. The roadmap is random, so it can miss a route that exists; when it
does, the query falls back to the complete ``grid3d`` search on the same height map (``extra["fallback"]``), so
"no path" means there is none. ``fallback=False`` reports the roadmap's own failures instead (``RoadmapNoPathError``,
which says to try another seed or more samples); ``bench/bench_planners.py`` measures how often that happens.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skyroute.planning import grid3d as g3
from skyroute.planning.errors import NoPathError
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import path_length

_LINK_CANDIDATES = (16, 64)


class RoadmapNoPathError(NoPathError):
    """The roadmap does not connect the start and the goal, though a path may exist (another seed or more
    samples may find it)."""

    def __init__(self, start: tuple[int, int], goal: tuple[int, int], seed: int, samples: int):
        super().__init__(start, goal, 0)
        self.args = (
            f"the {samples}-sample roadmap (seed {seed}) does not connect cell {start} to cell {goal}; try another "
            f"seed or more samples",
        )


@dataclass(frozen=True)
class ProbabilisticRoadmap:
    """A roadmap on one map, margin and base altitude.

    ``nodes`` ``(M, 3)`` rows ``[north_idx, east_idx, altitude_m]`` (cells of ``floor``); ``graph`` is a
    ``networkx.Graph`` over node indices with ``weight`` in metres.
    """

    obstacles: np.ndarray
    floor: np.ndarray
    north_offset: int
    east_offset: int
    altitude_m: float
    safety_m: float
    nodes: np.ndarray
    graph: object
    tree: object
    extra: dict
    edges: np.ndarray  # (E, 2) node index pairs, for plots

    @classmethod
    def build(
        cls,
        obstacles: np.ndarray,
        altitude_m: float,
        safety_m: float,
        *,
        seed: int = 0,
        n_samples: int = 1000,
        k: int = 10,
        altitude_span_m: float = 20.0,
    ) -> ProbabilisticRoadmap:
        """Sample ``n_samples`` free nodes (seeded) and link each to its ``k`` nearest where the leg is free."""
        import networkx as nx
        from scipy.spatial import cKDTree

        obstacles = np.asarray(obstacles, dtype=np.float64)
        floor, north_offset, east_offset = g3.floor_map(obstacles, safety_m)
        rng = np.random.default_rng(seed)
        n, m = floor.shape
        kept, drawn = [], 0
        for _ in range(50):  # bounded: a map with almost no free space yields a small roadmap
            batch = 2 * n_samples
            i = rng.integers(0, n, batch)
            j = rng.integers(0, m, batch)
            z = altitude_m + altitude_span_m * rng.random(batch)
            free = floor[i, j] <= z
            drawn += batch
            kept.append(np.column_stack([i, j, z])[free])
            if sum(len(a) for a in kept) >= n_samples:
                break
        nodes = np.concatenate(kept)[:n_samples].astype(np.float64)
        graph = nx.Graph()
        graph.add_nodes_from(range(len(nodes)))
        tree = cKDTree(nodes) if len(nodes) else None
        if len(nodes) > 1:
            _, idx = tree.query(nodes, k=min(k + 1, len(nodes)))
            a = np.repeat(np.arange(len(nodes)), idx.shape[1] - 1)
            b = idx[:, 1:].ravel()
            pairs = np.unique(np.column_stack([np.minimum(a, b), np.maximum(a, b)]), axis=0)
            pairs = pairs[pairs[:, 0] != pairs[:, 1]]
            ok = g3.legs_free(floor, nodes[pairs[:, 0]], nodes[pairs[:, 1]])
            pairs = pairs[ok]
            lengths = np.linalg.norm(nodes[pairs[:, 0]] - nodes[pairs[:, 1]], axis=1)
            graph.add_weighted_edges_from(zip(pairs[:, 0].tolist(), pairs[:, 1].tolist(), lengths.tolist()))
        extra = {
            "samples_drawn": int(drawn),
            "nodes": int(len(nodes)),
            "edges": int(graph.number_of_edges()),
            "components": int(nx.number_connected_components(graph)),
            "k": int(k),
            "seed": int(seed),
        }
        edges = np.array(list(graph.edges()), dtype=np.int64).reshape(-1, 2)
        return cls(obstacles, floor, north_offset, east_offset, float(altitude_m), float(safety_m), nodes, graph,
                   tree, extra, edges)

    def _links(self, point: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nodes ``point`` ``[i, j, z]`` reaches among its nearest, the link lengths, and each link's via point.

        A link is one free leg (via point NaN) or, failing that, two: vertical in the column of the lower end up
        to the higher end's altitude, then level (so a rooftop goal above the sampled band is reachable).
        """
        m = len(self.nodes)
        if m == 0:
            return np.empty(0, np.int64), np.empty(0), np.empty((0, 3))
        for k in _LINK_CANDIDATES:
            k = min(k, m)
            _, idx = self.tree.query(point, k=k)
            idx = np.atleast_1d(idx)
            targets = self.nodes[idx]
            here = np.repeat(point[None, :], len(idx), axis=0)
            direct = g3.legs_free(self.floor, here, targets)
            point_lower = (point[2] <= targets[:, 2])[:, None]
            via = np.where(point_lower, np.column_stack([here[:, :2], targets[:, 2]]),
                           np.column_stack([targets[:, :2], here[:, 2]]))
            lifted = ~direct & g3.legs_free(self.floor, here, via) & g3.legs_free(self.floor, via, targets)
            ok = direct | lifted
            if ok.any() or k == m:
                lengths = np.where(
                    direct,
                    np.linalg.norm(targets - here, axis=1),
                    np.linalg.norm(via - here, axis=1) + np.linalg.norm(targets - via, axis=1),
                )
                via[direct] = np.nan
                return idx[ok], lengths[ok], via[ok]
        return np.empty(0, np.int64), np.empty(0), np.empty((0, 3))

    def structure(self) -> dict:
        """Roadmap nodes ``(M, 2)`` and edges ``(E, 2, 2)`` in map metres (north, east), for plots."""
        centre = np.array([self.north_offset + 0.5, self.east_offset + 0.5])
        edges = self.edges
        return {
            "nodes": self.nodes[:, :2] + centre,
            "edges": np.stack([self.nodes[edges[:, 0], :2], self.nodes[edges[:, 1], :2]], axis=1) + centre,
        }

    def plan(
        self,
        start_ne: Sequence[float],
        goal_ne: Sequence[float],
        *,
        goal_alt_m: float | None = None,
        snap_start: bool = False,
        fallback: bool = True,
    ) -> Plan:
        """Route from ``start_ne`` at ``altitude_m`` to ``goal_ne`` at ``goal_alt_m`` (default: the same).

        If the roadmap does not connect the two, the complete ``grid3d`` search on the same height map plans the
        route (``extra["fallback"] == "grid3d"``), unless ``fallback`` is False.

        Raises ``OutsideGridError``, ``BlockedCellError``, ``NoPathError`` (no route exists), or, without
        ``fallback``, ``RoadmapNoPathError`` when the roadmap misses a route.
        """
        import networkx as nx

        goal_alt = self.altitude_m if goal_alt_m is None else float(goal_alt_m)
        start_cell, goal_cell, lead_in = g3.resolve_endpoints_3d(
            self.floor, self.north_offset, self.east_offset, self.obstacles, start_ne, goal_ne, self.altitude_m,
            goal_alt, snap_start,
        )
        t0 = time.perf_counter()
        start = np.array([start_cell[0], start_cell[1], self.altitude_m], dtype=np.float64)
        goal = np.array([goal_cell[0], goal_cell[1], goal_alt], dtype=np.float64)
        positions = {"start": start, "goal": goal}

        def position(node):
            return self.nodes[node] if isinstance(node, int) else positions[node]

        graph = self.graph
        added = ["start", "goal"]
        links = {}
        for end, point in (("start", start), ("goal", goal)):
            nodes, lengths, vias = self._links(point)
            links[end] = len(nodes)
            for v, length, via in zip(nodes.tolist(), lengths.tolist(), vias):
                if np.isnan(via[0]):
                    graph.add_edge(end, v, weight=length)
                    continue
                name = (end, v)  # the via point of this link
                positions[name] = via
                added.append(name)
                graph.add_edge(end, name, weight=float(np.linalg.norm(via - point)))
                graph.add_edge(name, v, weight=float(np.linalg.norm(self.nodes[v] - via)))
        if g3.legs_free(self.floor, start[None, :], goal[None, :])[0]:
            graph.add_edge("start", "goal", weight=float(np.linalg.norm(goal - start)))
        try:
            route = nx.astar_path(
                graph, "start", "goal", heuristic=lambda u, v: float(np.linalg.norm(position(u) - position(v))),
                weight="weight",
            )
        except (nx.NetworkXNoPath, nx.NodeNotFound):
            route = None
        finally:
            graph.remove_nodes_from(added)
        if route is None:
            if not fallback:
                raise RoadmapNoPathError(start_cell, goal_cell, self.extra["seed"], self.extra["nodes"])
            return self._fallback(start_ne, goal_ne, goal_alt_m, snap_start)
        search_ms = (time.perf_counter() - t0) * 1e3
        path = np.array([position(v) for v in route])
        path = path[np.concatenate(([True], (np.diff(path, axis=0) != 0).any(axis=1)))]  # a node on the start
        cost = path_length(path)
        pruned = path[g3.prune_mask_3d(self.floor, path)]
        points = pruned + (self.north_offset + 0.5, self.east_offset + 0.5, 0.0)
        raw = path[:, :2] + (self.north_offset + 0.5, self.east_offset + 0.5)
        if lead_in is not None:
            points = np.vstack([[lead_in[0], lead_in[1], self.altitude_m], points])
            raw = np.vstack([lead_in, raw])
        return Plan(
            planner="prm",
            waypoints=np.column_stack([points, g3.headings_3d(points)]),
            raw_path_ne=raw,
            length_m=path_length(points),
            cost_m=float(cost),
            search_ms=search_ms,
            expanded=len(route),
            extra={**self.extra, "start_links": links["start"], "goal_links": links["goal"]},
            structure=self.structure(),
        )


    def _fallback(self, start_ne, goal_ne, goal_alt_m, snap_start) -> Plan:
        """The complete search on this roadmap's height map, reported as a ``prm`` plan with ``fallback``."""
        search = g3.Grid3DPlanner(self.obstacles, self.floor, self.north_offset, self.east_offset, self.altitude_m,
                               self.safety_m)
        result = search.plan(start_ne, goal_ne, goal_alt_m=goal_alt_m, snap_start=snap_start)
        extra = {**self.extra, "fallback": "grid3d", "cruise_altitude_m": result.extra["cruise_altitude_m"]}
        return dataclasses.replace(result, planner="prm", extra=extra, structure=self.structure())


def connection_rate(
    roadmap: ProbabilisticRoadmap, queries: Sequence[tuple[Sequence[float], Sequence[float]]]
) -> float:
    """Fraction of ``queries`` (pairs of map points) that the roadmap itself connects (no fallback)."""
    connected = 0
    for start_ne, goal_ne in queries:
        try:
            roadmap.plan(start_ne, goal_ne, fallback=False)
        except NoPathError:
            continue
        connected += 1
    return connected / max(len(queries), 1)

