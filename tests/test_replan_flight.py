"""Replanning in flight, end to end: the real command line, given only the project map (stale), against
``sim --strict`` at speed-up 5 flying in a changed city (the truth: walls the map does not show). Judged by the
sim's report (collisions, clearance to the TRUE boxes, where it landed), never by what the client says.

The changed cities come from ``skyroute.cityedit`` (walls across the route the grid planner takes on the stale
map, redrawn until a detour exists; a ring round the goal). The landing point is compared in the sim's own map
frame (its report's ``landed`` north/east), so no client frame conversion is trusted.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import motion_planning as mp
from sim import FaultConfig, write_colliders
from sim.sensors import SensorConfig
from skyroute.cityedit import enclose_goal, walls_across_route
from skyroute.flight.replanning import MAX_VIEWPOINTS
from skyroute.maps import read_colliders
from skyroute.planning.replan import Replanner

from . import test_cli_flight
from .test_cli_flight import distance_m, goal_args, to_latlon

watchdog = test_cli_flight.watchdog  # the flight tests' wall-clock budget fixture

pytestmark = pytest.mark.flight

ALT_M, SAFETY_M = 5.0, 5.0
SPEEDUP = 5.0
CLEARANCE_M = 3.5  # issue 11's bar for the track's clearance to the true boxes with a 5 m margin
GOAL_NEAR = (129.5, -57.5)  # ~170 m from home round the blocks (free at 5 m with a 5 m margin)
GOAL_NEAR_7 = (126.5, -54.5)  # the same street corner, free with a 7 m margin
README_GOAL_NE = (-300.5, 350.5)  # the README demo's goal, ~600 m through the streets
#: The drift tests' GPS correlation time (s): harsher than the sim's default (PX4 SITL's 60 s). At 60 s the README
#: route flew with no replan with the scan matching or without it (clearance 4.5-4.8 m against 3.4-3.5 m), so the
#: replan bound below would not tell the matching apart.
HARSH_GPS_CORRELATION_S = 10.0


def _stale():
    return read_colliders(mp.DEFAULT_MAP)


def _truth(tmp_path: Path, boxes: np.ndarray) -> Path:
    city = _stale()
    rows = [tuple(float(x) for x in row) for row in boxes]
    return write_colliders(tmp_path / "truth.csv", city.lat0_deg, city.lon0_deg, rows)


def _walls(tmp_path: Path, count: int, seed: int) -> tuple[Path, np.ndarray]:
    change = walls_across_route(_stale().obstacles, (0.0, 0.0), GOAL_NEAR, altitude_m=ALT_M, safety_m=SAFETY_M,
                                count=count, seed=seed)
    added = change.obstacles[len(_stale().obstacles):]
    return _truth(tmp_path, change.obstacles), added


def _fly(sim, tmp_path: Path, *args: str, goal=GOAL_NEAR) -> int:
    argv = [*goal_args(*goal), "--alt", f"{ALT_M:g}", "--safety", f"{SAFETY_M:g}",
            "--connection", f"tcp:127.0.0.1:{sim.port}", "--timeout", "5", "--log-dir", str(tmp_path / "logs"),
            "--map", str(mp.DEFAULT_MAP), *args]
    return mp.main(argv)


@pytest.fixture
def start_sim(sim_start):
    def start(truth: Path, **kwargs):
        kwargs.setdefault("strict", True)
        kwargs.setdefault("speedup", SPEEDUP)
        kwargs.setdefault("scale_timeouts", True)
        return sim_start(map_path=truth, **kwargs)

    return start


def _landed_from_goal_m(report: dict, goal) -> float:
    landed = report["landed"]
    return distance_m(landed["lat_deg"], landed["lon_deg"], *to_latlon(*goal))


def _assert_safe_and_down(report: dict) -> None:
    assert not report["collisions"] and not report["crashed"]
    assert report["min_clearance_m"] >= CLEARANCE_M
    final = report["final"]
    assert not final["armed"] and final["on_ground"]


def _navlog(tmp_path: Path) -> str:
    (nav,) = (tmp_path / "logs").glob("navlog-*.txt")
    return nav.read_text(encoding="utf-8")


@pytest.mark.parametrize("autopilot, sensor", [
    pytest.param("px4", SensorConfig(), id="px4-obstacle-distance"),
    pytest.param("px4", SensorConfig(noise_m=0.3, dropout_pct=10.0), id="px4-noise-and-10pct-dropout"),
    pytest.param("ardupilot", SensorConfig(), id="ardupilot-distance-sensor-sectors"),
])
def test_a_wall_across_the_route_is_sensed_and_flown_round_to_the_goal(start_sim, tmp_path, capsys, watchdog,
                                                                        autopilot, sensor, monkeypatch):
    watchdog(90.0)
    truth, added = _walls(tmp_path, count=1, seed=3)
    sim = start_sim(truth, autopilot=autopilot, sensor=sensor)
    plot = tmp_path / "flight.png"
    named = []  # the routes the client names to its stale-map prior as the map's own
    suspect_route = Replanner.suspect_route
    monkeypatch.setattr(Replanner, "suspect_route",
                        lambda self, route: (named.append(np.asarray(route)), suspect_route(self, route))[1])
    code = _fly(sim, tmp_path, "--plot", str(plot))
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_OK, err
    _assert_safe_and_down(report)
    assert _landed_from_goal_m(report, GOAL_NEAR) <= 1.0
    log = _navlog(tmp_path)
    assert "PATH_BLOCKED" in log and "REPLANNED" in log and "replan: path" in log
    assert "observed obstacle cells within" in log  # the flight's sensing summary names where they were
    assert "replans" in [line for line in out.splitlines() if line.startswith("mission complete:")][0]
    assert plot.stat().st_size > 0
    assert len(named) == 1  # the first plan's, from home to the goal (replans are the live layer's, not the map's)
    assert np.hypot(*named[0][0, :2]) < 5.0 and np.hypot(*(named[0][-1, :2] - GOAL_NEAR)) < 1.0
    print(f"\n{autopilot}: landed {_landed_from_goal_m(report, GOAL_NEAR):.2f} m from the goal, clearance "
          f"{report['min_clearance_m']:.2f} m, airborne {report['airborne_time_s']:.1f} s, {len(added)} wall(s)")


def test_ardupilot_sectors_see_a_wall_behind_a_streets_buildings_in_time_to_stop(start_sim, tmp_path, capsys,
                                                                                 watchdog):
    """ArduPilot's 45 degree sectors down a street read its buildings first: a wall 49 m from the start, across the
    README demo's first street, is the nearest thing in the forward sector only from ~20 m (at 10 m/s the
    vehicle needs ~25 m to stop). The client flies no faster than it can stop within what it has seen free,
    so it turns off short of the wall (it flew into it at cruise speed before)."""
    watchdog(90.0)
    route_goal = (-300.5, 350.5)  # the README demo's goal; its changed city's walls (seed 11), the first of them
    change = walls_across_route(_stale().obstacles, (0.0, 0.0), route_goal, altitude_m=ALT_M, safety_m=SAFETY_M,
                                count=3, seed=11)
    added = change.obstacles[len(_stale().obstacles):]
    first = added[np.argmin(np.hypot(added[:, 0], added[:, 1]))]
    assert 40.0 < math.hypot(first[0], first[1]) < 60.0
    truth = _truth(tmp_path, np.vstack([_stale().obstacles, first]))
    sim = start_sim(truth, autopilot="ardupilot")
    goal = (-25.5, 136.5)  # a corner of that route, beyond the wall
    code = _fly(sim, tmp_path, goal=goal)
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_OK, err
    _assert_safe_and_down(report)
    assert _landed_from_goal_m(report, goal) <= 1.0
    assert "REPLANNED" in _navlog(tmp_path)


def test_over_a_slow_link_the_vehicle_still_keeps_its_margin_from_walls_its_sectors_show_late(start_sim, tmp_path,
                                                                                             capsys, watchdog):
    """The README route's changed city (walls seed 11) against the ArduPilot personality, whose 45 degree sectors
    show a wall late, with 300 ms of latency each way in the vehicle's time: a reading arrives 0.3 s late and the
    brake 0.3 s after the answer. The sight cap counts that round trip as reaction time, so the vehicle keeps
    most of its 5 m margin; without it the same flight came within 3.6-4.0 m of a wall (5.2 m with it)."""
    watchdog(150.0)
    change = walls_across_route(_stale().obstacles, (0.0, 0.0), README_GOAL_NE, altitude_m=ALT_M,
                                safety_m=SAFETY_M, count=3, seed=11)
    sim = start_sim(_truth(tmp_path, change.obstacles), autopilot="ardupilot", faults=FaultConfig(latency_ms=300.0))
    code = _fly(sim, tmp_path, goal=README_GOAL_NE)
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_OK, err
    _assert_safe_and_down(report)
    assert report["min_clearance_m"] >= 4.5
    assert _landed_from_goal_m(report, README_GOAL_NE) <= 1.0
    print(f"\nardupilot, 300 ms each way: clearance {report['min_clearance_m']:.2f} m, airborne "
          f"{report['airborne_time_s']:.1f} s")


def test_without_replanning_the_client_flies_into_the_wall(start_sim, tmp_path, capsys, watchdog):
    """The same city with ``--no-replan``: the sensor is there, the client ignores it, the sim sees the crash (so
    the test above would fail on a client that only got lucky)."""
    watchdog(90.0)
    truth, _ = _walls(tmp_path, count=1, seed=3)
    sim = start_sim(truth)
    code = _fly(sim, tmp_path, "--no-replan")
    report = sim.stop()
    capsys.readouterr()
    assert code != mp.EXIT_OK
    assert report["collisions"] or report["min_clearance_m"] < CLEARANCE_M
    assert "PATH_BLOCKED" not in _navlog(tmp_path)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_a_goal_that_becomes_unreachable_holds_lands_at_the_nearest_safe_point_and_exits_1(start_sim, tmp_path,
                                                                                             capsys, watchdog,
                                                                                             autopilot):
    """Under ArduPilot's wide sectors the vehicle may first look from viewpoints (at most five; a closure they show
    may be an arc through free street), never under PX4's fine ones; either way it ends at the nearest safe point.
    (Here the thinnest, least certain part of the ring is the one the vehicle stopped at and looked at already.)"""
    watchdog(150.0)
    ring_m = 8.0
    truth = _truth(tmp_path, np.vstack([_stale().obstacles, enclose_goal(GOAL_NEAR, ring_m=ring_m, height_m=30.0)]))
    sim = start_sim(truth, autopilot=autopilot)
    code = _fly(sim, tmp_path)
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_FAILED
    line = [x for x in err.splitlines() if x.startswith("error:")]
    assert len(line) == 1 and ("cannot be reached" in line[0] or "blocked" in line[0]), err
    _assert_safe_and_down(report)
    # Outside the ring (8 m from the goal, 1 m thick) and its margin, but not much farther: the nearest safe point.
    landed_m = _landed_from_goal_m(report, GOAL_NEAR)
    assert ring_m + 1.0 + SAFETY_M - 1.0 <= landed_m <= ring_m + 1.0 + SAFETY_M + 6.0
    assert "GOAL_UNREACHABLE" in _navlog(tmp_path) and "holding" in out
    looks = out.count("to look at what closes the way")
    print(f"\n{autopilot}: {looks} viewpoints, landed {landed_m:.2f} m from the goal")
    assert looks == 0 if autopilot == "px4" else looks <= MAX_VIEWPOINTS


# In the SITL tests' group (one worker, one test at a time), so it never flies beside a real-time autopilot: beside
# PX4 SITL in CI (2 cores) it took 44 s of wall time instead of 27 and the ArduPilot flight came 2.35 m from a
# building (4.5-4.9 m alone, or three of it side by side).
@pytest.mark.xdist_group("sitl")
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_scan_matching_keeps_a_drifting_vehicle_on_its_route(start_sim, tmp_path, capsys, watchdog, autopilot):
    """The same drift (1.5 m, 10 s correlation), the 5 m margin, the README's 600 m route: the scans matched to the
    map's buildings measure the estimate's error, and the client flies the route where it is in truth instead of
    replanning round the map's own buildings read where the estimate puts them. PX4's 5 degree sectors are
    matched scan by scan, ArduPilot's 45 degree ones gathered over a quarter of a second. Measured on this route
    (seeds 1-6 PX4, 1-3 ArduPilot): with the matching 0-1 and 1-2 replans, clearance 3.9-5.2 and 4.2-4.5 m;
    without (``--no-scan-match``) 3-18 and 4-10 replans, clearance 3.2-3.8 and 2.5-3.6 m. The clearance of one
    flight varies with the drift's draw and the machine's load (on a 170 m route, 2.4-4.5 m with the matching,
    0.6-3.9 m without), so the replans are what this test tells apart; the clearance must keep half the margin."""
    watchdog(180.0)
    sim = start_sim(mp.DEFAULT_MAP, autopilot=autopilot, gps_noise_m=1.5, gps_correlation_s=HARSH_GPS_CORRELATION_S,
                    seed=1)
    code = _fly(sim, tmp_path, goal=README_GOAL_NE)
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_OK, err
    assert not report["collisions"] and not report["crashed"]
    assert report["min_clearance_m"] >= 0.5 * SAFETY_M, report["min_clearance_at"]
    log = _navlog(tmp_path)
    replans = log.count("replan: path")
    assert replans <= 2, out
    matched = [int(m) for m in re.findall(r"position fix: .*; (\d+) scans matched", log)]
    assert matched and matched[-1] >= 100
    print(f"\n{autopilot} with 1.5 m GPS drift, 5 m margin: clearance {report['min_clearance_m']:.2f} m, "
          f"{replans} replans, landed {_landed_from_goal_m(report, README_GOAL_NE):.2f} m from the goal, "
          f"{matched[-1]} matches")


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_gps_drift_does_not_turn_the_maps_own_streets_into_obstacles(start_sim, tmp_path, capsys, watchdog,
                                                                      autopilot):
    """The unchanged city, with the position estimate drifting 1.5 m (standard deviation, 10 s correlation) off
    the truth and the receiver saying so (GPS_RAW_INT h_acc). The scans are placed at the estimate, so the map's
    own buildings read up to metres off where the map has them; taking them for new obstacles closed the streets
    (ArduPilot: "the goal cannot be reached" on an unchanged map; PX4: dozens of replans). The client takes
    readings within three times the stated accuracy (at most 70 % of its margin) of the map's buildings for theirs.

    The autopilot flies its estimate along the route, so the vehicle itself is off it by the drift: the flight
    keeps a 7 m margin (with 5 m, a flight came within 0.8 m of a building; the client warns before arming when
    three times the stated accuracy takes more than 70 % of the margin)."""
    watchdog(120.0)
    sim = start_sim(mp.DEFAULT_MAP, autopilot=autopilot, gps_noise_m=1.5, gps_correlation_s=HARSH_GPS_CORRELATION_S,
                    seed=4)
    code = _fly(sim, tmp_path, "--safety", "7", goal=GOAL_NEAR_7)
    report = sim.stop()
    out, err = capsys.readouterr()
    assert code == mp.EXIT_OK, err
    assert not report["collisions"] and not report["crashed"]
    assert report["min_clearance_m"] >= 1.0
    assert _landed_from_goal_m(report, GOAL_NEAR_7) <= math.hypot(4.5, 4.5)  # the estimate's error: 3 sigma a side
    replans = _navlog(tmp_path).count("replan: path")
    # 0-2 as a rule; 4 in one loaded CI run, after an early match put the correction 3 m off for a second (PX4):
    # taking the map's buildings for new obstacles closed the streets with dozens
    assert replans <= 5, out
    landed_m = _landed_from_goal_m(report, GOAL_NEAR_7)
    print(f"\n{autopilot} with 1.5 m GPS drift: {replans} replans, landed {landed_m:.2f} m from the goal, "
          f"clearance {report['min_clearance_m']:.2f} m")
