"""Issue 12's acceptance run: explore SF from an empty map, collect held-out targets, come home; scored independently.

The true city is the SF map (``$SKYROUTE_SHARED/maps/``, ``../shared/maps/`` or the cache; else the bundled
``colliders.csv``); the client gets an empty map with the same home line. ``python -m sim --strict --speedup 5``
flies in the truth with ``--targets`` (held out: random reachable street points, clear of every margin, drawn by
``tests/explore_oracle.py`` from the truth); the client runs ``motion_planning.py --explore RADIUS --save-map``.
Judged from the sim's report and the saved map alone (``tests/explore_oracle.py``): every target visited (within
3 m at <= 3 m), landed within 1 m of home, disarmed, 0 collisions; the saved map's recall of the walls visible from
the reachable streets and its precision (cells within 1 m of a real building), each >= 90 %.

    python bench/explore_acceptance.py                         # radius 120 m, 3 targets (~10-15 min)
    python bench/explore_acceptance.py --radius 60 --targets 2 --keep /tmp/explore
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from skyroute import sfmap  # noqa: E402
from skyroute.citygen import write_colliders  # noqa: E402
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic  # noqa: E402
from skyroute.maps import read_colliders  # noqa: E402
from tests import explore_oracle as oracle  # noqa: E402

ALT_M, SAFETY_M = 5.0, 5.0


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def true_map() -> Path:
    found = sfmap.local_copy()
    return found if found is not None else REPO / "colliders.csv"


def run(truth: Path, workdir: Path, *, radius_m: float, targets: int, seed: int, speedup: float,
        start_ne=(0.0, 0.0), explore_time_s: float | None = None, timeout_s: float = 3000.0,
        plot: bool = True) -> dict:
    """One exploration flight and its scores."""
    city = read_colliders(truth)
    home = Geodetic(city.lat0_deg, city.lon0_deg, 0.0)
    held_out = oracle.street_targets(city.obstacles, start_ne, radius_m, ALT_M, SAFETY_M, targets, seed)
    targets_csv = workdir / "targets.csv"
    targets_csv.write_text("north_m,east_m\n" + "".join(f"{n:.2f},{e:.2f}\n" for n, e in held_out))
    empty = workdir / "empty.csv"
    write_colliders(empty, city.obstacles[:0], city.lat0_deg, city.lon0_deg)
    saved = workdir / "explored.csv"
    port = free_port()
    report_path = workdir / "report.json"
    start = ned_to_geodetic(LocalNED(start_ne[0], start_ne[1], 0.0), home)
    sim_cmd = [sys.executable, "-m", "sim", "--map", str(truth), "--port", str(port), "--speedup", f"{speedup:g}",
               "--strict", "--report", str(report_path), "--targets", str(targets_csv), "--start",
               f"{start.lat_deg:.8f},{start.lon_deg:.8f}", "-q"]
    sim = subprocess.Popen(sim_cmd, cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if time.monotonic() > deadline or sim.poll() is not None:
                    raise RuntimeError(f"the sim did not start: {sim.stderr.read().decode()[-500:]}") from None
                time.sleep(0.1)
        cmd = [sys.executable, "motion_planning.py", "--connection", f"tcp:127.0.0.1:{port}", "--map", str(empty),
               "--explore", f"{radius_m:g}", "--alt", f"{ALT_M:g}", "--safety", f"{SAFETY_M:g}", "--save-map",
               str(saved), "--log-dir", str(workdir / "logs")]
        if explore_time_s is not None:
            cmd += ["--explore-time", f"{explore_time_s:g}"]
        if plot:
            cmd += ["--plot", str(workdir / "explored.png")]
        t0 = time.monotonic()
        client = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout_s,
                                stdin=subprocess.DEVNULL)
        wall_s = time.monotonic() - t0
    finally:
        if sim.poll() is None:
            sim.send_signal(2)
            try:
                sim.wait(timeout=15)
            except subprocess.TimeoutExpired:
                sim.kill()
                sim.wait()
    report = json.loads(report_path.read_text())
    return judge(report, client, saved, city.obstacles, start_ne, radius_m, wall_s)


def judge(report: dict, client, saved: Path, true_boxes, start_ne, radius_m: float, wall_s: float) -> dict:
    landed = report.get("landed")
    home_m = math.hypot(landed["north_m"] - start_ne[0], landed["east_m"] - start_ne[1]) if landed else math.inf
    targets = report.get("targets", [])
    visited = sum(t["visited_s"] is not None for t in targets)
    row = {"exit": client.returncode, "home_m": home_m, "landed": bool(report["final"]["on_ground"]),
           "disarmed": not report["final"]["armed"], "collisions": len(report["collisions"]),
           "min_clearance_m": report.get("min_clearance_m"), "targets": len(targets), "visited": visited,
           "airborne_s": report["airborne_time_s"], "distance_m": report["distance_flown_m"], "wall_s": wall_s,
           "client_summary": [line for line in client.stdout.splitlines() if line.startswith("exploration")]}
    if saved.exists():
        boxes = read_colliders(saved, allow_empty=True).obstacles
        row.update(oracle.score_map(true_boxes, boxes, start_ne, radius_m, ALT_M, SAFETY_M))
    else:
        row.update(recall=0.0, precision=0.0)
    row["pass"] = (row["exit"] == 0 and visited == len(targets) and home_m <= 1.0 and row["landed"]
                   and row["disarmed"] and row["collisions"] == 0 and row["recall"] >= 0.9
                   and row["precision"] >= 0.9)
    if not row["pass"]:
        row["stderr"] = client.stderr[-2000:]
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--map", type=Path, default=None, help="the true city (default: SF when present)")
    p.add_argument("--radius", type=float, default=120.0)
    p.add_argument("--targets", type=int, default=3)
    p.add_argument("--seed", type=int, default=12)
    p.add_argument("--speedup", type=float, default=5.0)
    p.add_argument("--explore-time", type=float, default=None)
    p.add_argument("--keep", type=Path, default=None, help="keep the maps, logs, plot and results here")
    args = p.parse_args(argv)
    truth = args.map or true_map()
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="explore-"))
    workdir.mkdir(parents=True, exist_ok=True)
    row = run(truth, workdir, radius_m=args.radius, targets=args.targets, seed=args.seed, speedup=args.speedup,
              explore_time_s=args.explore_time)
    row["map"] = str(truth)
    print(json.dumps(row, indent=2, default=float))
    (workdir / "results.json").write_text(json.dumps(row, indent=2, default=float))
    print(f"{'PASS' if row['pass'] else 'FAIL'}; files in {workdir}")
    return 0 if row["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
