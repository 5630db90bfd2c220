"""Issue 11's held-out check: the client, given only the SF map, flies SF cities with tall walls across its route.

    python bench/heldout_replan.py [--missions 5] [--walls 3] [--seed 11] [--speedup 5] [--planner grid]
                                   [--autopilot px4|ardupilot]

For each mission (start and goal free at 5 m with a 5 m margin, 300-700 m apart, drawn with ``--seed``),
``skyroute.cityedit`` puts ``--walls`` 30 m walls across the route the grid planner takes on the SF map, keeping a
detour. Then two flights of the real command line (``motion_planning.py --connection ...``) against
``python -m sim --strict --speedup 5`` flying in the changed city (the truth; PX4 personality unless
``--autopilot ardupilot``: its 45 degree DISTANCE_SENSOR sectors instead of OBSTACLE_DISTANCE):

* **stale**: the client is given only the SF map (it must sense the walls and replan);
* **true**: the same client given the changed city itself (the yardstick for the airborne time).

The sim's report is the independent monitor. A mission passes when the stale flight exits 0, lands within 1 m
of the goal, has 0 collisions, keeps >= 3.5 m clearance to the true boxes, and its airborne time is at most 1.5x
the true-map flight's. Exit code 0 when every mission passes.
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

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from skyroute import sfmap  # noqa: E402
from skyroute.cityedit import walls_across_route  # noqa: E402
from skyroute.citygen import write_colliders  # noqa: E402
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic  # noqa: E402
from skyroute.maps import read_colliders  # noqa: E402
from skyroute.planning.errors import PlanningError  # noqa: E402
from skyroute.planning.grid import GridMap  # noqa: E402

ALT_M, SAFETY_M = 5.0, 5.0
LANDING_M, CLEARANCE_M, TIME_RATIO = 1.0, 3.5, 1.5


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def fly(truth_map: Path, client_map: Path, start: Geodetic, goal: Geodetic, workdir: Path, *, speedup: float,
        planner: str, extra: list[str] | None = None, timeout_s: float = 600.0, autopilot: str = "px4") -> dict:
    """One flight of the CLI against a fresh sim in ``truth_map``: ``{exit, report, stdout, stderr, wall_s}``."""
    port = free_port()
    report = workdir / f"report-{port}.json"
    sim_cmd = [sys.executable, "-m", "sim", "--map", str(truth_map), "--port", str(port), "--speedup", f"{speedup:g}",
               "--strict", "--origin", "boot", "--report", str(report), "--start",
               f"{start.lat_deg:.8f},{start.lon_deg:.8f}", "--autopilot", autopilot, "-q"]
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
        cmd = [sys.executable, "motion_planning.py", "--connection", f"tcp:127.0.0.1:{port}", "--map",
               str(client_map), "--goal_lat", f"{goal.lat_deg:.8f}", "--goal_lon", f"{goal.lon_deg:.8f}",
               "--alt", f"{ALT_M:g}", "--safety", f"{SAFETY_M:g}", "--planner", planner, "--log-dir",
               str(workdir / "logs"), *(extra or [])]
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
    return {"exit": client.returncode, "report": json.loads(report.read_text()), "stdout": client.stdout,
            "stderr": client.stderr, "wall_s": wall_s}


def verdict(stale: dict, true: dict, goal_ne) -> tuple[bool, dict]:
    r = stale["report"]
    landed = r.get("landed")
    landing_m = math.hypot(landed["north_m"] - goal_ne[0], landed["east_m"] - goal_ne[1]) if landed else math.inf
    clearance = r.get("min_clearance_m")
    clearance = -math.inf if clearance is None else clearance
    ratio = r["airborne_time_s"] / max(true["report"]["airborne_time_s"], 1e-9)
    row = {"exit": stale["exit"], "landing_m": landing_m, "collisions": len(r["collisions"]),
           "clearance_m": clearance, "airborne_s": r["airborne_time_s"],
           "true_airborne_s": true["report"]["airborne_time_s"], "ratio": ratio,
           "replans": stale["stdout"].count("replanned") + stale["stderr"].count("replanned")}
    ok = (stale["exit"] == 0 and landing_m <= LANDING_M and row["collisions"] == 0 and clearance >= CLEARANCE_M
          and ratio <= TIME_RATIO)
    return ok, row


def missions(gm: GridMap, count: int, seed: int):
    rng = np.random.default_rng(seed)
    free = np.argwhere(~gm.grid)
    out = []
    while len(out) < count:
        a, b = free[rng.integers(len(free))], free[rng.integers(len(free))]
        start, goal = gm.centre_of(a), gm.centre_of(b)
        if not 300.0 <= math.dist(start, goal) <= 700.0:
            continue
        try:
            gm.plan(start, goal)
        except PlanningError:
            continue
        out.append(((float(start[0]), float(start[1])), (float(goal[0]), float(goal[1]))))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--map", type=Path, default=None, help="the map the client is given (default: SF)")
    p.add_argument("--missions", type=int, default=5)
    p.add_argument("--walls", type=int, default=3)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--speedup", type=float, default=5.0)
    p.add_argument("--planner", default="grid")
    p.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4", help="the sim's personality")
    p.add_argument("--keep", type=Path, default=None, help="keep the changed maps and logs here")
    args = p.parse_args(argv)
    stale_path = args.map or sfmap.local_copy()
    if stale_path is None:
        print("no SF map here: python -m skyroute.sfmap fetches it", file=sys.stderr)
        return 2
    city = read_colliders(stale_path)
    home = Geodetic(city.lat0_deg, city.lon0_deg, 0.0)
    gm = GridMap.build(city.obstacles, ALT_M, SAFETY_M)
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="heldout-"))
    workdir.mkdir(parents=True, exist_ok=True)
    rows, passed = [], 0
    for k, (start_ne, goal_ne) in enumerate(missions(gm, args.missions, args.seed)):
        try:
            change = walls_across_route(city.obstacles, start_ne, goal_ne, altitude_m=ALT_M, safety_m=SAFETY_M,
                                        count=args.walls, seed=args.seed + k)
        except (PlanningError, ValueError) as exc:  # no detour survives the walls, or too little straight street
            print(f"mission {k}: {start_ne} -> {goal_ne}: skipped ({exc})", flush=True)
            continue
        truth = workdir / f"city-{k}.csv"
        write_colliders(truth, change.obstacles, city.lat0_deg, city.lon0_deg)
        start = ned_to_geodetic(LocalNED(start_ne[0], start_ne[1], 0.0), home)
        goal = ned_to_geodetic(LocalNED(goal_ne[0], goal_ne[1], 0.0), home)
        flight = {"speedup": args.speedup, "planner": args.planner, "autopilot": args.autopilot}
        stale = fly(truth, Path(stale_path), start, goal, workdir, **flight)
        true = fly(truth, truth, start, goal, workdir, **flight)
        ok, row = verdict(stale, true, goal_ne)
        passed += ok
        row.update({"mission": k, "start": start_ne, "goal": goal_ne, "ok": ok})
        rows.append(row)
        print(f"mission {k}: {start_ne} -> {goal_ne}: exit {row['exit']}, landed {row['landing_m']:.2f} m from the "
              f"goal, {row['collisions']} collisions, clearance {row['clearance_m']:.2f} m, airborne "
              f"{row['airborne_s']:.1f} s vs {row['true_airborne_s']:.1f} s on the true map ({row['ratio']:.2f}x): "
              f"{'PASS' if ok else 'FAIL'}", flush=True)
        if not ok:
            print("  client stderr: " + stale["stderr"].strip().replace("\n", "\n  "), flush=True)
    print(f"{passed}/{len(rows)} missions pass (landing <= {LANDING_M:g} m, 0 collisions, clearance >= "
          f"{CLEARANCE_M:g} m, airborne <= {TIME_RATIO:g}x the true map's); maps and logs in {workdir}")
    (workdir / "results.json").write_text(json.dumps(rows, indent=2, default=float))
    return 0 if passed == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
