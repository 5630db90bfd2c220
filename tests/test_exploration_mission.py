"""The exploration mission's flow with a fake vehicle and a scripted explorer: legs, abandonment, targets, time.

The vehicle is test_mission's point-mass fake (local frame = map - OFFSET); the explorer is scripted here: its
frontiers are points that count as seen once the vehicle has looked down within ``clear_m`` of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyroute.flight.exploration import ExplorationMission
from skyroute.flight.mission import MissionEvent as E
from skyroute.flight.mission import MissionState as S
from skyroute.vehicle.sensors import RangeScan
from tests.test_mission import OFFSET, ORIGIN, FakeClock, FakeVehicle, Refused

ALT_M = 10.0


@dataclass
class Point:
    point_ne: tuple[float, float]


class ScriptedExplorer:
    def __init__(self, frontiers, clear_m=2.0, never_clear=()):
        self.open = [tuple(map(float, f)) for f in frontiers]
        self.never_clear = {tuple(map(float, f)) for f in never_clear}
        self.clear_m = clear_m
        self.abandoned: list[tuple[float, float]] = []
        self.routes = 0
        self.views: list[tuple[float, float]] = []

    def add_scan(self, *args):
        return None

    def check(self, position_ne, waypoints_ne):
        return None

    def route_to(self, position_ne, target_ne, extend_m=0.0):
        self.routes += 1
        return np.array([[position_ne[0], position_ne[1], math.nan, 0.0], [target_ne[0], target_ne[1], math.nan, 0.0]])

    def next_frontier(self, position_ne):
        return Point(self.open[0]) if self.open else None

    def is_frontier(self, point_ne):
        return tuple(map(float, point_ne)) in self.open

    def abandon(self, point_ne):
        p = tuple(map(float, point_ne))
        self.abandoned.append(p)
        self.open = [f for f in self.open if math.dist(f, p) > 4.0]
        return 1

    def view(self, north_m, east_m):
        self.views.append((north_m, east_m))
        self.open = [f for f in self.open
                     if f in self.never_clear or math.dist(f, (north_m, east_m)) > self.clear_m]

    def coverage(self):
        return 0.5

    def why_unreachable(self, position_ne):
        return ""

    def discovered_ne(self):
        return np.empty((0, 2))


class SightingVehicle(FakeVehicle):
    """The fake vehicle with a downward camera: a target at a map point is reported (local NED) within 5 m."""

    def __init__(self, clock, targets_ne=(), **kwargs):
        super().__init__(clock, **kwargs)
        self.targets_ne = list(targets_ne)

    def target_sightings(self):
        t = self.telemetry
        here = (t.north_m + OFFSET.north_m, t.east_m + OFFSET.east_m)
        out = []
        for k, (n, e) in enumerate(self.targets_ne):
            if math.dist(here, (n, e)) <= 5.0 and -t.down_m > 1.0:
                out.append(_Sighting(k, n - OFFSET.north_m, e - OFFSET.east_m))
        return out


@dataclass
class _Sighting:
    target_num: int
    north_m: float
    east_m: float


def explore(explorer, *, vehicle=None, clock=None, **kwargs):
    clock = clock or FakeClock()
    vehicle = vehicle or FakeVehicle(clock, speed_mps=8.0)
    kwargs.setdefault("explore_time_s", 600.0)
    mission = ExplorationMission(vehicle, lambda n, e: explorer, altitude_m=ALT_M, map_origin=ORIGIN,
                                 vehicle_errors=(Refused,), clock=clock, sleep=clock.sleep, ground_amsl_m=12.0,
                                 **kwargs)
    return mission, mission.run(), vehicle


HOME = (OFFSET.north_m, OFFSET.east_m)  # the fake starts at local (0, 0)


def test_flies_each_frontier_then_lands_home_and_only_the_way_home_ends_in_landing():
    explorer = ScriptedExplorer([(HOME[0] + 30, HOME[1]), (HOME[0] + 30, HOME[1] + 30)])
    mission, result, vehicle = explore(explorer)
    assert result.completed and mission.state is S.MANUAL
    assert explorer.open == [] and mission.stats.stopped == "no reachable frontier left"
    events = [event for _, event, _ in result.history]
    assert events.count(E.GOAL_REACHED) == 1
    assert events[events.index(E.GOAL_REACHED) + 1] is E.LANDED
    track = result.track
    assert min(math.dist(p, (HOME[0] + 30, HOME[1] + 30)) for p in track[:, 1:3]) <= 2.0
    assert math.dist(track[-1, 1:3], HOME) <= 0.5 and track[-1, 3] <= 0.05
    assert not vehicle.telemetry.armed


def test_a_frontier_that_never_clears_is_abandoned_not_flown_forever():
    stubborn = (HOME[0] - 20, HOME[1])
    explorer = ScriptedExplorer([stubborn], never_clear=[stubborn])
    mission, result, _ = explore(explorer)
    assert result.completed
    assert explorer.abandoned == [stubborn] and mission.stats.abandoned == 1
    assert explorer.routes <= 3  # the frontier, then home


def collect_one_target(vehicle_class=None, explorer_class=None):
    """Two frontiers north of home with a target 3 m off the first: the mission, its result, vehicle, explorer."""
    clock = FakeClock()
    target = (HOME[0] + 25, HOME[1] + 3)
    vehicle = (vehicle_class or SightingVehicle)(clock, targets_ne=[target], speed_mps=8.0)
    explorer = (explorer_class or ScriptedExplorer)([(HOME[0] + 25, HOME[1]), (HOME[0] + 50, HOME[1])])
    mission, result, _ = explore(explorer, vehicle=vehicle, clock=clock)
    return mission, result, vehicle, explorer, target


def test_a_sighted_target_is_collected_at_2_m_for_2_s():
    mission, result, vehicle, explorer, target = collect_one_target()
    assert result.completed
    (t,) = mission.stats.targets
    assert t.collected and math.dist((t.north_m, t.east_m), target) < 1e-6
    low = [row for row in result.track if row[3] <= 2.3 and math.dist(row[1:3], target) <= 0.5]
    assert low, "never came down over the target"
    # held there: the hold streams the 2 m setpoint over the target every 0.02 s poll for 2 s (our clock: the fake
    # reports no autopilot time), the descent a few more
    local = (target[0] - OFFSET.north_m, target[1] - OFFSET.east_m, -2.0 - mission._offset.down_m)
    at_two = [g for g in vehicle.gotos if np.allclose(g[:3], local, atol=1e-6)]
    assert len(at_two) >= 2.0 / 0.02
    assert explorer.open == []  # and carried on exploring afterwards


def test_the_time_budget_sends_it_home():
    far = [(HOME[0] + 40 * k, HOME[1]) for k in range(1, 50)]
    explorer = ScriptedExplorer(far)
    mission, result, _ = explore(explorer, explore_time_s=20.0)
    assert result.completed and mission.stats.stopped == "time budget used"
    assert len(explorer.open) > 40
    assert math.dist(result.track[-1, 1:3], HOME) <= 0.5


class ScanningVehicle(SightingVehicle):
    """The camera fake with an obstacle sensor whose readings reach the mission a poll late: each is stamped with
    the local position it arrived at (as the link stamps them), which is where the vehicle was a poll ago."""

    def __init__(self, clock, **kwargs):
        super().__init__(clock, **kwargs)
        self.stamps: list[tuple[float, float, float]] = []
        self._previous = None

    def sensor_readings(self):
        t = self.telemetry
        previous, self._previous = self._previous, (t.north_m, t.east_m, t.down_m)
        if previous is None:
            return []
        self.stamps.append(previous)
        return [RangeScan(np.array([0.0]), math.radians(2.5), np.array([np.inf]), 0.2, 30.0, 0.0, 0.0,
                          "OBSTACLE_DISTANCE", local_ne=previous[:2], local_down_m=previous[2])]


class RecordingExplorer(ScriptedExplorer):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.scans: list[tuple[float, float]] = []

    def add_scan(self, north_m, east_m, *rest):
        self.scans.append((north_m, east_m))


def test_scans_are_placed_where_they_arrived_and_low_ones_never_reach_the_map():
    mission, result, vehicle, explorer, _ = collect_one_target(ScanningVehicle, RecordingExplorer)
    assert result.completed and mission.stats.targets[0].collected
    floor = ALT_M - mission.altitude_tolerance_m
    high = [(n + mission._offset.north_m, e + mission._offset.east_m) for n, e, d in vehicle.stamps
            if -(d + mission._offset.down_m) >= floor]
    low = len(vehicle.stamps) - len(high)
    assert low > 50, "the flight should take scans low: the takeoff and the 2 s collect at 2 m"
    assert len(explorer.scans) == len(high) > 0 and np.allclose(explorer.scans, high, atol=1e-9)
    assert mission.sensing.low_scans == low
