"""Scale benchmark: generate a big city with citygen, rasterise it at 1 m and plan corner to corner.

    python bench/bench_scale.py [--size-m 5000] [--seed 5] [--method jps]

Reports wall times for each stage and the process's peak resident memory (``resource.getrusage`` maxrss,
which includes numba's allocations that tracemalloc cannot see). The issue's target for a 5 km city:
plan < 2 s, peak memory < 2 GB.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, in MiB (Linux reports KiB, macOS bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10


def nearest_free(grid: np.ndarray, cell: tuple[int, int]) -> tuple[int, int]:
    """Nearest free cell (True = blocked grid), searching square rings outwards; no O(grid) work."""
    n, m = grid.shape
    for r in range(max(n, m)):
        i0, i1, j0, j1 = max(cell[0] - r, 0), min(cell[0] + r, n - 1), max(cell[1] - r, 0), min(cell[1] + r, m - 1)
        ii, jj = np.nonzero(np.logical_not(grid[i0 : i1 + 1, j0 : j1 + 1]))
        if ii.size:
            d = (ii + i0 - cell[0]) ** 2 + (jj + j0 - cell[1]) ** 2
            k = int(np.argmin(d))
            return int(ii[k] + i0), int(jj[k] + j0)
    raise ValueError("the grid has no free cell")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size-m", type=float, default=5000.0, help="city side in metres (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=5, help="citygen seed (default: %(default)s)")
    parser.add_argument("--altitude-m", type=float, default=5.0, help="drone altitude (default: %(default)s)")
    parser.add_argument("--safety-m", type=float, default=5.0, help="safety distance (default: %(default)s)")
    parser.add_argument("--method", default=None, help="GridPlanner method, e.g. jps or astar (default: its own)")
    parser.add_argument("--repeat", type=int, default=3, help="timed plans after the first (default: %(default)s)")
    args = parser.parse_args(argv)

    sys.path.insert(0, str(REPO))  # a checkout works without installing; an installed project wins anyway
    import planning_utils as pu
    from skyroute import citygen

    rss0 = peak_rss_mb()
    t0 = time.perf_counter()
    city = citygen.generate_city(size_m=args.size_m, seed=args.seed)
    gen_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    grid, north_offset, east_offset = pu.create_grid(city, args.altitude_m, args.safety_m)
    grid_s = time.perf_counter() - t0
    grid = np.asarray(grid, dtype=bool)
    print(f"city {args.size_m:g} m, seed {args.seed}: {len(city)} boxes, generated in {gen_s:.2f} s")
    print(f"create_grid: {grid.shape[0]} x {grid.shape[1]} cells ({grid.size / 1e6:.1f} M, "
          f"{100 * grid.mean():.1f}% blocked) in {grid_s:.2f} s")

    n, m = grid.shape
    start = nearest_free(grid, (int(0.02 * n), int(0.02 * m)))
    goal = nearest_free(grid, (int(0.98 * n), int(0.98 * m)))
    straight = np.hypot(goal[0] - start[0], goal[1] - start[1])
    print(f"query: start {start} -> goal {goal} (straight line {straight:.0f} cells)")

    t0 = time.perf_counter()
    planner = pu.GridPlanner(grid) if args.method is None else pu.GridPlanner(grid, method=args.method)
    setup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    path = planner.plan(start, goal)
    first_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        path = planner.plan(start, goal)
        times.append(time.perf_counter() - t0)
    print(f"GridPlanner(): {1e3 * setup_s:.0f} ms; first plan (incl. JIT cache load) {first_s:.2f} s; "
          f"plan median {np.median(times) if times else first_s:.3f} s over {len(times)}")
    print(f"path: cost {path.cost:.1f} cells, {len(path.cells)} cells, {path.expanded} expanded")
    print(f"peak RSS {peak_rss_mb():.0f} MiB (after imports {rss0:.0f} MiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
