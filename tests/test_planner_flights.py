"""Every planner's route, flown end to end through the CLI against the sim in --strict mode: the sim's truth
must show no collision, a landing at the goal, and the safety margin kept (less the controller's tolerance)."""

from __future__ import annotations

from pathlib import Path

import pytest

from motion_planning import PLANNERS, main
from sim import SimConfig, Simulator
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic

ROOT = Path(__file__).resolve().parents[1]
HOME = Geodetic(37.792480, -122.397450, 0.0)
GOAL_NE = (-120.3, 130.4)  # ~240 m from home through two street corners of the project map
SAFETY_M = 5.0


@pytest.mark.flight
@pytest.mark.parametrize("planner", PLANNERS)
def test_each_planner_flies_to_the_goal_without_collision(planner, tmp_path, capsys):
    goal = ned_to_geodetic(LocalNED(*GOAL_NE, 0.0), HOME)
    config = SimConfig(map_path=ROOT / "colliders.csv", port=0, speedup=5, strict=True, origin="boot")
    # 5x, stock link timeouts: the client steers on the wall clock, and at 20x on a busy machine (the other xdist
    # worker flying SITL) a 50 ms pause was a second of the sim's flight: the voronoi route's track once came 2.2 m
    # from a building it plans 5 m from
    with Simulator(config) as sim:
        code = main([
            "--connection", f"tcp:127.0.0.1:{sim.port}", "--planner", planner,
            "--goal_lat", f"{goal.lat_deg:.9f}", "--goal_lon", f"{goal.lon_deg:.9f}",
            "--alt", "5", "--safety", str(SAFETY_M), "--log-dir", str(tmp_path), "--timeout", "10",
        ])
        report = sim.report()
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "mission complete" in out.out
    assert report["collisions"] == []
    landed = report["landed"]
    assert landed is not None and not report["final"]["armed"]
    assert abs(landed["north_m"] - GOAL_NE[0]) < 1.0 and abs(landed["east_m"] - GOAL_NE[1]) < 1.0
    assert report["min_clearance_m"] >= SAFETY_M - 1.0


@pytest.mark.flight
def test_grid3d_lands_on_a_rooftop(tmp_path, capsys):
    # The project map's 10 x 10 m building segment centred at N 20, E -18 has its roof at 14 m; its neighbours
    # reach 16 m, so with a 5 m margin the route arrives at 21 m and the vehicle descends onto the roof.
    goal_ne, roof_m = (20.3, -17.7), 14.0
    goal = ned_to_geodetic(LocalNED(*goal_ne, 0.0), HOME)
    config = SimConfig(map_path=ROOT / "colliders.csv", port=0, speedup=20, strict=True)
    with Simulator(config) as sim:
        code = main([
            "--connection", f"tcp:127.0.0.1:{sim.port}", "--planner", "grid3d", "--goal_alt", "21",
            "--goal_lat", f"{goal.lat_deg:.9f}", "--goal_lon", f"{goal.lon_deg:.9f}",
            "--alt", "5", "--safety", str(SAFETY_M), "--log-dir", str(tmp_path), "--timeout", "10",
        ])
        report = sim.report()
    assert code == 0, capsys.readouterr().err
    assert report["collisions"] == []
    landed = report["landed"]
    assert landed["up_m"] == pytest.approx(roof_m, abs=0.2)
    assert abs(landed["north_m"] - goal_ne[0]) < 1.0 and abs(landed["east_m"] - goal_ne[1]) < 1.0
    assert not report["final"]["armed"]


@pytest.mark.flight
def test_a_slow_planner_does_not_stall_the_link(tmp_path, capsys, monkeypatch):
    # Planning happens after arming (the classic order). While a slow planner runs, our heartbeat must keep
    # reaching the autopilot: the sim's tlog records every message it receives, with wall-clock timestamps.
    import time

    from pymavlink import mavutil

    from skyroute.cli import flying as motion_planning

    real_make_plan = motion_planning.make_plan

    def slow_make_plan(*args, **kwargs):
        time.sleep(3.0)
        return real_make_plan(*args, **kwargs)

    monkeypatch.setattr(motion_planning, "make_plan", slow_make_plan)
    goal = ned_to_geodetic(LocalNED(*GOAL_NE, 0.0), HOME)
    tlog = tmp_path / "sim.tlog"
    config = SimConfig(map_path=ROOT / "colliders.csv", port=0, speedup=20, strict=True, tlog_path=tlog)
    with Simulator(config) as sim:
        code = main([
            "--connection", f"tcp:127.0.0.1:{sim.port}", "--goal_lat", f"{goal.lat_deg:.9f}",
            "--goal_lon", f"{goal.lon_deg:.9f}", "--log-dir", str(tmp_path), "--timeout", "10",
        ])
        report = sim.report()
    assert code == 0, capsys.readouterr().err
    assert report["collisions"] == [] and report["landed"] is not None
    log = mavutil.mavlink_connection(str(tlog))
    beats = []
    while (msg := log.recv_match(type="HEARTBEAT")) is not None:
        if msg.get_srcSystem() == 255:
            beats.append(msg._timestamp)
    gaps = [b - a for a, b in zip(beats[:-1], beats[1:])]
    assert len(beats) >= 5 and max(gaps) < 1.6, f"our heartbeat paused for {max(gaps):.1f} s"
