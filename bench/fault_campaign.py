"""Fault campaign: random missions on the SF map flown by the real CLI against ``python -m sim --strict`` with faults.

Each random mission (a free start and a reachable goal 150-800 m apart) is flown twice, each time by a fresh sim
and a fresh client process: once with no fault (the baseline) and once with the next fault mix of the rotation:

- ``loss10``: 10 % packet loss each way
- ``latency200``: 200 ms latency each way
- ``outage3``: a 3 s outage mid-flight (the socket stays open; everything is dropped)

- ``loss5_latency100_wind``: 5 % loss, 100 ms latency, 4 m/s wind with 1 m/s gusts

(latencies and the outage in wall-clock time, as the client meets them: the sim gets them times its speed-up, so
at speed-up 5 the vehicle meets 200 ms as a second each way). Two more mixes, outside the default rotation
(``--mixes``): ``latency100``, ``sensor_noise_dropout`` (0.3 m range noise, 20 % of the sectors lost), and
``gps1`` / ``gps2`` (the position estimate off the truth by a Gauss-Markov drift of 1 or 2 m deviation and 10 s
correlation: harsher than the sim's default 60 s), ``storm``: all at once, moderately (5.8 m/s wind with 2 m/s
gusts, 10 % loss, 100 ms latency, the noisy sensor, ``gps1``), and ``gale``: a 13 m/s wind with 3 m/s gusts, most of
what a 30 degree tilt limit (ArduCopter's default) can hold against.
With ``--walls N`` each mission is flown in a changed city, N tall walls across the route the map gives it
(``skyroute.cityedit``; the sim's truth, the client keeps the map), baseline and fault flight alike.

The sim's report is the truth: completion (exit 0 and landed), landing error (sim touchdown to the goal, with a
local WGS84 approximation written here), collisions, minimum clearance, airborne time (simulated seconds, against
the same mission's baseline; the client never flies faster than it can stop within what its sensor has seen,
counting the link's round trip, so latency costs time: ~1.3-1.4x for ``latency200`` at speed-up 5), and whether
the client's logs are complete (a navigation log that ends with the outcome, a tlog). One JSON document and a table.

    python bench/fault_campaign.py                       # 10 missions x 2 flights, SF map, speed-up 5
    python bench/fault_campaign.py --missions 4 --map colliders.csv --out /tmp/campaign.json
    python bench/fault_campaign.py --autopilot ardupilot  # the same against the ArduPilot personality
    python bench/fault_campaign.py --walls 3 --mixes latency100 sensor_noise_dropout --autopilot ardupilot
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from skyroute.cityedit import walls_across_route  # noqa: E402
from skyroute.citygen import write_colliders  # noqa: E402
from skyroute.cli.exits import UserError  # noqa: E402
from skyroute.cli.setting import check_endpoint, load_setting, make_plan  # noqa: E402
from skyroute.maps import read_colliders  # noqa: E402
from skyroute.planning.errors import PlanningError  # noqa: E402
from tests.geodesy import distance_m  # noqa: E402 (the campaign's own WGS84, not the client's)
from tests.geodesy import ned_to_latlon as to_latlon  # noqa: E402

ALT_M, SAFETY_M = 5.0, 5.0
MIXES = {
    "loss10": ["--packet-loss", "10"],
    "latency200": ["--latency", "200"],
    "outage3": [],  # --outage T,3 with T mid-flight, per mission
    "loss5_latency100_wind": ["--packet-loss", "5", "--latency", "100", "--wind", "3,-2.6", "--gust", "1"],
    # not in the default rotation (--mixes): they matter most where the sensor finds what the map lacks (--walls)
    "latency100": ["--latency", "100"],
    # a poor radio link: acks go missing (a command whose effect the heartbeat shows is taken as done)
    "loss30": ["--packet-loss", "30"],
    "sensor_noise_dropout": ["--sensor-noise", "0.3", "--sensor-dropout", "20"],
    # the position estimate wanders off the truth (a drift of this many metres' deviation, 10 s correlation), the
    # vehicle flies the estimate: only the scans, matched against the map, tell the client how far off it is
    "gps1": ["--gps-noise", "1", "--gps-correlation", "10"],
    "gps2": ["--gps-noise", "2", "--gps-correlation", "10"],
    # everything at once, moderately: wind with gusts, a lossy slow link, a noisy sensor, a wandering estimate
    "storm": ["--wind", "5,3", "--gust", "2", "--packet-loss", "10", "--latency", "100", "--sensor-noise", "0.3",
              "--sensor-dropout", "20", "--gps-noise", "1", "--gps-correlation", "10"],
    # a gale: 13 m/s with 3 m/s gusts takes most of the tilt ArduCopter's default ANGLE_MAX (30 degrees) allows
    "gale": ["--wind", "11,-7", "--gust", "3"],
}
DEFAULT_MIXES = ["loss10", "latency200", "outage3", "loss5_latency100_wind"]


def default_map() -> Path:
    shared = Path(os.environ["SKYROUTE_SHARED"]) if os.environ.get("SKYROUTE_SHARED") else ROOT.parent / "shared"
    sf = shared / "maps" / "udacity_sf_colliders.csv"
    return sf if sf.exists() else ROOT / "colliders.csv"


def pick_missions(map_path: Path, count: int, seed: int) -> list[dict]:
    """``count`` (start, goal) pairs: free at ground level and at the flight altitude, 150-800 m apart, planned."""
    setting = load_setting(map_path, ALT_M, SAFETY_M)
    rng = np.random.default_rng(seed)
    grid = setting.grid_map
    n, m = grid.grid.shape
    out: list[dict] = []
    while len(out) < count:
        (i0, j0), (i1, j1) = rng.integers(0, (n, m), size=(2, 2))
        if grid.grid[i0, j0] or grid.grid[i1, j1]:
            continue
        if setting.landing_point((i0, j0))[1] or setting.landing_point((i1, j1))[1]:
            continue  # starts and goals in a street, clear of every building's margin, however low
        start, goal = grid.centre_of((i0, j0)), grid.centre_of((i1, j1))
        if not 150.0 <= math.dist(start, goal) <= 800.0:
            continue
        try:
            check_endpoint(setting, "goal", *goal)
            plan = make_plan(setting, start, goal)
        except UserError:
            continue  # unreachable: the campaign counts only missions with a reachable goal
        length = float(np.linalg.norm(np.diff(plan.waypoints[:, :2], axis=0), axis=1).sum())
        out.append({"start_ne": [float(v) for v in start], "goal_ne": [float(v) for v in goal],
                    "planned_m": length})
    lat0, lon0 = setting.home.lat_deg, setting.home.lon_deg
    for mission in out:
        mission["start"] = to_latlon(*mission["start_ne"], lat0, lon0)
        mission["goal"] = to_latlon(*mission["goal_ne"], lat0, lon0)
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def sim_fault_time_is_simulated() -> bool:
    """The sim's link faults run on its clock (its help says "in simulated time") or on the wall clock."""
    text = subprocess.run([sys.executable, "-m", "sim", "--help"], cwd=ROOT, capture_output=True, text=True).stdout
    return "simulated time" in " ".join(text.split())


def changed_city(map_path: Path, mission: dict, walls: int, seed: int, out: Path) -> Path | None:
    """Write a copy of the map with ``walls`` tall walls across the route the map gives ``mission`` (the sim's
    truth; the client keeps the map) to ``out``; None when no draw leaves the goal reachable or the route has too
    little straight street (``skyroute.cityedit.walls_across_route``)."""
    city = read_colliders(map_path)
    try:
        change = walls_across_route(city.obstacles, mission["start_ne"], mission["goal_ne"], altitude_m=ALT_M,
                                    safety_m=SAFETY_M, count=walls, seed=seed)
    except (PlanningError, ValueError):
        return None
    write_colliders(out, change.obstacles, city.lat0_deg, city.lon0_deg)
    return out


def fly_once(mission: dict, mix: str, *, map_path: Path, speedup: float, seed: int, workdir: Path,
             simulated_faults: bool, autopilot: str = "px4", truth_path: Path | None = None) -> dict:
    port = free_port()
    report_path = workdir / "report.json"
    # The mixes are what a real link does in real time. A sim whose faults run on its own clock at speed-up N
    # must delay by N x 200 ms and stay silent N x 3 s of its time for the client (on the wall clock) to meet
    # 200 ms and 3 s; its link-loss timeouts are scaled by N too (--scale-timeouts), as PX4 SITL's are.
    scale = speedup if simulated_faults else 1.0
    faults = list(MIXES.get(mix, []))
    for k, arg in enumerate(faults[:-1]):
        if arg == "--latency":
            faults[k + 1] = f"{float(faults[k + 1]) * scale:g}"
    if mix == "outage3":
        # mid-flight: after the boot, the readiness wait and the takeoff (~15 s simulated), 40 % into the legs
        flight_s = 15.0 + 0.4 * mission["planned_m"] / 7.0
        start_s = flight_s if simulated_faults else flight_s / speedup + 1.5
        faults += ["--outage", f"{start_s:.1f},{3.0 * scale:g}"]
    if simulated_faults:
        faults.append("--scale-timeouts")
    lat, lon = mission["start"]
    sim_cmd = [sys.executable, "-m", "sim", "--map", str(truth_path or map_path), "--port", str(port), "--strict",
               "--speedup",
               f"{speedup:g}", "--start", f"{lat:.8f},{lon:.8f}", "--report", str(report_path), "--seed",
               str(seed), "--autopilot", autopilot, "-q", *faults]
    sim = subprocess.Popen(sim_cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                           start_new_session=True)
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            if sim.poll() is not None:
                raise RuntimeError(f"sim exited: {sim.stderr.read()}")
            time.sleep(0.1)
        glat, glon = mission["goal"]
        client_cmd = [sys.executable, str(ROOT / "motion_planning.py"), "--map", str(map_path), "--goal_lat",
                      f"{glat:.9f}", "--goal_lon", f"{glon:.9f}", "--alt", f"{ALT_M:g}", "--safety", f"{SAFETY_M:g}",
                      "--connection", f"tcp:127.0.0.1:{port}", "--timeout", "20", "--log-dir", str(workdir / "logs"),
                      "-q"]
        started = time.monotonic()
        client = subprocess.run(client_cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
        wall_s = time.monotonic() - started
    finally:
        if sim.poll() is None:
            os.killpg(sim.pid, signal.SIGINT)
            try:
                sim.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(sim.pid, signal.SIGKILL)
                sim.wait()
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    landed = report.get("landed")
    error_m = distance_m(landed["lat_deg"], landed["lon_deg"], glat, glon) if landed else math.nan
    navlogs = sorted((workdir / "logs").glob("navlog-*.txt"))
    tlogs = sorted((workdir / "logs").glob("flight-*.tlog"))
    nav_text = navlogs[-1].read_text(encoding="utf-8") if navlogs else ""
    logs_complete = bool(nav_text) and ("DISARMING --DISARMED--> MANUAL" in nav_text or "landed" in nav_text
                                        or "LINK_TIMEOUT" in nav_text) and bool(tlogs) and tlogs[-1].stat().st_size > 0
    final = report.get("final", {})
    return {
        "mix": mix, "exit": client.returncode, "completed": client.returncode == 0 and landed is not None,
        "landing_error_m": error_m, "collisions": len(report.get("collisions", [])),
        "min_clearance_m": report.get("min_clearance_m"), "airborne_s": report.get("airborne_time_s"),
        "down_and_disarmed": bool(final.get("on_ground")) and not final.get("armed"),
        "logs_complete": logs_complete, "wall_s": round(wall_s, 1),
        "client_error": client.stderr.strip().splitlines()[-1] if client.returncode else "",
        "recoveries": nav_text.count("--LINK_LOST--> RECOVERING") + nav_text.count("--CONTROL_LOST--> RECOVERING"),
    }


def summarize(flights: list[dict]) -> str:
    rows = ["| mix | flights | completed | landing error median / max (m) | collisions | min clearance (m) | "
            "airborne vs baseline | recoveries | logs complete |", "|---|---|---|---|---|---|---|---|---|"]
    base = {f["mission"]: f for f in flights if f["mix"] == "none"}
    for mix in ["none", *MIXES]:
        group = [f for f in flights if f["mix"] == mix]
        if not group:
            continue
        errors = [f["landing_error_m"] for f in group if math.isfinite(f["landing_error_m"])]
        clearances = [f["min_clearance_m"] for f in group if f["min_clearance_m"] is not None]
        ratios = [f["airborne_s"] / base[f["mission"]]["airborne_s"] for f in group
                  if mix != "none" and f["completed"] and base.get(f["mission"], {}).get("airborne_s")]
        rows.append(
            f"| {mix} | {len(group)} | {sum(f['completed'] for f in group)}/{len(group)} | "
            f"{statistics.median(errors) if errors else math.nan:.2f} / {max(errors, default=math.nan):.2f} | "
            f"{sum(f['collisions'] for f in group)} | {min(clearances, default=math.nan):.2f} | "
            f"{'-' if not ratios else f'{statistics.median(ratios):.2f} (max {max(ratios):.2f})'} | "
            f"{sum(f['recoveries'] for f in group)} | {sum(f['logs_complete'] for f in group)}/{len(group)} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--missions", type=int, default=10, help="random missions (each flown twice)")
    parser.add_argument("--map", type=Path, default=default_map(), help="colliders.csv (default: the SF map)")
    parser.add_argument("--speedup", type=float, default=5.0, help="the sim's speed-up")
    parser.add_argument("--seed", type=int, default=1, help="seed for the missions and the sims")
    parser.add_argument("--mixes", nargs="+", default=DEFAULT_MIXES, choices=list(MIXES),
                        help="fault mixes to rotate")
    parser.add_argument("--walls", type=int, default=0,
                        help="fly each mission in a changed city: this many tall walls across the map's route (the "
                             "sim's truth; the client keeps the map); missions where no draw fits are skipped")
    parser.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                        help="the sim's personality (conventions, parameters, sensor messages)")
    parser.add_argument("--out", type=Path, default=None, help="write the flights as JSON here")
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep every flight's changed city, report and client logs under this directory")
    args = parser.parse_args(argv)
    simulated = sim_fault_time_is_simulated()
    print(f"map {args.map}, {args.autopilot} personality, speed-up {args.speedup:g}, link faults in "
          f"{'simulated' if simulated else 'wall-clock'} time", flush=True)
    missions = pick_missions(args.map, args.missions, args.seed)
    flights = []
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    with contextlib.nullcontext(str(args.keep)) if args.keep else tempfile.TemporaryDirectory(
            prefix="skyroute-campaign-") as tmp:
        for k, mission in enumerate(missions):
            truth = None
            if args.walls:
                truth = changed_city(args.map, mission, args.walls, args.seed + k, Path(tmp) / f"city-{k:03d}.csv")
                if truth is None:
                    print(f"mission {k} skipped: no {args.walls} walls across its route leave the goal reachable",
                          flush=True)
                    continue
            for mix in ("none", args.mixes[k % len(args.mixes)]):
                workdir = Path(tmp) / f"{k:03d}-{mix}"
                workdir.mkdir(exist_ok=True)
                flight = fly_once(mission, mix, map_path=args.map, speedup=args.speedup, seed=args.seed + k,
                                  workdir=workdir, simulated_faults=simulated, autopilot=args.autopilot,
                                  truth_path=truth)
                flight.update(mission=k, planned_m=round(mission["planned_m"], 1))
                flights.append(flight)
                print(f"mission {k} {mix:22s} exit {flight['exit']} landing error {flight['landing_error_m']:.2f} m "
                      f"collisions {flight['collisions']} airborne {flight['airborne_s']} s wall {flight['wall_s']} s "
                      f"{flight['client_error']}", flush=True)
    print(summarize(flights))
    if args.out:
        args.out.write_text(json.dumps({"missions": missions, "flights": flights}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
