"""Scale benchmark: a big generated city, rasterised and searched in process, and the cold command line on it.

    python bench/bench_scale.py [--size-m 10000] [--seed 5] [--repeat 3] [--cold-runs 3]

Rows, each against its target and the figure the project measured before this version (printed as "before"):

* the cold ``--plan-only`` command line (a new process: imports, map file, grids, plan, output) on the city,
  from a free point near one corner to one near the opposite corner: wall time and the process's peak RSS
  (its ``VmHWM``, which includes numba's allocations);
* the same in process: ``create_grid`` plus one plan (``GridPlanner`` built and queried), with the previous
  square-margin ``create_grid`` (``bench/previous_cspace.py``) timed in the same run as a peer;
* the cold ``--plan-only`` command line on the SF map (if ``skyroute.sfmap`` finds a local copy) corner to
  corner.

Times are medians; the cold runs assume numba's disk cache is warm (the first run after an install compiles, and
says so). The per-planner rows (grid3d, any-angle, PRM) are in ``bench_planners.py``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from previous_cspace import create_grid_square_margin  # noqa: E402

import planning_utils as pu  # noqa: E402
from skyroute import citygen, sfmap  # noqa: E402
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic  # noqa: E402

SF_QUERY = ["--start_lat", "37.790088", "--start_lon", "-122.401634", "--goal_lat", "37.797476",
            "--goal_lon", "-122.392619"]
# (what, before, target, unit): "before" is what the project measured before this version (2 cores, same
# machine class), the target what it must meet now.
TARGETS = {
    "cli_city": ("cold --plan-only CLI on the city, corner to corner", 19.4, 4.0, "s"),
    "cli_city_rss": ("  its peak RSS", 2.7e9 / 2**30, 1.5, "GiB"),
    "in_process": ("create_grid + one plan, in process", 5.8 + 8.5, 1.5, "s"),
    "cli_sf": ("cold --plan-only CLI on SF, corner to corner", 0.80, 0.5, "s"),
}


# Runs motion_planning.py as its __main__ and, at exit, reports the process's own peak resident set size:
# VmHWM of /proc/self/status on Linux (the high-water mark of this program's memory since exec; getrusage's
# ru_maxrss would also count the benchmark process it was forked from), else ru_maxrss.
_LAUNCHER = """
import atexit, resource, runpy, sys
def _report():
    try:
        with open('/proc/self/status') as f:
            kib = next(int(line.split()[1]) for line in f if line.startswith('VmHWM:'))
    except OSError:
        kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // (1024 if sys.platform == 'darwin' else 1)
    sys.stderr.write(f'PEAK_RSS_KIB {kib}\\n')
atexit.register(_report)
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name='__main__')
"""


def corner_points(grid: np.ndarray, north_offset: int, east_offset: int) -> tuple[tuple, tuple]:
    """Free cells nearest 2% and 98% of the grid's extent (the corner-to-corner query), as map points."""
    n, m = grid.shape
    cells = [pu.nearest_free_cell(grid, (int(f * n), int(f * m))) for f in (0.02, 0.98)]
    return tuple(pu.cell_to_map(c, north_offset, east_offset) for c in cells)


def latlon_args(prefix: str, point_ne, home: Geodetic) -> list[str]:
    p = ned_to_geodetic(LocalNED(point_ne[0], point_ne[1], 0.0), home)
    return [f"--{prefix}_lat", f"{p.lat_deg:.8f}", f"--{prefix}_lon", f"{p.lon_deg:.8f}"]


def cold_cli(args: list[str], runs: int) -> tuple[float, float, str]:
    """``motion_planning.py --plan-only -q ARGS`` in fresh processes: median wall time (s), the largest peak RSS
    (GiB) and the last stdout line. The wall time includes the small launcher that measures the memory."""
    times, peaks, last = [], [], ""
    for _ in range(runs):
        t0 = time.perf_counter()
        result = subprocess.run(
            [sys.executable, "-c", _LAUNCHER, str(REPO / "motion_planning.py"), "--plan-only", "-q", *args],
            capture_output=True, text=True, check=False,
        )
        times.append(time.perf_counter() - t0)
        if result.returncode != 0:
            raise SystemExit(f"the command line failed: {result.stderr.strip()}")
        last = result.stdout.strip().splitlines()[-1]
        peaks.append(int(result.stderr.rsplit("PEAK_RSS_KIB ", 1)[1].split()[0]) / 2**20)
    return statistics.median(times), max(peaks), last


def verdict(key: str, value: float) -> str:
    what, before, target, unit = TARGETS[key]
    ok = "MET" if value <= target else "NOT MET"
    return f"{what:<52} {value:8.2f} {unit:<3}  before {before:6.2f}  target <= {target:g} {unit}  {ok}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size-m", type=float, default=10_000.0, help="city side in metres (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=5, help="citygen seed (default: %(default)s)")
    parser.add_argument("--altitude-m", type=float, default=5.0, help="drone altitude (default: %(default)s)")
    parser.add_argument("--safety-m", type=float, default=5.0, help="safety distance (default: %(default)s)")
    parser.add_argument("--repeat", type=int, default=3, help="timed in-process plans (default: %(default)s)")
    parser.add_argument("--cold-runs", type=int, default=3, help="cold CLI runs per map (default: %(default)s)")
    parser.add_argument("--skip-previous", action="store_true",
                        help="skip the previous square-margin create_grid (2.7 GB on the 10 km city)")
    args = parser.parse_args(argv)
    alt, safety = args.altitude_m, args.safety_m
    rows = []

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        city = citygen.generate_city(size_m=args.size_m, seed=args.seed)
        path = Path(tmp) / "city.csv"
        citygen.write_colliders(path, city)
        print(f"city {args.size_m:g} m, seed {args.seed}: {len(city)} boxes, generated and written in "
              f"{time.perf_counter() - t0:.1f} s")

        # In process: read, rasterise (ours and the previous implementation), build the planner, plan.
        t0 = time.perf_counter()
        obstacles = pu.read_colliders(path).obstacles
        read_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        grid, north_offset, east_offset = pu.create_grid(obstacles, alt, safety)
        grid_s = time.perf_counter() - t0
        print(f"read_colliders {read_s:.2f} s; create_grid {grid.shape[0]} x {grid.shape[1]} cells "
              f"({grid.size / 1e6:.0f} M, {100 * grid.mean():.1f}% blocked) in {grid_s:.2f} s")
        if not args.skip_previous:
            t0 = time.perf_counter()
            previous = create_grid_square_margin(obstacles, alt, safety)[0]
            previous_s = time.perf_counter() - t0
            print(f"  previous square-margin create_grid in the same run: {previous_s:.2f} s "
                  f"(x ours {previous_s / grid_s:.1f}), {100 * previous.mean():.1f}% blocked")
            del previous
        start_ne, goal_ne = corner_points(grid, north_offset, east_offset)
        t0 = time.perf_counter()
        planner = pu.GridPlanner(grid)
        build_s = time.perf_counter() - t0
        start_cell = pu.map_to_cell(*start_ne, north_offset, east_offset)
        goal_cell = pu.map_to_cell(*goal_ne, north_offset, east_offset)
        times = []
        for _ in range(max(args.repeat, 1)):
            t0 = time.perf_counter()
            path_found = planner.plan(start_cell, goal_cell)
            times.append(time.perf_counter() - t0)
        plan_s = statistics.median(times)
        print(f"GridPlanner() {build_s:.2f} s; plan {start_cell} -> {goal_cell}: median {plan_s:.2f} s over "
              f"{len(times)}, cost {path_found.cost:.1f} m, {path_found.expanded} jump points expanded, state "
              f"table {path_found.state_entries} entries")
        rows.append(verdict("in_process", grid_s + build_s + plan_s))
        del planner, grid

        # Cold command lines.
        home = Geodetic(citygen.DEFAULT_LAT0_DEG, citygen.DEFAULT_LON0_DEG, 0.0)
        query = [*latlon_args("start", start_ne, home), *latlon_args("goal", goal_ne, home)]
        wall_s, peak_gib, last = cold_cli(["--map", str(path), *query], args.cold_runs)
        print(f"cold CLI on the city: median {wall_s:.2f} s over {args.cold_runs}, peak RSS {peak_gib:.2f} GiB: "
              f"{last}")
        rows.append(verdict("cli_city", wall_s))
        rows.append(verdict("cli_city_rss", peak_gib))

    sf = sfmap.local_copy()
    if sf is None:
        print("cold CLI on SF: skipped (no local copy; python -m skyroute.sfmap fetches one)")
    else:
        wall_s, _, last = cold_cli(["--map", str(sf), *SF_QUERY], max(args.cold_runs, 5))
        print(f"cold CLI on SF: median {wall_s:.2f} s: {last}")
        rows.append(verdict("cli_sf", wall_s))

    print()
    for row in rows:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
