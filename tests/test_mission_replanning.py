"""In-flight replanning with the mission's fake vehicle: it carries a range sensor that sees the TRUE city (the
sim's own sector model), while the mission plans on a stale map. The live layer and replanner are the real ones."""

from __future__ import annotations

import math
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from sim.sensors import sector_minima
from skyroute.cityedit import enclose_goal
from skyroute.flight import mission as m
from skyroute.flight.mission import MissionEvent as E
from skyroute.flight.mission import MissionState as S
from skyroute.flight.replanning import (
    GOAL_AGAIN,
    MAX_VIEWPOINTS,
    STREAM_GRACE_S,
    Sensing,
    speed_to_stop_within_mps,
    turn_lead_in_m,
)
from skyroute.planning.cspace import create_grid
from skyroute.planning.errors import PlanningError
from skyroute.planning.grid import GridMap
from skyroute.planning.livemap import LiveMap, ScanUpdate
from skyroute.planning.pruning import line_of_sight
from skyroute.planning.replan import Blockage, GoalUnreachable, Replanner

from .test_mission import OFFSET, FakeClock, FakeVehicle, make_mission, straight_plan

ALT, SAFETY = 10.0, 3.0
#: Four 60 m blocks in a 2 x 2 grid, 20 m streets between and round them; posts fix a 200 m extent.
STALE = np.array([[n, e, 15.0, 30.0, 30.0, 15.0] for n in (-40.0, 40.0) for e in (-40.0, 40.0)]
                 + [[-99.5, -99.5, 0.5, 0.5, 0.5, 0.5], [99.5, 99.5, 0.5, 0.5, 0.5, 0.5]])
#: A wall across the central north-south street, north 19..21 (the stale map's route runs straight up it).
WALL = np.array([[20.0, 0.0, 15.0, 1.0, 12.0, 15.0]])
START, GOAL = (-85.0, 0.5), (85.0, 0.5)


class SensingVehicle(FakeVehicle):
    """The fake with a 72-sector OBSTACLE_DISTANCE-like sensor at 10 Hz of the fake clock, seeing ``truth``
    (``sectors=8``: ArduPilot's 45 degree proximity sectors, all read at once)."""

    def __init__(self, clock, truth, *, range_m=30.0, sectors=72, **kwargs):
        super().__init__(clock, **kwargs)
        lo, hi = truth[:, :3] - truth[:, 3:], truth[:, :3] + truth[:, 3:]
        self.lo, self.hi, self.top = lo[:, :2], hi[:, :2], hi[:, 2]
        self.range_m, self.sectors = range_m, sectors
        self.queue = []
        self.next_scan_s = 0.0
        self.sensing = True
        clock.tickers.append(self._scan)

    def _scan(self, dt):
        t = self.telemetry
        if self.clock.now < self.next_scan_s or t.on_ground:
            return
        self.next_scan_s = self.clock.now + 0.1
        self._take(t.north_m + OFFSET.north_m, t.east_m + OFFSET.east_m, -t.down_m)

    def _take(self, north_m, east_m, altitude_m, **stamp):
        """Queue a scan taken at the map point (the boxes reaching ``altitude_m``), with ``stamp``'s attributes."""
        tall = self.top >= altitude_m
        n = self.sectors
        d = sector_minima(self.lo[tall], self.hi[tall], north_m, east_m, n, 0.0, self.range_m)
        self.queue.append(SimpleNamespace(bearings_rad=np.radians(np.arange(0.0, 360.0, 360.0 / n)),
                                          half_width_rad=math.pi / n, distances_m=d, max_range_m=self.range_m,
                                          received_s=self.clock.now, **stamp))

    def sensor_readings(self):
        out, self.queue = self.queue, []
        return out


def _plan_fn(calls):
    gm = GridMap.build(STALE, ALT, SAFETY)

    def plan(n, e):
        calls.append((n, e))
        return gm.plan((n, e), GOAL, snap_start=True).waypoints

    return plan


def _obstacles(goal=GOAL):
    gm = GridMap.build(STALE, ALT, SAFETY)
    live = LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0])
    return Replanner(live, goal, ALT)


def _mission(vehicle, clock, obstacles, calls):
    return make_mission(vehicle, clock, _plan_fn(calls), goal_ne=GOAL, obstacles=obstacles,
                        replan_errors=(PlanningError,), replan_margin_m=SAFETY, leg_timeout_s=120.0)


def _track_clearance(track: np.ndarray, boxes: np.ndarray) -> float:
    lo, hi = boxes[:, :2] - boxes[:, 3:5], boxes[:, :2] + boxes[:, 3:5]
    pts = track[:, 1:3]
    gap = np.maximum(np.maximum(lo[None] - pts[:, None], pts[:, None] - hi[None]), 0.0)
    return float(np.hypot(gap[..., 0], gap[..., 1]).min())


def test_control_lost_while_braking_for_a_wall_is_taken_back_and_the_wall_still_flown_round(monkeypatch):
    # PX4 left OFFBOARD (a failsafe: "Failsafe activated") just as the vehicle braked for a wall: the recovery took
    # control back inside the brake, and its "resumed" escaped the flight loop as an unexpected error (exit 1 with
    # the vehicle landing where it was; found against the sim's --gps-loss at 10x)
    clock = FakeClock()
    truth = np.vstack([STALE, WALL])
    v = SensingVehicle(clock, truth, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    mission = _mission(v, clock, _obstacles(), calls=[])
    monkeypatch.setattr("skyroute.flight.replanning.can_turn_in_time", lambda *args, **kwargs: False)
    brake = mission._brake

    def brake_and_lose_control():
        if not v.calls.count("take_control"):
            v.mode, v.hint = "posctl", "the autopilot said 'Failsafe activated'"
        brake()

    mission._brake = brake_and_lose_control
    result = mission.run()
    assert result.completed and v.calls.count("take_control") == 1
    events = [e for _, e, _ in result.history]
    assert events.count(E.PATH_BLOCKED) >= 2  # the wall found again once flown on from where it stopped
    assert result.landing_error_m < 0.5
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0


def test_an_obstacle_stream_that_stops_and_comes_back_is_said_once_each_way():
    # the sensor (or its stream) dies mid-route: replanning stops with it, and the operator is told so
    clock = FakeClock()
    truth = np.vstack([STALE, WALL])
    v = SensingVehicle(clock, truth, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    lines = []
    mission = make_mission(v, clock, _plan_fn([]), goal_ne=GOAL, obstacles=_obstacles(),
                           replan_errors=(PlanningError,), replan_margin_m=SAFETY, leg_timeout_s=120.0,
                           progress=lines.append)

    def silent():
        v.sensing, v.next_scan_s = False, math.inf

    def back():
        v.sensing, v.next_scan_s = True, clock.now

    clock.at(6.0, silent)
    clock.at(12.0, back)
    result = mission.run()
    assert result.completed
    said = [line for line in lines if "obstacle sensor" in line]
    assert said == ["the obstacle sensor went silent: flying on the map alone, nothing replanned, until it streams "
                    "again", "the obstacle sensor streams again: replanning on"]
    assert result.replans  # the wall, seen once the stream was back


def test_a_silence_the_link_explains_is_not_said_to_be_the_sensors():
    clock = FakeClock()
    vehicle = SimpleNamespace(sensing=True)
    sensing = Sensing(vehicle, _obstacles(), clock)
    assert sensing.stream_change() is None  # streaming from the start: nothing to say
    vehicle.sensing = False
    assert sensing.stream_change(link_ok=False) is None  # the link is down: that explains it
    clock.sleep(5.0)
    assert sensing.stream_change() is None  # the link just back: the stream has not resumed yet
    clock.sleep(STREAM_GRACE_S - 0.5)
    assert sensing.stream_change() is None  # nor within the grace
    clock.sleep(1.0)
    assert sensing.stream_change() == "silent"  # back for longer, and still nothing
    assert sensing.stream_change() is None  # said once
    vehicle.sensing = True
    assert sensing.stream_change() == "back"


def test_a_wall_across_the_route_is_seen_and_flown_round_to_the_goal():
    clock = FakeClock()
    truth = np.vstack([STALE, WALL])
    v = SensingVehicle(clock, truth, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    mission = _mission(v, clock, _obstacles(), calls=[])
    result = mission.run()
    assert result.completed and result.final_state is S.MANUAL
    events = [e for _, e, _ in result.history]
    assert E.PATH_BLOCKED in events and E.REPLANNED in events
    i = events.index(E.PATH_BLOCKED)
    assert result.history[i][0] is S.WAYPOINT and result.history[i][2] is S.REPLANNING
    assert result.history[i + 1][1] is E.REPLANNED and result.history[i + 1][2] is S.WAYPOINT
    assert result.landing_error_m < 0.5
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0  # the fake cuts corners less than a real one
    first = result.replans[0]
    assert first.outcome == "replanned" and first.plan_ms > 0 and math.isfinite(first.latency_ms)
    if math.isnan(first.refine_ms):
        assert first.waypoints[0, :2] == pytest.approx((first.north_m, first.east_m))
    else:  # the record keeps the refined route, which starts where the vehicle was when it was taken (on its track)
        after = result.track[result.track[:, 0] >= first.time_s]
        assert np.hypot(*(after[:, 1:3] - first.waypoints[0, :2]).T).min() < 1.0
    assert len(mission.discovered_obstacles) > 0 and mission.discovered_obstacles.shape[1] == 6


class _Unsighted:
    """The real replanner without ``seen_free_m``: the mission then flies its schedule whatever it has seen."""

    def __init__(self, replanner):
        self._r = replanner

    def __getattr__(self, name):
        if name == "seen_free_m":
            raise AttributeError(name)
        return getattr(self._r, name)


@pytest.mark.parametrize("sighted", [True, False])
def test_the_vehicle_never_outruns_a_short_sensor(sighted):
    """A 10 m sensor shows a wall too late to stop from the 10 m/s cruise (a real vehicle needs ~20 m; the fake
    stops at once, so the contrast here is the speed): with the cap on what it has seen free
    (``_sight_cap_mps``) the vehicle flies no faster than it could stop within that, all the way."""
    clock = FakeClock()
    truth = np.vstack([STALE, WALL])
    v = SensingVehicle(clock, truth, range_m=10.0, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m),
                       speed_mps=10.0)
    obstacles = _obstacles() if sighted else _Unsighted(_obstacles())
    result = _mission(v, clock, obstacles, calls=[]).run()
    track = result.track
    speeds = np.hypot(*np.diff(track[:, 1:3], axis=0).T) / np.maximum(np.diff(track[:, 0]), 1e-9)
    # what braking at the mission's 3 m/s^2 allows within 10 m seen, less a cell and half the margin (streets seen
    # before from elsewhere may be seen further: the 90th percentile, not the top speed)
    cap = speed_to_stop_within_mps(10.0 - 1.2 - 0.5 * SAFETY, 3.0)
    cruise = np.percentile(speeds[speeds > 1.0], 90)
    if sighted:
        assert result.completed and result.landing_error_m < 0.5
        assert _track_clearance(track, WALL) >= 0.5 * SAFETY
        assert cruise <= cap + 0.5
    else:  # the same flight at its schedule
        assert cruise > cap + 2.0


@pytest.mark.parametrize("round_trip_s", [0.0, 0.8])
def test_a_slow_link_counts_its_round_trip_as_reaction_time(round_trip_s):
    """A reading arrives half the link's round trip late and the brake setpoint takes the other half: the sight
    cap, the braking rule and the lead-in before a turn count it as reaction time (``_reaction_s``). 10 m seen free
    ahead at 3 m/s^2, half the 3 m margin to spare: 6.3 m/s over a fast link, 4.6 m/s over a 0.8 s round trip
    (300 ms each way took an ArduPilot-personality flight to 3.4 m from a wall with a 5 m margin)."""
    clock = FakeClock()
    v = FakeVehicle(clock)
    v.sensing, v.round_trip_s = True, round_trip_s
    seen = SimpleNamespace(seen_free_m=lambda north, east, d_north, d_east, max_m: min(10.0, max_m))
    mission = make_mission(v, clock, straight_plan([]), obstacles=seen, replan_margin_m=SAFETY)
    assert mission._reaction_s() == pytest.approx(0.3 + round_trip_s)
    cap = mission._sight_cap_mps(SimpleNamespace(north_m=0.0, east_m=0.0), (1.0, 0.0))
    assert cap == pytest.approx(speed_to_stop_within_mps(10.0 - 0.5 * SAFETY, 3.0, 0.3 + round_trip_s))
    assert cap == pytest.approx(6.30 if round_trip_s == 0.0 else 4.57, abs=0.01)
    v.telemetry.local_v_north_mps = 10.0
    lead = mission._lead_in_m(np.array([10.0, 0.0]), (0.0, 0.0), _route((0.0, 0.0), (0.0, 20.0)).waypoints)
    assert lead == pytest.approx(turn_lead_in_m(10.0, math.pi / 2, 3.0, 3.0, 0.3 + round_trip_s))


def test_a_goal_at_the_edge_of_the_map_is_reached_though_nothing_beyond_the_edge_is_ever_seen():
    """The live layer ends with the map: past its edge no cell is ever seen free, so near a goal half a metre from
    the edge less space ahead is seen free than the sight cap's spare (half the 5 m margin). The vehicle still gets
    there (it stood still 1.6 m short of such a goal on SF, here 2 m, until its leg timed out)."""
    clock = FakeClock()
    goal = (99.5, 0.5)  # the posts fix the grid's north edge at 100 m
    v = SensingVehicle(clock, STALE, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    mission = make_mission(v, clock, lambda n, e: gm.plan((n, e), goal, snap_start=True).waypoints, goal_ne=goal,
                           obstacles=_obstacles(goal), replan_errors=(PlanningError,), replan_margin_m=5.0,
                           leg_timeout_s=60.0)
    result = mission.run()
    assert result.completed and result.landing_error_m < 0.5


def test_without_replanning_the_same_flight_never_looks():
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    result = _mission(v, clock, None, calls=[]).run()  # --no-replan: the fake flies through the wall
    assert E.PATH_BLOCKED not in [e for _, e, _ in result.history]
    assert _track_clearance(result.track, WALL) == 0.0 and result.replans == []


def test_a_goal_walled_in_holds_lands_at_the_nearest_reachable_safe_point_and_fails():
    clock = FakeClock()
    ring = enclose_goal(GOAL, ring_m=8.0, height_m=30.0)
    v = SensingVehicle(clock, np.vstack([STALE, ring]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    mission = _mission(v, clock, _obstacles(), calls=[])
    with pytest.raises(m.GoalUnreachableInFlight, match="cannot be reached|blocked") as info:
        mission.run()
    result = info.value.result
    events = [e for _, e, _ in result.history]
    assert E.GOAL_UNREACHABLE in events and not result.completed
    assert result.final_state is S.MANUAL and not v.telemetry.armed and v.telemetry.on_ground
    landed = result.track[-1, 1:3]
    # Outside the ring's margin, on the near side: within the ring's reach plus a few metres of the goal.
    ring_reach = 8.0 + 1.0 + SAFETY
    assert ring_reach - 0.5 <= math.dist(landed, GOAL) <= ring_reach + 6.0
    assert "instead of the goal" in str(info.value)


def test_a_wall_seen_late_at_speed_makes_the_vehicle_brake_before_it_turns():
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), range_m=12.0, speed_mps=12.0,
                       start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    result = _mission(v, clock, _obstacles(), calls=[]).run()
    assert result.completed and any(r.braked for r in result.replans)
    # every replan's latency is known: reading in -> the brake's first setpoint, or the new route's
    assert all(math.isfinite(r.latency_ms) and r.latency_ms >= 0 for r in result.replans)


@pytest.mark.parametrize("method", ["grid", "any-angle"])
def test_each_replanning_method_flies_round_the_wall_with_free_legs(method):
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = Replanner(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT, method=method)
    result = _mission(v, clock, obstacles, calls=[]).run()
    assert result.completed and result.replans
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0
    assert result.landing_error_m < 0.5
    if method == "any-angle":  # pulled taut: no turn left whose neighbours see each other (from the search's start)
        live = obstacles.live
        cells = [live.cell_of(*p) for p in result.replans[-1].waypoints[1:, :2]]
        assert len(cells) >= 3
        assert not any(line_of_sight(live.grid, a, c) for a, c in zip(cells[:-2], cells[2:]))


def test_the_command_lines_obstacle_map_serves_every_planner():
    import motion_planning as mp
    from skyroute.cli.flying import obstacle_map
    from skyroute.cli.setting import load_setting
    from skyroute.planning import PLANNERS

    setting = load_setting(mp.DEFAULT_MAP, 5.0, 5.0)
    for planner in PLANNERS:
        replanner = obstacle_map(setting, (129.5, -57.5), planner)
        assert replanner.method == ("any-angle" if planner == "any-angle" else "grid")
        route = replanner.replan((0.5, 0.5))  # nothing observed yet: the map's own route
        assert np.allclose(route.waypoints[-1, :2], (129.5, -57.5))


class _RefiningToTheOtherSide(Replanner):
    """A replanner whose prior always prefers the other outer street to the one the replan took."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.asked, self.via = [], None

    def refine_job(self, position_ne, current_ne):
        self.asked.append((tuple(position_ne), np.array(current_ne)))
        side = -1.0 if float(np.mean(np.asarray(current_ne)[:, 1])) > 0 else 1.0
        self.via = (0.5, 85.0 * side)
        first, second = self.route_to(position_ne, self.via), self.route_to(self.via, self.goal_ne)
        waypoints = np.vstack([first.waypoints, second.waypoints[1:]])
        return lambda: type(first)(waypoints, 5.0, 0.0, 0, False)


def test_a_replanned_route_is_refined_once_and_the_refined_route_is_flown():
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _RefiningToTheOtherSide(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT)
    result = _mission(v, clock, obstacles, calls=[]).run()
    assert result.completed and result.landing_error_m < 0.5
    assert len(obstacles.asked) == len(result.replans) >= 1
    # asked with the replanned route from where the vehicle turns onto it: the end of the lead-in it flies straight
    # on (north, as it was flying) to slow down for the turn into the side street, within its braking distance
    position, current = obstacles.asked[0]
    replanned_at = (result.replans[0].north_m, result.replans[0].east_m)
    assert abs(position[1] - replanned_at[1]) < 0.5 and 0.0 <= position[0] - replanned_at[0] < 7.0
    assert tuple(current[0]) == position and np.allclose(current[-1], GOAL)
    track = result.track[:, 1:3]
    assert np.hypot(*(track - obstacles.via).T).min() < 3.0  # flew the refined route, by the other side
    assert result.replans[-1].refine_ms == 5.0 and "refined under the stale-map prior" in result.replans[-1].describe()
    assert np.allclose(result.replans[-1].waypoints[-1, :2], GOAL)
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0


@pytest.mark.parametrize("where, taken", [((-20.0, 0.5), True),  # a few metres along its first leg
                                           ((1.5, 0.5), True),  # just past its first turn (2 m: under a margin)
                                           ((10.0, 0.5), False),  # well past its first turn (a slow search)
                                           ((-80.0, 40.0), False)])  # the leg back to its start cuts a block
def test_a_refined_route_is_taken_only_from_where_its_first_leg_is_clear_and_ahead(where, taken):
    """A refinement searched from (-25.5, 0.5), up the middle street to (-0.5, 0.5) then west, finishes with the
    vehicle somewhere else: it becomes the route only while its first turn is ahead (or passed by less than a
    margin) and the leg there is clear."""
    from concurrent.futures import Future

    clock = FakeClock()
    v = SensingVehicle(clock, STALE, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    mission = _mission(v, clock, Replanner(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT),
                       [])
    route = SimpleNamespace(waypoints=np.array([[-25.5, 0.5, ALT, 0.0], [-0.5, 0.5, ALT, 0.0],
                                                [-0.5, -85.0, ALT, 0.0], [85.0, -85.0, ALT, 0.0]]),
                            plan_ms=5.0, length_m=300.0)
    done = Future()
    done.set_result(route)
    mission._refining = done
    if taken:
        with pytest.raises(m._Rerouted) as rerouted:
            mission._take_refined(SimpleNamespace(north_m=where[0], east_m=where[1], altitude_m=ALT))
        assert rerouted.value.waypoints[:2, :2].tolist() == [list(where), [-0.5, 0.5]]
    else:
        mission._take_refined(SimpleNamespace(north_m=where[0], east_m=where[1], altitude_m=ALT))  # not taken


def test_a_refinement_that_comes_too_late_is_asked_for_once_more_from_where_the_vehicle_is():
    from concurrent.futures import Future

    clock = FakeClock()
    v = SensingVehicle(clock, STALE, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    asked = []

    class Asked(Replanner):
        def refine_job(self, position_ne, current_ne, **kw):
            asked.append((tuple(position_ne), np.asarray(current_ne)))
            return lambda: None

    mission = _mission(v, clock, Asked(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT), [])
    late = SimpleNamespace(waypoints=np.array([[-25.5, 0.5, ALT, 0.0], [-0.5, 0.5, ALT, 0.0],
                                               [-0.5, -85.0, ALT, 0.0], [85.0, -85.0, ALT, 0.0]]),
                           plan_ms=5.0, length_m=300.0)
    flown = np.array([[-40.5, 0.5, ALT, 0.0], [40.5, 0.5, ALT, 0.0], [85.0, -85.0, ALT, 0.0]])
    here = SimpleNamespace(north_m=10.0, east_m=0.5, altitude_m=ALT)  # 10 m past the refined route's first turn
    for _ in range(2):
        done = Future()
        done.set_result(late)
        mission._refining = done
        mission._take_refined(here, flown, 1)  # not taken
        if mission._refining is not None:
            mission._refining.result(timeout=5.0)
    assert len(asked) == 1  # once per replan, not at every poll
    assert asked[0][0] == (10.0, 0.5) and asked[0][1][:, :2].tolist() == [[10.0, 0.5], [40.5, 0.5], [85.0, -85.0]]


def test_a_refinement_overtaken_by_the_next_replan_never_runs():
    """A wall seen a piece at a time is replanned at the sensor rate, faster than a refinement runs: only the one
    running and the one for the route flown now may run, not a queue of refinements of routes given up."""
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gate, ran = threading.Event(), []

    class Slow(Replanner):
        def refine_job(self, position_ne, current_ne):
            k = len(asked)
            asked.append(k)

            def job():
                ran.append(k)
                gate.wait(10.0)

            return job

    asked: list[int] = []
    gm = GridMap.build(STALE, ALT, SAFETY)
    mission = _mission(v, clock, Slow(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT), [])
    mission.result.waypoints = np.array([[*START, ALT, 0.0], [*GOAL, ALT, 0.0]])
    try:
        mission._refine()
        deadline = time.monotonic() + 5.0
        while not ran and time.monotonic() < deadline:  # the first is running before the next replans come
            time.sleep(0.01)
        for _ in range(3):  # replanned three more times in a row, each route's refinement asked for at once
            mission._forget_refinement()
            mission._refine()
        gate.set()
        last = mission._refining
        assert last is not None and last.result(timeout=5.0) is None
    finally:
        gate.set()
        mission._stop_refining()
    assert asked == [0, 1, 2, 3] and ran == [0, 3]


class _RefiningBadly(Replanner):
    """A replanner whose refinement fails, or offers a route straight through the wall it has seen."""

    def __init__(self, *args, how, **kwargs):
        super().__init__(*args, **kwargs)
        self.how, self.jobs = how, 0

    def refine_job(self, position_ne, current_ne):
        self.jobs += 1
        if self.how == "raises":
            def job():
                raise RuntimeError("the search fell over")
            return job
        straight = np.array([[*position_ne, ALT, 0.0], [*GOAL, ALT, 0.0]])  # north up the walled street
        return lambda: type(self.replan(position_ne))(straight, 1.0, 170.0, 0, False)


@pytest.mark.parametrize("how", ["raises", "through-the-wall"])
def test_a_refinement_that_fails_or_is_blocked_leaves_the_replanned_route(how, caplog):
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _RefiningBadly(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT, how=how)
    with caplog.at_level("INFO", logger="skyroute.flight.replanning"):
        result = _mission(v, clock, obstacles, calls=[]).run()
    assert obstacles.jobs >= 1 and result.completed and result.landing_error_m < 0.5
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0  # never took the straight line through the wall
    assert all(not math.isfinite(r.refine_ms) for r in result.replans)
    assert ("refining the route failed" if how == "raises" else "blocked by what was seen since") in caplog.text


class _CutOffUntilLookedAgain(Replanner):
    """The goal is 'cut off' at the first replan (as a hit from a drifted position estimate would cut it off); the
    hold to look again feeds scans, after which the replan finds the way (the hits seen free again)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.refusals = 0
        self.scans_at_refusal = None

    def replan(self, position_ne):
        if self.refusals == 0:
            self.refusals += 1
            self.scans_at_refusal = self.live.scans
            raise GoalUnreachable(GOAL, (position_ne[0] + 2.0, position_ne[1]))
        return super().replan(position_ne)


def test_a_goal_cut_off_only_for_a_moment_is_looked_at_again_and_reached():
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _CutOffUntilLookedAgain(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT)
    mission = _mission(v, clock, obstacles, calls=[])
    result = mission.run()
    assert result.completed and result.landing_error_m < 0.5
    events = [e for _, e, _ in result.history]
    assert obstacles.refusals == 1 and E.GOAL_UNREACHABLE not in events and E.REPLANNED in events
    # it held where it stopped for the look (3 s at the sensor's 10 Hz: ~30 scans before the next replan)
    assert obstacles.live.scans - obstacles.scans_at_refusal >= 25


def test_a_goal_still_cut_off_after_looking_again_is_given_up(caplog):
    clock = FakeClock()
    ring = enclose_goal(GOAL, ring_m=8.0, height_m=30.0)
    v = SensingVehicle(clock, np.vstack([STALE, ring]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    mission = _mission(v, clock, _obstacles(), calls=[])
    caplog.set_level("INFO", logger="skyroute.flight")
    with pytest.raises(m.GoalUnreachableInFlight):
        mission.run()
    looked = caplog.text.index("holding to look again for 3 s")
    assert looked < caplog.text.index("holding; landing at the nearest reachable safe point")
    assert "fallback point (the goal out of reach) reached at" in caplog.text and "goal reached at" not in caplog.text


def _without_prior():
    """The real replanner with its stale-map prior off: a replanned route is flown as planned."""
    gm = GridMap.build(STALE, ALT, SAFETY)
    return Replanner(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT, suspect_weight=1.0)


def test_a_new_route_turning_sharply_from_the_motion_starts_with_a_straight_lead_in():
    """At 5 m/s up the street, the route round the wall turns into the side street: the vehicle cannot turn on the
    spot, so the new route first runs straight on (the way it flies) for the braking it needs, then turns."""
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    result = _mission(v, clock, _without_prior(), calls=[]).run()
    assert result.completed and result.landing_error_m < 0.5
    first = result.replans[0]
    assert not first.braked
    lead, after = first.waypoints[1, :2] - first.waypoints[0, :2], first.waypoints[2, :2] - first.waypoints[1, :2]
    assert 3.0 < lead[0] < 7.0 and abs(lead[1]) < 0.5  # straight on, north, about the braking from 5 m/s
    assert abs(after[1]) > abs(after[0])  # then into the side street
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0


def test_a_sharp_turn_without_a_free_lead_in_brakes_first(monkeypatch, caplog):
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    obstacles = _without_prior()
    monkeypatch.setattr(obstacles, "segment_free", lambda a, b: False)
    with caplog.at_level("INFO"):
        result = _mission(v, clock, obstacles, calls=[]).run()
    assert result.completed and result.landing_error_m < 0.5
    first = result.replans[0]
    assert first.braked and "not free: braking first" in caplog.text
    assert first.waypoints[0, :2] == pytest.approx((first.north_m, first.east_m))


class _DriftingVehicle(SensingVehicle):
    """Its position estimate (the telemetry, which it flies to the setpoints) is ``error_ne`` (m) off the truth,
    and its receiver says it may be (``accuracy_m``): the scans are taken at the truth and stamped with the
    estimate, as the link's sensor reader stamps them. ``truth`` keeps the true map track."""

    def __init__(self, clock, city, error_ne, accuracy_m, **kwargs):
        super().__init__(clock, city, **kwargs)
        self.error_ne, self.accuracy_m = np.asarray(error_ne, float), float(accuracy_m)
        self.truth = []

    def _scan(self, dt):
        t = self.telemetry
        if t.on_ground:
            return
        n, e = t.north_m + OFFSET.north_m - self.error_ne[0], t.east_m + OFFSET.east_m - self.error_ne[1]
        self.truth.append((n, e))
        if self.clock.now < self.next_scan_s:
            return
        self.next_scan_s = self.clock.now + 0.1
        self._take(n, e, -t.down_m, time_s=self.clock.now, local_ne=(t.north_m, t.east_m),
                   position_error_m=3.0 * self.accuracy_m)


def _off_route_m(points: np.ndarray, route: np.ndarray) -> np.ndarray:
    """Each point's distance (m) from the polyline ``route``."""
    a, b = route[:-1], route[1:]
    ab = b - a
    t = np.clip(np.einsum("pki,ki->pk", points[:, None] - a, ab) / np.maximum((ab * ab).sum(1), 1e-12), 0.0, 1.0)
    return np.hypot(*(points[:, None] - (a + t[..., None] * ab)).transpose(2, 0, 1)).min(axis=1)


@pytest.mark.parametrize("matched", [True, False])
def test_scans_matched_to_the_map_bring_a_drifted_estimate_back_onto_the_route(matched):
    """The estimate 2 m east of the truth (the receiver states 1 m) up a street between blocks: matched to the
    map's walls, the scans measure the error and the mission flies the route and lands at the goal in truth;
    without matching, the vehicle flies the whole route and lands 2 m off, as its estimate tells it."""
    from skyroute.planning.scanmatch import MapSurface, PositionFix

    clock = FakeClock()
    error = (0.0, 2.0)
    start = (START[0] - OFFSET.north_m + error[0], START[1] - OFFSET.east_m + error[1])
    v = _DriftingVehicle(clock, STALE, error, accuracy_m=1.0, start=start)
    fix = PositionFix(MapSurface(STALE, ALT)) if matched else None
    mission = make_mission(v, clock, _plan_fn([]), goal_ne=GOAL, obstacles=_obstacles(), position_fix=fix,
                           replan_errors=(PlanningError,), replan_margin_m=SAFETY, leg_timeout_s=120.0)
    result = mission.run()
    assert result.completed
    truth = np.array(v.truth)
    landed_m = math.dist(truth[-1], GOAL)
    if matched:
        assert fix.correction_ne == pytest.approx((0.0, -2.0), abs=0.2)
        assert landed_m < 0.75  # the fake's goal tolerance and landing, against 2 m without
        street = truth[(truth[:, 0] > -60.0) & (truth[:, 0] < 60.0)]
        assert np.percentile(_off_route_m(street, result.waypoints[:, :2]), 90) < 0.5  # on the route, in truth
    else:
        assert landed_m == pytest.approx(2.0, abs=0.3)
        street = truth[(truth[:, 0] > -60.0) & (truth[:, 0] < 60.0)]
        assert np.median(_off_route_m(street, result.waypoints[:, :2])) == pytest.approx(2.0, abs=0.3)



@pytest.mark.parametrize("reading", [True, False], ids=["reading-on-the-way-down", "not-reading"])
def test_an_estimate_drifting_during_the_descent_over_the_goal_is_followed_by_the_fix(reading, monkeypatch):
    """The estimate drifts 2 m north (1 m/s) once the vehicle starts coming down over the goal, 15 m north of the
    blocks: the scans taken on the way down, from below the flight altitude, are matched to the blocks' faces at
    their own altitude and the vehicle lands at the goal in truth; read nothing from the top of the descent (as
    before) and it lands where the estimate drifted it, 2 m off."""
    from skyroute.planning.scanmatch import MapSurface, PositionFix

    clock = FakeClock()
    v = _DriftingVehicle(clock, STALE, (0.0, 0.0), accuracy_m=1.0, start=(START[0] - OFFSET.north_m,
                                                                             START[1] - OFFSET.east_m))
    fix = PositionFix(MapSurface(STALE, ALT), obstacles=STALE)
    mission = make_mission(v, clock, _plan_fn([]), goal_ne=GOAL, obstacles=_obstacles(), position_fix=fix,
                           replan_errors=(PlanningError,), replan_margin_m=SAFETY, leg_timeout_s=120.0)
    if not reading:
        monkeypatch.setattr(mission, "_sense_coming_down", lambda p: None)

    def drift(dt):  # the estimate moves north, the vehicle does not
        if v.gotos and v.gotos[-1][2] > -ALT + 0.5 and v.error_ne[0] < 2.0:
            step = min(1.0 * dt, 2.0 - v.error_ne[0])
            v.error_ne[0] += step
            v.telemetry.north_m += step

    clock.tickers.append(drift)
    result = mission.run()
    assert result.completed and v.error_ne[0] == pytest.approx(2.0)
    landed_m = math.dist(v.truth[-1], GOAL)
    if reading:
        assert fix.correction_ne[0] == pytest.approx(-2.0, abs=0.3)
        assert landed_m < 0.75
    else:
        assert landed_m > 1.5


@pytest.mark.parametrize("keep_off", [True, False])
def test_a_wall_the_sensor_reads_closer_than_the_estimate_says_is_kept_off(keep_off, monkeypatch):
    """A route up the central street 3.5 m from the east blocks' faces (the margin is 3 m), the estimate 2 m west
    of the truth: flying its estimate, the vehicle itself runs 1.5-1.7 m from the faces while the map says 3.5 m. The
    readings are relative to the vehicle, so they say so: the route shifts west until they read 80 % of the
    margin (2.4 m) again, and back once past the blocks. Here the live layer is kept from replanning (where it
    takes the readings for the map's building, placed where the estimate puts them, it does not); without the
    shift the vehicle flies the street that close to the walls."""
    clock = FakeClock()
    error, start_ne, goal_ne = (0.0, -2.0), (-85.0, 6.5), (85.0, 6.5)
    gm = GridMap.build(STALE, ALT, SAFETY)
    start = (start_ne[0] - OFFSET.north_m + error[0], start_ne[1] - OFFSET.east_m + error[1])
    v = _DriftingVehicle(clock, STALE, error, accuracy_m=0.7, start=start)
    obstacles = _obstacles(goal_ne)
    monkeypatch.setattr(obstacles, "check", lambda *args, **kwargs: None)
    mission = make_mission(v, clock, lambda n, e: gm.plan((n, e), goal_ne, snap_start=True).waypoints,
                           goal_ne=goal_ne, obstacles=obstacles, replan_errors=(PlanningError,),
                           replan_margin_m=SAFETY, leg_timeout_s=120.0)
    if not keep_off:
        mission.keep_off = mission.sensing.keep_off = None
    result = mission.run()
    assert result.completed and not result.replans
    truth = np.array(v.truth)
    clearance = _track_clearance(np.column_stack([np.zeros(len(truth)), truth]), STALE[:4])
    if keep_off:
        assert clearance >= 0.8 * SAFETY - 0.25
        assert mission.keep_off.largest_m == pytest.approx(0.9, abs=0.25)
        assert truth[-1, 1] == pytest.approx(goal_ne[1] - error[1], abs=0.3)  # the shift relaxed past the blocks
    else:
        assert clearance < 1.8  # 1.5 m and the grid route's half cell

class _RoofVehicle(SensingVehicle):
    """The sensing fake with a downward rangefinder over a flat ground and one roof ``roof_top_m`` high under
    north ``roof_n`` (a low building the map lacks; the horizontal sensor, at the flight altitude, misses it).
    ``altitudes`` keeps the true altitude over the roof."""

    def __init__(self, clock, truth, roof_n, roof_top_m, **kwargs):
        super().__init__(clock, truth, **kwargs)
        self.roof_n, self.roof_top_m, self.altitudes = roof_n, roof_top_m, []

    def _scan(self, dt):
        t = self.telemetry
        due = self.clock.now >= self.next_scan_s and not t.on_ground
        super()._scan(dt)
        if not due:
            return
        n, up = t.north_m + OFFSET.north_m, -t.down_m
        over = self.roof_n[0] <= n <= self.roof_n[1]
        if over:
            self.altitudes.append(up)
        self.queue.append(SimpleNamespace(height_m=up - (self.roof_top_m if over else 0.0), min_range_m=0.2,
                                          max_range_m=40.0, received_s=self.clock.now))


@pytest.mark.parametrize("keep_off", [True, False])
def test_a_roof_the_rangefinder_reads_closer_below_than_kept_is_flown_over_higher(keep_off):
    """A 9 m roof 30 m long the map lacks under the route at 10 m (the margin is 3 m): the horizontal sensor misses it;
    the downward rangefinder reads 1 m. The route lifts until it reads 80 % of the margin (2.4 m), and comes
    back down past it; without the lift the vehicle passes 1 m over it."""
    clock = FakeClock()
    v = _RoofVehicle(clock, STALE, (-15.0, 15.0), ALT - 1.0,
                     start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    mission = _mission(v, clock, _obstacles(), calls=[])
    if not keep_off:
        mission.keep_off = mission.sensing.keep_off = None
    result = mission.run()
    assert result.completed and not result.replans and result.landing_error_m <= 0.5
    over = np.array(v.altitudes) - (ALT - 1.0)
    if keep_off:
        assert mission.keep_off.highest_m == pytest.approx(1.4, abs=0.1)
        assert over[-1] >= 0.8 * SAFETY - 0.2  # climbing at 1.5 m/s from where it read the roof, at 5 m/s
        assert mission.keep_off.lift_m < 0.1  # back down past it
    else:
        assert over.max() == pytest.approx(1.0, abs=0.1)

def _route(*points):
    pts = np.array(points, float)
    return SimpleNamespace(waypoints=np.column_stack([pts, np.full(len(pts), ALT), np.zeros(len(pts))]), plan_ms=0.1)


def test_a_new_route_is_taken_on_the_fly_only_when_the_vehicle_can_slow_down_for_its_corners():
    """At 12 m/s (the mission brakes at 3 m/s^2: 24 m to stop), flying north: a new route straight on
    with its first corner 60 m ahead is taken as it is, even when the vehicle could not have stopped short of the
    obstacle on its old path (a wall followed to its visible end, seen a piece at a time: a held-out flight on SF
    stopped 4 times in 20 s when each new piece made it brake to a stop); one turning 90 degrees 10 m ahead is not
    (it could only cut that corner): the vehicle brakes first."""
    clock = FakeClock()
    v = FakeVehicle(clock)
    mission = make_mission(v, clock, straight_plan([]))
    v.telemetry.local_v_north_mps, v.telemetry.local_v_east_mps = 12.0, 0.0
    far_corner = _route((0.0, 0.0), (60.0, 0.0), (60.0, 40.0))
    near_corner = _route((0.0, 0.0), (10.0, 0.0), (10.0, 40.0))
    assert mission._slows_in_time(12.0, (0.0, 0.0), far_corner.waypoints)
    assert not mission._slows_in_time(12.0, (0.0, 0.0), near_corner.waypoints)
    assert mission._slows_in_time(2.0, (0.0, 0.0), near_corner.waypoints)
    assert mission._turn_onto(far_corner, (0.0, 0.0), None, stops_short=False) == (far_corner, None)
    assert mission._turn_onto(near_corner, (0.0, 0.0), None, stops_short=True) is None
    assert not mission._slows_in_time(12.0, (0.0, 0.0), _route((0.0, 0.0), (15.0, 0.0)).waypoints)  # the goal


def _lead_in_mission(free: bool, first_leg_m: float):
    """A mission flying north at 12 m/s whose obstacle map plans, from any point, ``first_leg_m`` 15 degrees right of
    north, then a right angle to the right and 40 m on; ``segment_free`` answers ``free``. Returns it and the route
    from the origin."""
    turn = math.radians(15.0)

    def replan(p):
        q = (p[0] + first_leg_m * math.cos(turn), p[1] + first_leg_m * math.sin(turn))
        return _route(p, q, (q[0] - 40.0 * math.sin(turn), q[1] + 40.0 * math.cos(turn)))

    clock = FakeClock()
    v = FakeVehicle(clock)
    obstacles = SimpleNamespace(replan=replan, segment_free=lambda a, b: free)
    mission = make_mission(v, clock, straight_plan([]), obstacles=obstacles, replan_errors=(PlanningError,))
    v.telemetry.local_v_north_mps, v.telemetry.local_v_east_mps = 12.0, 0.0
    return mission, replan((0.0, 0.0))


def test_a_lead_in_is_taken_only_when_the_vehicle_can_slow_down_for_every_corner_after_it():
    """At 12 m/s north, a new route turning 15 degrees right at once needs ~13 m straight on to slow down for
    the turn (3 m/s^2, 1 m swing). Where that lead-in is free (margins included) and the vehicle can then slow down
    for every corner after it, the route is taken from the lead-in's end without a stop; not when the lead-in is
    not free, nor when the route's right angle comes 10 m after it (from ~9 m/s that needs ~13 m: before, only the
    turn onto the first leg was checked), nor when the vehicle could not have stopped short of the old path's
    obstacle (such a lead-in is about a stop: a stop and a plan from there use what was seen meanwhile)."""
    mission, route = _lead_in_mission(free=True, first_leg_m=20.0)
    ahead, point = mission._turn_onto(route, (0.0, 0.0), None)
    assert 10.0 < point[0] < 16.0 and point[1] == pytest.approx(0.0)  # straight on, north
    assert ahead.waypoints[0, :2] == pytest.approx(point)
    assert ahead.waypoints[1, 1] == pytest.approx(20.0 * math.sin(math.radians(15.0)))  # then 15 degrees right
    blocked, route = _lead_in_mission(free=False, first_leg_m=20.0)
    assert blocked._turn_onto(route, (0.0, 0.0), None) is None
    hurried, route = _lead_in_mission(free=True, first_leg_m=10.0)
    assert hurried._turn_onto(route, (0.0, 0.0), None) is None
    late, route = _lead_in_mission(free=True, first_leg_m=20.0)
    assert late._turn_onto(route, (0.0, 0.0), None, stops_short=False) is None


class _PhantomWallVehicle(SensingVehicle):
    """Reads the wall across the central street in three scans as soon as it comes within the sensor's 30 m,
    and never again (noise that looks like a wall): the layer confirms it, then sees the street free and drops it."""

    def __init__(self, clock, truth, **kwargs):
        super().__init__(clock, truth, **kwargs)
        phantom = np.vstack([truth, WALL])
        lo, hi = phantom[:, :3] - phantom[:, 3:], phantom[:, :3] + phantom[:, 3:]
        self.phantom = lo[:, :2], hi[:, :2], hi[:, 2]
        self.phantom_scans = 3

    def _take(self, north_m, east_m, altitude_m, **stamp):
        if self.phantom_scans and north_m >= WALL[0, 0] - 29.0:
            self.phantom_scans -= 1
            truth, (self.lo, self.hi, self.top) = (self.lo, self.hi, self.top), self.phantom
            try:
                return super()._take(north_m, east_m, altitude_m, **stamp)
            finally:
                self.lo, self.hi, self.top = truth
        return super()._take(north_m, east_m, altitude_m, **stamp)


def test_a_detour_round_an_obstacle_dropped_as_noise_is_given_up_for_the_way_it_closed():
    clock = FakeClock()
    v = _PhantomWallVehicle(clock, STALE, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    result = _mission(v, clock, _obstacles(), calls=[]).run()
    assert result.completed and result.landing_error_m < 0.5
    reasons = [r.reason for r in result.replans]
    assert reasons[0] in ("blocked", "margin") and "reopened" in reasons  # detoured, then took the street again
    reroute = result.replans[reasons.index("reopened")]
    assert "rerouted" in reroute.describe() and np.allclose(reroute.waypoints[-1, :2], GOAL)
    track = result.track[:, 1:3]
    passed = track[np.abs(track[:, 0] - WALL[0, 0]) < 1.0]  # where it crossed the phantom wall's line
    assert len(passed) and np.abs(passed[:, 1]).max() < 10.0  # up the central street (east -10..10), not round


def test_without_a_reroute_the_phantom_wall_sends_the_vehicle_round_a_block():
    """The check on the test above: the same flight with the reroute taken out goes the long way."""
    clock = FakeClock()
    v = _PhantomWallVehicle(clock, STALE, start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    obstacles = _obstacles()
    obstacles.reroute_job = lambda position_ne, current_ne: None
    result = _mission(v, clock, obstacles, calls=[]).run()
    assert result.completed and "reopened" not in [r.reason for r in result.replans]
    track = result.track[:, 1:3]
    passed = track[np.abs(track[:, 0] - WALL[0, 0]) < 1.0]
    assert np.abs(passed[:, 1]).min() > 10.0


class _CutOffUntilFallback(Replanner):
    """The goal is 'cut off' until the vehicle has given it up (twice refused: the replan and the look again) and
    flown towards the fallback point 25 m back down the street; ``reopen_after_m``: once that far from where it
    gave up, one scan reports observed obstacles dropped as noise (as views on the way there see a wide sector's
    arc free), else the goal is asked for again only at the fallback point."""

    def __init__(self, *args, reopen_after_m=math.inf, **kwargs):
        super().__init__(*args, **kwargs)
        self.refusals, self.gave_up_at, self.reopen_after_m, self.reopened_at = 0, None, reopen_after_m, None
        self.fallback_ne = None

    def replan(self, position_ne):
        if self.goal_ne == GOAL and self.refusals < 2:
            self.refusals += 1
            self.gave_up_at = tuple(position_ne[:2])
            self.fallback_ne = (float(position_ne[0]) - 25.0, 0.5)
            raise GoalUnreachable(GOAL, self.fallback_ne)
        return super().replan(position_ne)

    def add_scan(self, north_m, east_m, *args, **kwargs):
        update = super().add_scan(north_m, east_m, *args, **kwargs)
        if (self.gave_up_at is not None and self.reopened_at is None
                and math.dist((north_m, east_m), self.gave_up_at) > self.reopen_after_m):
            self.reopened_at = (north_m, east_m)
            return ScanUpdate(0, 1, update.explained, update.unexplained, True)
        return update


@pytest.mark.parametrize("reopen_after_m", [math.inf, 8.0], ids=["at-the-fallback-point", "on-the-way-there"])
def test_a_goal_given_up_is_flown_to_once_it_is_in_reach_again(reopen_after_m):
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _CutOffUntilFallback(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT,
                                     reopen_after_m=reopen_after_m)
    result = _mission(v, clock, obstacles, calls=[]).run()
    assert result.completed and result.landing_error_m < 0.5  # at the goal, not the fallback point: exit 0
    events = [e for _, e, _ in result.history]
    assert obstacles.refusals == 2 and E.GOAL_UNREACHABLE in events
    again = [r for r in result.replans if r.reason == GOAL_AGAIN]
    assert len(again) == 1 and "the goal in reach again" in again[0].describe()
    where = (again[0].north_m, again[0].east_m)
    if math.isinf(reopen_after_m):  # asked again once there
        assert math.dist(where, obstacles.fallback_ne) < 2.0
    else:  # asked again at the first scan that dropped something, well short of the fallback point
        assert math.dist(where, obstacles.reopened_at) < 3.0 and math.dist(where, obstacles.fallback_ne) > 8.0
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0


class _ClosedUntilLookedAt(Replanner):
    """The goal is 'cut off' (as by a wide sector's arc across the only way on) until the vehicle has been to the
    viewpoint the layer offers (6 m back down the street from where it was first asked for one, 6 m further for
    each one looked from already); ``never``: cut off for good."""

    def __init__(self, *args, never=False, **kwargs):
        super().__init__(*args, **kwargs)
        self.never, self.offered, self.looked, self.first_north = never, [], False, None

    def viewpoint(self, position_ne, looked_from=()):
        if self.first_north is None:
            self.first_north = float(position_ne[0])
        point = (self.first_north - 6.0 * (len(looked_from) + 1), 0.5)
        self.offered.append(point)
        return point

    def replan(self, position_ne):
        if self.goal_ne == GOAL:
            if self.offered and math.dist(position_ne[:2], self.offered[-1]) < 1.5:
                self.looked = True
            if self.never or not self.looked:
                raise GoalUnreachable(GOAL, (float(position_ne[0]) - 25.0, 0.5))
        return super().replan(position_ne)


def _closed_until_looked_at(never: bool):
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _ClosedUntilLookedAt(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT,
                                     never=never)
    return v, obstacles, _mission(v, clock, obstacles, calls=[])


def test_a_goal_out_of_reach_is_looked_for_from_the_viewpoint_before_it_is_given_up():
    v, obstacles, mission = _closed_until_looked_at(never=False)
    result = mission.run()
    assert result.completed and result.landing_error_m < 0.5  # at the goal, exit 0
    assert len(obstacles.offered) == 1
    looking = [r for r in result.replans if "looking from" in r.outcome]
    assert len(looking) == 1 and np.allclose(looking[0].waypoints[-1, :2], obstacles.offered[0])
    track = result.track[:, 1:3]
    assert np.hypot(*(track - obstacles.offered[0]).T).min() < 1.0  # it went there
    again = [r for r in result.replans if r.reason == GOAL_AGAIN]
    assert len(again) == 1 and math.dist((again[0].north_m, again[0].east_m), obstacles.offered[0]) < 1.5
    events = [e for _, e, _ in result.history]
    assert E.GOAL_UNREACHABLE not in events
    assert _track_clearance(result.track, WALL) >= SAFETY - 1.0


def test_a_goal_still_out_of_reach_from_every_viewpoint_is_given_up_at_the_fallback_point():
    v, obstacles, mission = _closed_until_looked_at(never=True)
    with pytest.raises(m.GoalUnreachableInFlight, match="instead of the goal") as info:
        mission.run()
    result = info.value.result
    assert len(obstacles.offered) == MAX_VIEWPOINTS > 0  # then no more: the fallback point
    assert len([r for r in result.replans if "looking from" in r.outcome]) == MAX_VIEWPOINTS
    events = [e for _, e, _ in result.history]
    assert E.GOAL_UNREACHABLE in events and not result.completed
    assert result.final_state is S.MANUAL and not v.telemetry.armed and v.telemetry.on_ground



def test_a_goal_still_out_of_reach_is_logged_once_per_way_and_reason_however_often_it_is_asked(caplog):
    """On the way to a viewpoint or the fallback point the goal is asked for at every change of the layer (near a
    wall, at the sensor's rate: 47 lines in 2 s of one flight); the log says so once per way and reason."""
    reasons = iter(["cut off"] * 5 + ["cut off further on"] * 3)

    def replan(position_ne):
        raise PlanningError(next(reasons))

    clock = FakeClock()
    mission = make_mission(FakeVehicle(clock), clock, straight_plan([]), obstacles=SimpleNamespace(replan=replan),
                           replan_errors=(PlanningError,))
    with caplog.at_level("INFO", logger="skyroute.flight.replanning"):
        assert all(mission._goal_route((0.0, 0.0)) is None for _ in range(6))
        mission._viewpoint_ne = (10.0, 0.0)
        assert all(mission._goal_route((0.0, 0.0)) is None for _ in range(2))
    said = [r.getMessage() for r in caplog.records if r.levelname == "INFO" and "still out of reach" in r.message]
    assert said == ["flying to the fallback point: the goal is still out of reach (cut off)",
                    "flying to the fallback point: the goal is still out of reach (cut off further on)",
                    "flying to the viewpoint: the goal is still out of reach (cut off further on)"]

class _ViewpointAfterFallback(_ClosedUntilLookedAt):
    """No viewpoint at first (the goal is given up for the fallback point 25 m back), then the way to the fallback
    point is found blocked once and has no route: the next give-up offers a viewpoint, where the goal is in reach."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.asked, self.fallback_ne, self.fallback_blocked = 0, None, False

    def viewpoint(self, position_ne, looked_from=()):
        self.asked += 1
        return None if self.asked == 1 else super().viewpoint(position_ne, looked_from)

    def replan(self, position_ne):
        try:
            return super().replan(position_ne)
        except GoalUnreachable as exc:
            if self.fallback_ne is None and self.goal_ne == GOAL:
                self.fallback_ne = exc.fallback_ne
            raise

    def check(self, position_ne, waypoints_ne):
        heading_back = self.fallback_ne is not None and np.allclose(waypoints_ne[-1, :2], self.fallback_ne)
        if heading_back and not self.fallback_blocked and self.asked == 1:
            self.fallback_blocked = True
            return Blockage("blocked", 6.0, (float(position_ne[0]) - 6.0, float(position_ne[1])))
        return super().check(position_ne, waypoints_ne)

    def route_to(self, position_ne, target_ne):
        if self.fallback_blocked and self.fallback_ne is not None and np.allclose(target_ne, self.fallback_ne):
            raise GoalUnreachable(tuple(target_ne), None)
        return super().route_to(position_ne, target_ne)


def test_a_goal_found_in_reach_from_a_viewpoint_after_it_was_given_up_is_a_success():
    clock = FakeClock()
    v = SensingVehicle(clock, np.vstack([STALE, WALL]), start=(START[0] - OFFSET.north_m, START[1] - OFFSET.east_m))
    gm = GridMap.build(STALE, ALT, SAFETY)
    obstacles = _ViewpointAfterFallback(LiveMap.for_grid_map(gm, create_grid(STALE, ALT, 0.0)[0]), GOAL, ALT)
    result = _mission(v, clock, obstacles, calls=[]).run()  # not GoalUnreachableInFlight
    assert obstacles.fallback_blocked and len(obstacles.offered) == 1
    assert result.completed and result.landing_error_m < 0.5
    events = [e for _, e, _ in result.history]
    assert E.GOAL_UNREACHABLE in events and [r.reason for r in result.replans].count(GOAL_AGAIN) == 1
