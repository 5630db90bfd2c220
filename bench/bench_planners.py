"""Benchmark every planner of ``skyroute.planning.graphs`` on the same queries of one map, in one run.

    python bench/bench_planners.py [--map PATH] [--altitude 5] [--safety 5] [--repeat 5] [--skip-reference]

For each planner and query: build time of the per-map structure (median of ``--builds`` fresh builds, after a
warm-up that compiles the numba kernels), query time (median of ``--repeat`` calls on the cached structure,
wall time of ``graphs.plan``), flown path length (3D for the 3D planners), its ratio to the yardstick,
the waypoint count, and the minimum clearance: the 3D distance from the flown legs (sampled every 0.25 m) to the
nearest obstacle box without margin.

Yardstick: the true Euclidean shortest path between the same start and goal cell centres among the padded
obstacles, as ``create_grid`` rasterises them (blocked cells, 8-connected, traced into exact polygons), from the
``extremitypathfinder`` visibility-graph package (``pip install --no-deps extremitypathfinder``: its metadata pins
numpy<2, which would downgrade the runtime, and it works on numpy 2). The 2D planners fly through cell
centres of the same grid, so their ratio is >= 1; the 3D planners may climb over obstacles, so theirs may be < 1.

Then: the PRM's failure-to-connect rate per sample count (random free query pairs the grid planner connects,
several seeds), for the roadmap alone and for the planner with its fallback, and every figure against its
target.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import planning_utils as pu  # noqa: E402
from skyroute import sfmap  # noqa: E402
from skyroute.planning import graphs as gp  # noqa: E402
from skyroute.planning import grid3d as g3  # noqa: E402
from skyroute.planning import sampling as sp  # noqa: E402

DEFAULT_MAP = sfmap.local_copy() or REPO / "colliders.csv"  # the SF map when this machine has it
# Queries as fractions of the grid shape (as in bench_grid.py); each end snaps to the nearest free cell.
QUERIES = {
    "corner": ((50 / 921, 76 / 921), (870 / 921, 870 / 921)),
    "medium-1": ((0.5, 0.15), (0.55, 0.85)),
    "medium-2": ((0.2, 0.6), (0.75, 0.3)),
    "medium-3": ((0.35, 0.35), (0.6, 0.62)),
}


# --------------------------------------------------------------------------------------------------------------
# Yardstick: blocked cells traced into polygons, shortest path by extremitypathfinder


def trace_loops(blocked: np.ndarray) -> list[np.ndarray]:
    """Boundary loops of the blocked cells as ``(K, 2)`` integer vertex arrays in ``(x=east, y=north)`` cell units.

    Each loop keeps the blocked cells on its left (islands counter-clockwise, the free region's outer boundary
    clockwise). Blocked cells that touch only at a corner are joined there (the grid planners cannot pass
    between them either). Collinear vertices are dropped.
    """
    b = np.pad(blocked, 1, constant_values=True)  # a blocked frame: off the map counts as blocked
    padded = np.pad(b, 1, constant_values=True)
    edges = []  # rows x0, y0, x1, y1 for cell (i, j) = square x in [j, j+1], y in [i, i+1]
    i, j = np.nonzero(b & ~padded[2:, 1:-1])  # free to the north: walk west along y = i + 1
    edges.append(np.column_stack([j + 1, i + 1, j, i + 1]))
    i, j = np.nonzero(b & ~padded[:-2, 1:-1])  # free to the south: walk east along y = i
    edges.append(np.column_stack([j, i, j + 1, i]))
    i, j = np.nonzero(b & ~padded[1:-1, 2:])  # free to the east: walk north along x = j + 1
    edges.append(np.column_stack([j + 1, i, j + 1, i + 1]))
    i, j = np.nonzero(b & ~padded[1:-1, :-2])  # free to the west: walk south along x = j
    edges.append(np.column_stack([j, i + 1, j, i]))
    edges = np.concatenate(edges) - 1  # frame cell (i, j) is map cell (i - 1, j - 1)
    outgoing: dict[tuple[int, int], list[int]] = {}
    for k, (x0, y0, _, _) in enumerate(edges.tolist()):
        outgoing.setdefault((x0, y0), []).append(k)
    used = np.zeros(len(edges), bool)
    loops = []
    for first in range(len(edges)):
        if used[first]:
            continue
        loop, k = [], first
        while not used[k]:
            used[k] = True
            x0, y0, x1, y1 = edges[k]
            loop.append((x0, y0))
            dx, dy = x1 - x0, y1 - y0
            candidates = [c for c in outgoing[(x1, y1)] if not used[c]] or outgoing[(x1, y1)]
            # At a saddle vertex turn left, towards the blocked side, so corner-touching cells join.
            def turn(c, dx=dx, dy=dy):
                ex, ey = edges[c, 2] - edges[c, 0], edges[c, 3] - edges[c, 1]
                cross = dx * ey - dy * ex
                return 0 if cross > 0 else (1 if cross == 0 else 2)

            k = min(candidates, key=turn)
        points = np.array(loop)
        previous, following = np.roll(points, 1, axis=0), np.roll(points, -1, axis=0)
        incoming, outgoing_leg = points - previous, following - points
        cross = incoming[:, 0] * outgoing_leg[:, 1] - incoming[:, 1] * outgoing_leg[:, 0]
        loops.append(points[cross != 0])
    return loops


def signed_area(loop: np.ndarray) -> float:
    x, y = loop[:, 0].astype(float), loop[:, 1].astype(float)
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


class Yardstick:
    """Exact shortest paths among the blocked cells of the free component around ``seed_cell``."""

    def __init__(self, grid: np.ndarray, seed_cell: tuple[int, int]):
        from extremitypathfinder import PolygonEnvironment
        from scipy import ndimage

        labels, _ = ndimage.label(np.logical_not(grid))  # 4-connected free cells
        component = labels == labels[seed_cell]
        loops = trace_loops(np.logical_not(component))
        areas = [signed_area(loop) for loop in loops]
        outer = int(np.argmin(areas))  # the free region's outer boundary: clockwise, the largest magnitude
        boundary = loops[outer][::-1]  # counter-clockwise
        holes = [loop[::-1] for k, loop in enumerate(loops) if k != outer]  # clockwise
        t0 = time.perf_counter()
        self.environment = PolygonEnvironment()
        self.environment.store(  # store() also prepares the visibility graph
            [tuple(p) for p in boundary.tolist()], [[tuple(p) for p in h.tolist()] for h in holes], validate=False
        )
        self.prepare_ms = (time.perf_counter() - t0) * 1e3
        self.component = component
        self.vertices = int(len(boundary) + sum(len(h) for h in holes))

    def length(self, start_cell, goal_cell) -> float:
        start = (start_cell[1] + 0.5, start_cell[0] + 0.5)
        goal = (goal_cell[1] + 0.5, goal_cell[0] + 0.5)
        path, length = self.environment.find_shortest_path(start, goal)
        return float(length) if path else float("nan")


# --------------------------------------------------------------------------------------------------------------
# Measurements


def min_clearance_m(points: np.ndarray, obstacles: np.ndarray, step_m: float = 0.25) -> float:
    """Smallest 3D distance from the polyline ``(K, 3)`` (sampled every ``step_m``) to any obstacle box."""
    samples = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / step_m)))
        samples.append(a + (b - a) * (np.arange(1, count + 1) / count)[:, None])
    samples = np.concatenate(samples)
    lo = obstacles[:, :3] - obstacles[:, 3:]
    hi = obstacles[:, :3] + obstacles[:, 3:]
    best = np.inf
    for chunk in np.array_split(samples, max(1, len(samples) // 256)):
        gap = np.maximum(np.maximum(lo[None] - chunk[:, None], chunk[:, None] - hi[None]), 0.0)
        best = min(best, float(np.sqrt((gap**2).sum(axis=2)).min()))
    return best


def free_queries(gmap: pu.GridMap) -> dict[str, tuple[tuple[int, int], tuple[int, int]]]:
    n, m = gmap.grid.shape
    out = {}
    for name, (a, b) in QUERIES.items():
        start = pu.nearest_free_cell(gmap.grid, (int(a[0] * n), int(a[1] * m)))
        goal = pu.nearest_free_cell(gmap.grid, (int(b[0] * n), int(b[1] * m)))
        out[name] = (start, goal)
    return out


def warm_up() -> None:
    """Compile every numba kernel on a tiny map so build and query times exclude compilation."""
    tiny = np.array([[0.5, 0.5, 0.1, 0.5, 0.5, 0.1], [10, 10, 5, 2, 2, 5], [19.5, 19.5, 0.1, 0.5, 0.5, 0.1]])
    for name in gp.PLANNERS:
        gp.plan(name, tiny, (2.5, 2.5), (17.5, 17.5), 5, 1)
    gp.clear_cache()


def median_ms(fn, repeat: int) -> tuple[float, object]:
    return timed_ms(fn, repeat)[:2]


def timed_ms(fn, repeat: int) -> tuple[float, object, float]:
    """Median time in ms of ``repeat`` calls, the last result, and the first call's time."""
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), result, times[0]


def prm_failure_rates(obstacles, gmap, altitude, safety, sample_counts, seeds, pairs, rng) -> list[tuple]:
    """For each sample count: build time (median over seeds), query times, the fraction of grid-connected pairs
    the roadmap itself misses, and the fraction the planner misses (the roadmap, then its grid3d fallback)."""
    n, m = gmap.grid.shape
    free = np.argwhere(np.logical_not(gmap.grid))
    queries = []
    while len(queries) < pairs:
        s, t = (tuple(free[k]) for k in rng.integers(0, len(free), 2))
        try:
            gmap.planner.plan(s, t)
        except pu.NoPathError:
            continue
        queries.append((gmap.centre_of(s), gmap.centre_of(t)))
    rows = []
    for count in sample_counts:
        builds, missed, failed, query_ms = [], 0, 0, []
        for seed in seeds:
            t0 = time.perf_counter()
            roadmap = sp.ProbabilisticRoadmap.build(obstacles, altitude, safety, seed=seed, n_samples=count)
            builds.append((time.perf_counter() - t0) * 1e3)
            for s, t in queries:
                t0 = time.perf_counter()
                try:
                    result = roadmap.plan(s, t)
                except pu.NoPathError:
                    failed += 1
                else:
                    missed += result.extra.get("fallback") is not None
                query_ms.append((time.perf_counter() - t0) * 1e3)
        total = len(seeds) * len(queries)
        rows.append((count, statistics.median(builds), statistics.median(query_ms), max(query_ms),
                     (missed + failed) / total, failed / total))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", type=Path, default=DEFAULT_MAP, help="colliders.csv (default: %(default)s)")
    parser.add_argument("--altitude", type=float, default=5.0, help="flight altitude in m (default: %(default)s)")
    parser.add_argument("--safety", type=float, default=5.0, help="safety margin in m (default: %(default)s)")
    parser.add_argument("--repeat", type=int, default=5, help="timed calls per query (default: %(default)s)")
    parser.add_argument("--builds", type=int, default=3, help="fresh builds per planner (default: %(default)s)")
    parser.add_argument("--prm-pairs", type=int, default=40, help="PRM rate query pairs (default: %(default)s)")
    parser.add_argument("--skip-reference", action="store_true", help="skip the extremitypathfinder yardstick")
    args = parser.parse_args(argv)

    if not args.map.exists():
        print(f"map not found: {args.map}", file=sys.stderr)
        return 2
    obstacles = pu.read_colliders(args.map).obstacles
    altitude, safety = args.altitude, args.safety
    gmap = pu.GridMap.build(obstacles, altitude, safety)
    queries = free_queries(gmap)
    print(f"map {args.map.name}: {len(obstacles)} boxes, grid {gmap.grid.shape[0]} x {gmap.grid.shape[1]}, "
          f"altitude {altitude} m, safety {safety} m, {100 * gmap.grid.mean():.1f}% blocked")
    warm_up()

    reference = {}
    if not args.skip_reference:
        try:
            import extremitypathfinder  # noqa: F401
        except ImportError:
            print("no yardstick: pip install --no-deps extremitypathfinder==2.7.2 (its metadata pins numpy<2, "
                  "which would downgrade the runtime; it runs on numpy 2), or pass --skip-reference")
            args.skip_reference = True
    if not args.skip_reference:
        yardstick = Yardstick(gmap.grid, queries["corner"][0])
        print(f"yardstick: extremitypathfinder over {yardstick.vertices} polygon vertices, "
              f"prepared in {yardstick.prepare_ms:.0f} ms")
        for name, (s, t) in queries.items():
            reference[name] = yardstick.length(s, t) if yardstick.component[t] else float("nan")

    rows = []
    for planner in gp.PLANNERS:
        options = {"seed": 0} if planner == "prm" else {}
        builds = []
        for _ in range(args.builds):
            gp.clear_cache()
            builds.append(gp.structure_for(planner, obstacles, altitude, safety, **options)[1])
        build_ms = statistics.median(builds)
        for name, (s, t) in queries.items():
            start, goal = gmap.centre_of(s), gmap.centre_of(t)
            try:
                query_ms, result, first_ms = timed_ms(
                    lambda p=planner, a=start, b=goal: gp.plan(p, obstacles, a, b, altitude, safety), args.repeat
                )
            except pu.PlanningError as exc:
                rows.append((planner, name, build_ms, float("nan"), float("nan"), float("nan"), 0, float("nan"),
                             type(exc).__name__))
                continue
            bad = gp.colliding_legs(result, obstacles, safety)
            ratio = result.length_m / reference[name] if name in reference else float("nan")
            clearance = min_clearance_m(result.waypoints[:, :3], obstacles)
            note = f"COLLIDES legs {bad}" if bad else (f"max alt {result.waypoints[:, 2].max():.0f} m"
                                                       if planner in gp.PLANNERS_3D else "")
            if planner == "grid3d":
                note += f"; first query {first_ms:.1f} ms (builds the levels it searches)"
            rows.append(
                (planner, name, build_ms, query_ms, result.length_m, ratio, len(result.waypoints), clearance, note)
            )

    header = f"{'planner':<12} {'query':<9} {'build ms':>9} {'query ms':>9} {'length m':>9} {'/ shortest':>10} " \
             f"{'waypoints':>9} {'clear m':>8}  note"
    print()
    print(header)
    print("-" * len(header))
    for planner, name, build_ms, query_ms, length, ratio, count, clearance, note in rows:
        print(f"{planner:<12} {name:<9} {build_ms:9.1f} {query_ms:9.2f} {length:9.1f} {ratio:10.4f} {count:9d} "
              f"{clearance:8.2f}  {note}")
    if reference:
        print("shortest   " + ", ".join(f"{k} {v:.1f} m" for k, v in reference.items()))

    print()
    for line in rooftop_rows(obstacles, gmap, queries["medium-3"][0], altitude, safety, args.repeat):
        print(line)

    rng = np.random.default_rng(0)
    prm_rows = prm_failure_rates(
        obstacles, gmap, altitude, safety, (250, 500, 1000, 2000), (0, 1, 2), args.prm_pairs, rng
    )
    print()
    print(f"PRM over {args.prm_pairs} random grid-connected pairs x 3 seeds (k = 10, altitude band "
          f"{altitude}-{altitude + 20} m)")
    print(f"{'samples':>8} {'build ms':>9} {'query ms':>9} {'max q ms':>9} {'roadmap misses':>15} "
          f"{'planner fails':>14}")
    for count, build_ms, query_ms, max_query, missed, failed in prm_rows:
        print(f"{count:8d} {build_ms:9.1f} {query_ms:9.2f} {max_query:9.2f} {missed:15.3f} {failed:14.3f}")
    print("(roadmap misses: pairs the random roadmap alone does not connect; the planner then falls back to the "
          "complete grid3d search, so it fails only where no route exists)")

    print()
    print("targets (before = the project's figure before this version, same machine class)")
    for line in targets(rows, prm_rows, reference):
        print("  " + line)
    return 0


def rooftop_rows(obstacles, gmap, start_cell, altitude, safety, repeat) -> list[str]:
    """The 3D planners to a rooftop: the building 15-40 m tall, at least 10 x 10 m, nearest the medium-3 goal;
    the goal altitude is the lowest free one over its centre cell (roof plus margin)."""
    n, m = gmap.grid.shape
    near = np.array(gmap.centre_of((int(0.6 * n), int(0.62 * m))))
    top = obstacles[:, 2] + obstacles[:, 5]
    roofs = np.flatnonzero((top > 15) & (top < 40) & (obstacles[:, 3] >= 5) & (obstacles[:, 4] >= 5))
    if not len(roofs):
        return ["rooftop: no building 15-40 m tall and 10 x 10 m on this map"]
    k = roofs[np.argmin(np.hypot(*(obstacles[roofs, :2] - near).T))]
    floor, north_offset, east_offset = g3.floor_map(obstacles, safety)
    goal = tuple(obstacles[k, :2])
    goal_alt = float(floor[pu.map_to_cell(goal[0], goal[1], north_offset, east_offset)])
    start = gmap.centre_of(start_cell)
    lines = [f"rooftop: from {start} at {altitude} m to the roof of box {k} (top {top[k]:.1f} m) at "
             f"({goal[0]:.1f}, {goal[1]:.1f}), goal altitude {goal_alt:.1f} m"]
    for planner in gp.PLANNERS_3D:
        try:
            def query(planner=planner):
                return gp.plan(planner, obstacles, start, goal, altitude, safety, goal_alt_m=goal_alt)

            query_ms, result = median_ms(query, repeat)
        except pu.PlanningError as exc:
            lines.append(f"  {planner:<8} {type(exc).__name__}: {exc}")
            continue
        bad = gp.colliding_legs(result, obstacles, safety)
        lines.append(f"  {planner:<8} query {query_ms:7.1f} ms, length {result.length_m:7.1f} m, "
                     f"{len(result.waypoints)} waypoints, ends at {result.waypoints[-1, 2]:.1f} m, "
                     f"clearance {min_clearance_m(result.waypoints[:, :3], obstacles):.2f} m"
                     + (f", COLLIDES legs {bad}" if bad else ""))
    return lines


def targets(rows, prm_rows, reference) -> list[str]:
    """Each measured figure against what it must meet (and what it was before)."""
    by = {}
    for planner, name, build_ms, query_ms, length, ratio, *_ in rows:
        by.setdefault(planner, []).append((name, build_ms, query_ms, length, ratio))
    lines = []

    def verdict(ok: bool) -> str:
        return "MET" if ok else "NOT MET"

    corner = {planner: dict((q[0], q) for q in queries)["corner"] for planner, queries in by.items()}
    grid3d_ms = corner["grid3d"][2]
    lines.append(f"{verdict(grid3d_ms <= 100)}: grid3d corner query <= 100 ms: {grid3d_ms:.1f} ms (before 855 ms)")
    any_ms = corner["any-angle"][2]
    lines.append(f"{verdict(any_ms <= 30)}: any-angle corner query <= 30 ms: {any_ms:.1f} ms (before 315 ms)")
    if reference:
        ratios = [r for _, _, _, _, r in by["any-angle"]]
        lines.append(f"{verdict(max(ratios) <= 1.02)}: any-angle within 1.02x of the shortest path on every query "
                     f"(max {max(ratios):.4f})")
    shorter = all(a[3] <= g[3] + 1e-9 for a, g in zip(by["any-angle"], by["grid"]))
    lines.append(f"{verdict(shorter)}: any-angle no longer than the pruned 8-connected optimum on every query")
    for planner in ("voronoi", "medial-axis"):
        build = by[planner][0][1]
        worst = max(q for _, _, q, _, _ in by[planner])
        lines.append(f"{verdict(build < 2000 and worst < 100)}: {planner} build < 2 s ({build:.0f} ms), "
                     f"query < 100 ms (worst {worst:.1f} ms)")
    thousand = [r for r in prm_rows if r[0] == 1000][0]
    lines.append(f"{verdict(thousand[5] == 0)}: prm 1000 samples fails 0% of grid-connected pairs: "
                 f"{100 * thousand[5]:.1f}% (the roadmap alone misses {100 * thousand[4]:.1f}%; before 6.7%)")
    lines.append(f"{verdict(thousand[1] < 2000)}: prm 1000 samples build < 2 s ({thousand[1]:.0f} ms), worst query "
                 f"{thousand[3]:.1f} ms")
    climbs = [(a[0], a[3], g[3]) for a, g in zip(by["grid3d"], by["grid"]) if a[3] < g[3]]
    lines.append(f"{verdict(bool(climbs))}: grid3d shorter than the 2D plan at the same altitude on "
                 + (", ".join(f"{n} ({a:.0f} vs {g:.0f} m)" for n, a, g in climbs) or "no query"))
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
