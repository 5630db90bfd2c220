"""The mission: the transition table, the path geometry and steering, and every flow and failure path with a fake.

The fake vehicle is a kinematic point that moves towards its setpoint at 5 m/s when the injected fake clock's
``sleep`` is called, so whole missions (including outages, lost modes and a pilot's takeover) run
deterministically in milliseconds. At the end, missions against the in-process ``sim``.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass

import numpy as np
import pytest

from skyroute.flight import drag as dg
from skyroute.flight import follower as fw
from skyroute.flight import keepoff
from skyroute.flight import mission as m
from skyroute.flight import path as fp
from skyroute.flight.mission import MissionEvent as E
from skyroute.flight.mission import MissionState as S
from skyroute.frames import Geodetic, LocalNED
from skyroute.vehicle.limits import Geofence
from skyroute.vehicle.statustext import names_our_link

ORIGIN = Geodetic(37.79248, -122.39745, 0.0)
OFFSET = LocalNED(100.0, -50.0, 0.0)  # the autopilot's local origin is 100 m S, 50 m E of the map origin
GROUND_AMSL_M = 12.0  # the map's ground, metres above sea level (the fake's GPS says so)


# ----------------------------------------------------------------------------------------- transitions
@pytest.mark.parametrize("state_event, expected", sorted(m.TRANSITIONS.items(), key=str))
def test_each_legal_transition(state_event, expected):
    assert m.next_state(*state_event) is expected


ILLEGAL = [(s, e) for s, e in itertools.product(S, E) if (s, e) not in m.TRANSITIONS]


@pytest.mark.parametrize("state, event", ILLEGAL)
def test_each_illegal_transition_raises(state, event):
    with pytest.raises(m.IllegalTransition, match=event.name):
        m.next_state(state, event)


def test_happy_path_waits_plans_arms_then_flies():
    state, seen = S.MANUAL, [S.MANUAL]
    for event in (E.START, E.READY, E.PLANNED, E.ARMED, E.TAKEOFF_DONE, E.WAYPOINT_REACHED, E.GOAL_REACHED,
                  E.LANDED, E.DISARMED):
        state = m.next_state(state, event)
        seen.append(state)
    assert seen == [S.MANUAL, S.PREFLIGHT, S.PLANNING, S.ARMING, S.TAKEOFF, S.WAYPOINT, S.WAYPOINT, S.LANDING,
                    S.DISARMING, S.MANUAL]


def test_an_outage_in_flight_is_ridden_out_not_ended():
    assert m.next_state(S.WAYPOINT, E.LINK_LOST) is S.RECOVERING
    assert m.next_state(S.RECOVERING, E.RESUMED) is S.WAYPOINT
    assert m.next_state(S.RECOVERING, E.LANDED_MEANWHILE) is S.MANUAL
    assert m.next_state(S.RECOVERING, E.TAKEN_OVER) is S.HANDED_OVER


def test_failed_and_handed_over_are_terminal():
    assert not [k for k in m.TRANSITIONS if k[0] in (S.FAILED, S.HANDED_OVER)]


def test_nothing_before_arming_can_reach_a_state_that_needs_a_landing():
    # planning happens before arming: a planner failure leaves nothing to undo
    for state in (S.PREFLIGHT, S.PLANNING):
        assert {new for (old, _), new in m.TRANSITIONS.items() if old is state} <= {S.MANUAL, S.PLANNING, S.ARMING}


# -------------------------------------------------------------------------------------------- geometry
def test_leg_headings_follow_each_leg():
    wps = np.array([[0, 0, 5, 0], [0, 10, 5, 0], [-10, 10, 5, 0], [-10, 10.1, 5, 0]], float)
    # east (pi/2), east, south (pi), and a 0.1 m leg keeps south
    assert fp.leg_headings(wps) == pytest.approx([math.pi / 2, math.pi / 2, math.pi, math.pi])


def test_corner_radius_keeps_the_arc_within_the_cut():
    # 90 deg: r = cut / (1 - cos 45) = 0.5 / (1 - 1/sqrt 2) = 1 + 1/sqrt 2; tangent points r * tan 45 = r away
    assert fp.corner_radius_m(math.pi / 2, 0.5, 100.0) == pytest.approx(1.0 + 1.0 / math.sqrt(2))
    # 60 deg: r = 0.5 / (1 - cos 30) = 2 + sqrt 3
    assert fp.corner_radius_m(math.pi / 3, 0.5, 100.0) == pytest.approx(2.0 + math.sqrt(3))
    # a 2 m leg allows tangent points 1 m out: r = 1 / tan 45 = 1
    assert fp.corner_radius_m(math.pi / 2, 0.5, 1.0) == pytest.approx(1.0)
    assert fp.corner_radius_m(0.0, 0.5, 100.0) == math.inf  # straight on
    assert fp.corner_radius_m(math.pi, 0.5, 100.0) == 0.0  # reversal: stop at the corner
    assert fp.corner_cut_m(0.0, math.inf) == 0.0  # straight on: no arc, nothing cut (not inf x 0)
    for turn_deg in (10, 45, 90, 135, 170):
        turn = math.radians(turn_deg)
        assert fp.corner_cut_m(turn, fp.corner_radius_m(turn, 0.5, 1e6)) == pytest.approx(0.5)
        assert fp.corner_cut_m(turn, fp.corner_radius_m(turn, 0.5, 2.0)) <= 0.5 + 1e-12


def _distance_to_polyline(point, corners):
    best = math.inf
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        f = min(max(float((point - a) @ (b - a)) / float((b - a) @ (b - a)), 0.0), 1.0)
        best = min(best, float(np.linalg.norm(a + f * (b - a) - point)))
    return best


L_PATH = np.array([[0.0, 0.0, 5.0], [20.0, 0.0, 5.0], [20.0, 20.0, 5.0]])  # 20 m north, then 20 m east


def test_smooth_path_rounds_a_right_angle_by_the_cut():
    p = fp.smooth_path(L_PATH, corner_cut_m=0.5, cruise_mps=10.0, accel_mps2=3.0, lateral_accel_mps2=3.0)
    r = 1.0 + 1.0 / math.sqrt(2)
    # tangent points r = 1.707 m before and after the corner; the arc's middle is (19.5, 0.5): 0.5 m off both legs
    assert p.points[1] == pytest.approx([20.0 - r, 0.0, 5.0])
    assert p.points[-2] == pytest.approx([20.0, r, 5.0])
    middle = p.points[len(p.points) // 2]
    assert middle == pytest.approx([19.5, 0.5, 5.0])
    assert max(_distance_to_polyline(q, L_PATH) for q in p.points) == pytest.approx(0.5)
    # length: two straights of 20 - r and six chords of 2 r sin(7.5 deg) on the quarter circle
    assert p.length_m == pytest.approx(2 * (20.0 - r) + 6 * 2 * r * math.sin(math.radians(7.5)))
    assert p.waypoint_s_m == pytest.approx([0.0, 20.0 - r + 3 * 2 * r * math.sin(math.radians(7.5)), p.length_m])


def test_smooth_path_speed_schedule():
    p = fp.smooth_path(L_PATH, corner_cut_m=0.5, cruise_mps=10.0, accel_mps2=3.0, lateral_accel_mps2=3.0)
    r = 1.0 + 1.0 / math.sqrt(2)
    v_turn = math.sqrt(3.0 * r)  # 2.263 m/s: 3 m/s^2 sideways on the arc
    assert p.speed_at(0.0) == 10.0  # cruise: braking from 18.3 m out would allow 10.7 m/s
    assert p.speed_at(20.0 - r - 5.0) == pytest.approx(math.sqrt(v_turn**2 + 2 * 3.0 * 5.0))  # braking, 5 m out
    assert p.speed_at(p.waypoint_s_m[1]) == pytest.approx(v_turn)  # on the arc
    assert p.speed_at(p.length_m - 1.5) == pytest.approx(3.0)  # stopping at the goal: sqrt(2 * 3 * 1.5)
    assert p.speed_at(p.length_m) == 0.0


def test_smooth_path_limits_the_vertical_speed_and_keeps_collinear_points():
    climb = fp.smooth_path(np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 30.0]]), vertical_mps=1.5, cruise_mps=10.0)
    assert climb.segment_speed_mps == pytest.approx([1.5 * 50.0 / 30.0])  # 30 m up in 50 m: 2.5 m/s along it
    straight = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [30.0, 0.0, 5.0]]))
    assert straight.points.tolist() == [[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [30.0, 0.0, 5.0]]
    assert straight.waypoint_s_m.tolist() == [0.0, 10.0, 30.0]


def test_point_at_and_project():
    p = fp.smooth_path(L_PATH)
    position, tangent = p.point_at(10.0)
    assert position == pytest.approx([10.0, 0.0, 5.0]) and tangent == pytest.approx([1.0, 0.0, 0.0])
    assert p.point_at(1e9)[0] == pytest.approx([20.0, 20.0, 5.0])
    assert p.project((10.0, 3.0, 5.0)) == pytest.approx(10.0)  # 3 m off the first leg, 10 m along
    assert p.project((19.5, 0.5, 5.0)) == pytest.approx(p.waypoint_s_m[1])
    assert p.project((25.0, 20.0, 5.0)) == pytest.approx(p.length_m)  # past the end: the end
    # forward only, and within the window: from 30 m on, the start is not considered; 5 m on is out of reach
    assert p.project((0.0, 0.0, 5.0), from_s_m=30.0) == pytest.approx(30.0)
    # a vehicle that fell back behind from_s_m on a straight stays there: no jump to a later segment
    assert p.project((5.0, 0.0, 5.0), from_s_m=6.0) == pytest.approx(6.0)
    # segments starting within the window count whole: (20, 15) is closest to the end of the first straight
    assert p.project((20.0, 15.0, 5.0), from_s_m=0.0, window_m=5.0) == pytest.approx(20.0 - 1.0 - 1.0 / math.sqrt(2))


def test_path_length():
    assert fp.path_length_m(np.array([[0, 0, 0], [3, 4, 0], [3, 4, 12]])) == pytest.approx(17.0)


def test_a_one_point_path_is_that_point_with_no_direction():
    p = fp.smooth_path(np.array([[3.0, 4.0, 5.0]]))  # a goal already reached: nothing to fly
    position, tangent = p.point_at(2.0)
    assert position.tolist() == [3.0, 4.0, 5.0] and tangent.tolist() == [0.0, 0.0, 0.0]
    assert p.project((10.0, 10.0, 5.0)) == 0.0


def test_point_at_is_exact_near_the_start_and_at_a_repeated_goal():
    p = fp.smooth_path(L_PATH)
    assert p.point_at(0.25)[0] == pytest.approx([0.25, 0.0, 5.0])  # a quarter metre up the first leg
    # a planner that repeats the goal leaves a zero-length last segment: its end is still the goal
    repeated = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [10.0, 0.0, 5.0]]))
    position, tangent = repeated.point_at(repeated.length_m)
    assert position.tolist() == [10.0, 0.0, 5.0] and tangent.tolist() == [0.0, 0.0, 0.0]


def test_project_starts_from_the_path_start_and_searches_exactly_window_m_ahead():
    p = fp.smooth_path(L_PATH)
    assert p.project((0.0, 0.0, 5.0)) == 0.0  # the start, by default searched from 0 m
    # collinear waypoints keep their points: segments start at 0, 30 and 30.5 m; the search takes every segment
    # that starts within 30 m of from_s_m, no more
    line = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [30.0, 0.0, 5.0], [30.5, 0.0, 5.0], [60.0, 0.0, 5.0]]))
    assert line.project((60.0, 0.0, 5.0)) == pytest.approx(30.5)  # the segment from 30 m counts, from 30.5 not


def test_project_finds_points_between_the_arcs_samples_and_never_goes_back_on_them():
    p = fp.smooth_path(L_PATH)  # the corner's arc is sampled every ~0.45 m
    arc = [j for j in range(len(p.points) - 1) if 0.0 < p.s_m[j] < p.waypoint_s_m[1] + 1.0
           and p.s_m[j + 1] - p.s_m[j] < 1.0]
    assert len(arc) >= 4
    for j in arc:
        s_mid = 0.5 * (p.s_m[j] + p.s_m[j + 1])
        assert p.project(p.point_at(s_mid)[0]) == pytest.approx(s_mid, abs=1e-9)  # from 0 m: across the leg
        # from a point of this segment, a position just behind it is not taken back
        assert p.project(p.point_at(s_mid - 0.1)[0], from_s_m=s_mid) == pytest.approx(s_mid, abs=1e-9)


def test_project_gives_the_same_arc_length_over_few_segments_as_over_many(monkeypatch):
    # project() looks at a few segments in Python floats and at more with NumPy: both must agree everywhere
    rng = np.random.default_rng(5)
    wps = np.column_stack([np.cumsum(rng.uniform(-15, 15, (12, 2)), axis=0), rng.uniform(4, 8, 12)])
    p = fp.smooth_path(wps)
    probes = [(p.point_at(s)[0] + rng.normal(0.0, 2.0, 3), s + rng.uniform(-3, 3), window)
              for s in rng.uniform(0, p.length_m, 300) for window in (2.0, 30.0)]
    few = [p.project(q, from_s_m=max(s, 0.0), window_m=w) for q, s, w in probes]
    monkeypatch.setattr(fp, "_FEW_SEGMENTS", 0)  # the NumPy branch for every window
    many = [p.project(q, from_s_m=max(s, 0.0), window_m=w) for q, s, w in probes]
    assert few == pytest.approx(many, abs=1e-9)
    assert sum(few[k] != few[k + 1] for k in range(0, len(few), 2)) > 50  # the windows did matter somewhere


def test_a_single_straight_leg_ends_at_its_end_and_brakes_to_it():
    p = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0]]), cruise_mps=10.0, accel_mps2=3.0)
    assert p.point_at(10.0)[0].tolist() == [10.0, 0.0, 5.0] and p.point_at(25.0)[0].tolist() == [10.0, 0.0, 5.0]
    assert p.speed_at(5.0) == pytest.approx(math.sqrt(2 * 3.0 * 5.0))  # braking to the end from 5 m out
    assert p.speed_at(9.5) == pytest.approx(math.sqrt(2 * 3.0 * 0.5))  # and in its last metre


def test_leg_headings_are_clockwise_from_north_for_legs_of_half_a_metre_or_more():
    wps = np.array([[0.0, 0.0], [0.0, -10.0], [0.0, -9.0], [0.5, -9.0], [0.5, -8.8]])  # W 10 m, E 1, N 0.5, E 0.2
    assert fp.leg_headings(wps) == pytest.approx([1.5 * math.pi, 1.5 * math.pi, 0.5 * math.pi, 0.0,
                                                 0.0])  # the 0.2 m leg keeps the heading before it
    assert fp.leg_headings(np.array([[1.0, 1.0]])).tolist() == [0.0]  # one waypoint: north


def _corner(turn_deg, leg_m):
    """Waypoints: ``leg_m`` north to a corner at (leg_m, 0), then ``leg_m`` turning right by ``turn_deg``."""
    out = np.array([math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg)), 0.0])
    corner = np.array([leg_m, 0.0, 5.0])
    return np.array([[0.0, 0.0, 5.0], corner, corner + leg_m * out]), corner, out


@pytest.mark.parametrize("turn_deg, leg_m, tangent_m", [
    (120.0, 40.0, 0.5 / (1 - math.cos(math.radians(60))) * math.tan(math.radians(60))),  # r = 1 m, 1.73 m out
    (60.0, 40.0, 0.5 / (1 - math.cos(math.radians(30))) * math.tan(math.radians(30))),  # r = 3.73 m, 2.15 m out
    (60.0, 2.0, 1.0),  # short legs: the tangent points at half the shorter leg
    (90.0, 0.8, 0.4),  # legs under a metre are rounded too
])
def test_any_corner_is_rounded_by_an_arc_tangent_to_both_legs_within_the_cut(turn_deg, leg_m, tangent_m):
    wps, corner, out = _corner(turn_deg, leg_m)
    p = fp.smooth_path(wps, corner_cut_m=0.5)
    u_in = np.array([1.0, 0.0, 0.0])
    assert p.points[1] == pytest.approx(corner - tangent_m * u_in)  # the arc leaves the first leg here
    assert p.points[-2] == pytest.approx(corner + tangent_m * out)  # and joins the second here
    half = math.radians(turn_deg) / 2
    radius_m = tangent_m / math.tan(half)
    cut_m = radius_m * (1 - math.cos(half))  # the arc's middle from both legs (0.5 m unless the legs are short)
    assert max(_distance_to_polyline(q, wps) for q in p.points) <= cut_m + 1e-9
    chords = np.linalg.norm(np.diff(p.points[1:-1], axis=0), axis=1)
    assert chords.min() > 0 and chords == pytest.approx(chords[0])  # evenly sampled, no repeated point
    assert len(p.waypoint_s_m) == 3  # one per waypoint; the corner's at the arc's middle (to half a sample)
    assert p.waypoint_s_m[1] == pytest.approx(0.5 * (p.s_m[1] + p.s_m[-2]), abs=0.5 * chords[0] + 1e-9)


def _box_room(lo, hi):
    """A room_fn for one box (north, east corners lo and hi): each point's horizontal distance to it."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return lambda p, alt: np.hypot(*np.maximum(np.maximum(lo - p, p - hi), 0.0).T)


# The L path turns round a building whose corner stands 6 m inside the turn: (14, 6) from the corner at (20, 0)
L_INSIDE = _box_room((-50.0, 6.0), (14.0, 50.0))


def test_a_corner_with_room_gets_a_wider_arc_that_keeps_the_margin_and_is_faster():
    plain = fp.smooth_path(L_PATH, corner_cut_m=0.5, cruise_mps=10.0, lateral_accel_mps2=3.0)
    wide = fp.smooth_path(L_PATH, corner_cut_m=0.5, cruise_mps=10.0, lateral_accel_mps2=3.0,
                          room_fn=L_INSIDE, room_m=5.0)
    assert L_INSIDE(wide.points[:, :2], 5.0).min() >= 5.0  # the whole margin, on the arc as on the legs
    assert wide.segment_speed_mps.min() > 2.0 * plain.segment_speed_mps.min()  # 2.3 -> 5.2 m/s here
    # the widest: one step (x1.25) wider would come within the margin
    radius = 3.0 * wide.segment_speed_mps.min() ** 2 / 3.0 / 3.0
    corner, u_in, u_out = L_PATH[1], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    wider = fp.widest_radius_m(corner, u_in, u_out, math.pi / 2, radius * 1.25, 1e3, L_INSIDE, 5.0)
    assert L_INSIDE(fp._arc(corner, u_in, u_out, math.pi / 2, radius * 1.25, 0.1)[:, :2], 5.0).min() < 5.0
    assert wider == pytest.approx(radius * 1.25)  # no wider one passes either: it starts there and stays


def test_a_corner_without_room_keeps_the_cut_and_one_with_plenty_stops_at_cruise_or_half_the_legs():
    tight = lambda p, alt: np.full(len(p), 4.9)  # noqa: E731  (already within the margin: no wider arc can do better)
    plain = fp.smooth_path(L_PATH, corner_cut_m=0.5)
    assert fp.smooth_path(L_PATH, corner_cut_m=0.5, room_fn=tight, room_m=5.0).points == pytest.approx(plain.points)
    open_air = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    long_l = L_PATH * [10.0, 10.0, 1.0]  # 200 m legs: cruise bounds the radius (v^2 / a = 100 / 3 m)
    p = fp.smooth_path(long_l, cruise_mps=10.0, lateral_accel_mps2=3.0, room_fn=open_air)
    assert p.segment_speed_mps.min() == pytest.approx(10.0)
    short = fp.smooth_path(L_PATH, cruise_mps=10.0, lateral_accel_mps2=3.0, room_fn=open_air)
    assert short.points[1] == pytest.approx([10.0, 0.0, 5.0])  # the tangent points at half of either leg
    assert short.points[-2] == pytest.approx([20.0, 10.0, 5.0])


def test_max_cut_bounds_how_far_a_widened_arc_leaves_its_legs():
    open_air = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    long_l = L_PATH * [10.0, 10.0, 1.0]
    p = fp.smooth_path(long_l, cruise_mps=10.0, lateral_accel_mps2=3.0, room_fn=open_air, max_cut_m=2.5)
    radius = 2.5 / (1 - math.cos(math.pi / 4))  # the arc whose middle is 2.5 m off both legs
    assert max(_distance_to_polyline(q, long_l) for q in p.points) <= 2.5 + 1e-9
    assert p.segment_speed_mps.min() == pytest.approx(math.sqrt(3.0 * radius), rel=1e-6)


#: Two 45 degree turns 4.95 m apart (grid pruning leaves such pairs where a route rounds a building's corner).
PAIR = np.array([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0], [53.5, 3.5, 5.0], [53.5, 50.0, 5.0]])


def test_a_close_pair_of_turns_the_same_way_is_flown_as_one_wider_corner():
    open_air = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    p = fp.smooth_path(PAIR, cruise_mps=10.0, lateral_accel_mps2=3.0, room_fn=open_air, room_m=5.0, max_cut_m=2.5)
    apart = math.sqrt(3.0 * 0.5 * math.dist(PAIR[1], PAIR[2]) / math.tan(math.radians(22.5)))  # 4.2 m/s each
    assert p.segment_speed_mps.min() > 1.3 * apart  # 5.7 m/s: 2.5 m off the pair's legs
    assert max(_distance_to_polyline(q, PAIR) for q in p.points) <= 2.5 + 1e-9  # max_cut from the pair's own legs
    assert len(p.waypoint_s_m) == 4 and p.waypoint_s_m[1] == p.waypoint_s_m[2]  # both passed at the one corner
    assert p.points[0].tolist() == PAIR[0].tolist() and p.points[-1].tolist() == PAIR[-1].tolist()


def test_a_pair_is_not_merged_across_a_jog_or_where_no_merged_arc_keeps_the_margin():
    jog = PAIR * [1.0, 1.0, 1.0]
    jog[3] = [100.0, 3.5, 5.0]  # the second turn goes back the other way: a jog, two corners
    open_air = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    assert len(fp._merge_close_pairs(jog[:, :3], open_air, 5.0, math.inf)) == 4
    cramped = lambda p, alt: np.full(len(p), 4.9)  # noqa: E731  (no arc keeps the margin)
    assert len(fp._merge_close_pairs(PAIR, cramped, 5.0, math.inf)) == 4
    assert len(fp._merge_close_pairs(PAIR, open_air, 5.0, math.inf)) == 3


def test_a_climbing_corner_is_not_widened():
    climb = np.array([[0.0, 0.0, 5.0], [20.0, 0.0, 5.0], [20.0, 20.0, 15.0]])
    open_air = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    assert fp.smooth_path(climb, room_fn=open_air).points == pytest.approx(fp.smooth_path(climb).points)


def test_one_waypoint_gives_one_point_and_one_waypoint_arc_length():
    p = fp.smooth_path(np.array([[3.0, 4.0, 5.0]]))
    assert p.points.tolist() == [[3.0, 4.0, 5.0]] and p.waypoint_s_m.tolist() == [0.0]


def test_short_steep_segments_are_held_to_the_vertical_speed():
    # 0.5 m along and 0.5 m up: the vertical limit (1.5 m/s up) allows 1.5 x 0.707 / 0.5 = 2.12 m/s along it
    p = fp.smooth_path(np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.5]]), vertical_mps=1.5, cruise_mps=10.0)
    assert p.segment_speed_mps == pytest.approx([1.5 * math.sqrt(0.5) / 0.5])
    # a level leg, then a climbing one: each segment judged by its own climb
    p = fp.smooth_path(np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0], [80.0, 0.0, 30.0]]), vertical_mps=1.5,
                       cruise_mps=10.0)
    assert p.segment_speed_mps[0] == 10.0 and p.segment_speed_mps[-1] == pytest.approx(1.5 * 50.0 / 30.0)
    assert p.point_speed_mps[0] == 10.0  # the start: the first segment's speed


def test_braking_is_planned_back_over_every_point_before_a_slow_part():
    # a collinear waypoint at 10 m, then the right angle at 20 m: braking for the arc starts before the waypoint
    p = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [20.0, 0.0, 5.0], [20.0, 20.0, 5.0]]),
                       corner_cut_m=0.5, cruise_mps=10.0, accel_mps2=3.0, lateral_accel_mps2=3.0)
    r = 1.0 + 1.0 / math.sqrt(2)
    v_turn = math.sqrt(3.0 * r)
    assert p.speed_at(5.0) == pytest.approx(math.sqrt(v_turn**2 + 2 * 3.0 * (20.0 - r - 5.0)))
    assert p.speed_at(12.0) == pytest.approx(math.sqrt(v_turn**2 + 2 * 3.0 * (20.0 - r - 12.0)))
    # a collinear waypoint 1 m before the goal: braking to the goal starts before it
    p = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [11.0, 0.0, 5.0]]), accel_mps2=3.0)
    assert p.speed_at(5.0) == pytest.approx(math.sqrt(2 * 3.0 * 6.0))
    # a steep climb first, then two level legs: the level legs are not held to the climb's speed
    p = fp.smooth_path(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 3.0], [40.0, 0.0, 3.0], [40.0, 40.0, 3.0]]),
                       corner_cut_m=0.5, cruise_mps=10.0, accel_mps2=3.0, lateral_accel_mps2=3.0)
    arc_s = p.waypoint_s_m[2] - 3 * 2 * r * math.sin(math.radians(7.5))  # where the second corner's arc starts
    assert p.speed_at(arc_s - 5.0) == pytest.approx(math.sqrt(v_turn**2 + 2 * 3.0 * 5.0))


def test_where_the_path_passes_over_itself_the_first_pass_counts():
    # out 10 m north and straight back (a reversal keeps its corner): (5, 0) is on both passes
    p = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [0.0, 0.0, 5.0]]))
    assert p.length_m == pytest.approx(20.0)
    assert p.project((5.0, 0.0, 5.0)) == pytest.approx(5.0)  # the outbound pass, not the return at 15 m
    assert p.project((5.0, 0.0, 5.0), from_s_m=10.0) == pytest.approx(15.0)  # once past the turn: the return


# ------------------------------------------------------------------------------------------- steering
def test_steer_leads_by_the_round_trip():
    # 100 m straight north at 10 m/s; the vehicle at 20 m, moving at 8 m/s
    path = fp.smooth_path(np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0]]), cruise_mps=10.0, accel_mps2=3.0)
    kwargs = dict(s_m=20.0, ref_s_m=0.0, position=(20.0, 0.0, 10.0), velocity=(8.0, 0.0, 0.0), accel_mps2=3.0,
                  velocity_lag_s=0.0, heading_rad=0.0)
    near = fw.steer(path, ahead_s=0.2, **kwargs)
    slow_link = fw.steer(path, ahead_s=0.2 + 0.4, **kwargs)  # a 400 ms round trip
    assert near.position[0] == pytest.approx(20.0 + 8.0 * 0.2)
    assert slow_link.position[0] == pytest.approx(20.0 + 8.0 * 0.6)  # where it will be when the command lands
    assert np.linalg.norm(near.velocity) == pytest.approx(8.0 + 3.0 * 0.2)  # speeding up at 3 m/s^2


def test_steer_under_a_speed_cap_below_the_schedule_commands_the_cap_and_no_lead():
    # the same vehicle at 8 m/s; the mission may fly 5 m/s here (what its sensor has seen free ahead)
    path = fp.smooth_path(np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0]]), cruise_mps=10.0, accel_mps2=3.0)
    kwargs = dict(s_m=20.0, ref_s_m=0.0, position=(20.0, 0.0, 10.0), velocity=(8.0, 0.0, 0.0), accel_mps2=3.0,
                  velocity_lag_s=0.0, heading_rad=0.0, ahead_s=0.6)
    capped = fw.steer(path, speed_cap_mps=5.0, **kwargs)
    assert np.linalg.norm(capped.velocity) == pytest.approx(2.0)  # 3 m/s over the cap: told 3 m/s under it
    assert capped.position[0] == pytest.approx(20.0)  # a target ahead would pull it on at its own speed
    slower = fw.steer(path, speed_cap_mps=5.0, **{**kwargs, "velocity": (4.0, 0.0, 0.0)})
    assert np.linalg.norm(slower.velocity) == pytest.approx(5.0)  # under the cap: speeding up to it, no more
    loose = fw.steer(path, speed_cap_mps=12.0, **kwargs)  # above the schedule: as without a cap
    assert loose.position[0] == pytest.approx(fw.steer(path, **kwargs).position[0]) == pytest.approx(24.8)
    assert np.linalg.norm(fw.steer(path, speed_cap_mps=0.0, **kwargs).velocity) == 0.0


def test_steer_under_a_speed_cap_still_aims_where_the_vehicle_will_be_when_a_slow_link_delivers():
    # the same, with 0.4 s of the 0.6 s lead the link's round trip: the target no lead beyond that, but that much
    path = fp.smooth_path(np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0]]), cruise_mps=10.0, accel_mps2=3.0)
    kwargs = dict(s_m=20.0, ref_s_m=0.0, position=(20.0, 0.0, 10.0), velocity=(4.0, 0.0, 0.0), accel_mps2=3.0,
                  velocity_lag_s=0.0, heading_rad=0.0, ahead_s=0.6, speed_cap_mps=5.0)
    assert fw.steer(path, delay_s=0.4, **kwargs).position[0] == pytest.approx(20.0 + 4.0 * 0.4)
    assert fw.steer(path, delay_s=0.0, **kwargs).position[0] == pytest.approx(20.0)  # behind it by then: a drag
    assert fw.steer(path, delay_s=0.4, **{**kwargs, "speed_cap_mps": 12.0}).position[0] == pytest.approx(22.4)


def test_the_prediction_over_a_link_without_delay_is_the_measurement():
    p, v = fw.predict_over_link((1.0, 2.0, 5.0), (3.0, 0.0, 0.0), [(0.0, (9.0, 0.0, 0.0))], now_s=0.0, rate=1.0,
                                down_s=0.0, up_s=0.0, response_s=0.6, accel_mps2=3.0)
    assert p.tolist() == [1.0, 2.0, 5.0] and v.tolist() == [3.0, 0.0, 0.0]


def test_over_a_slow_link_the_vehicle_is_predicted_to_fly_the_commands_already_sent():
    # measured at 10 m/s north half a second ago; for the last second it was told 4 m/s (arriving half a second
    # after they were sent, at 5x: rate 5 turns our 0.2 s into the autopilot's 1 s)
    sent = [(-0.2, (4.0, 0.0, 0.0)), (-0.1, (4.0, 0.0, 0.0))]
    p, v = fw.predict_over_link((0.0, 0.0, 5.0), (10.0, 0.0, 0.0), sent, now_s=0.0, rate=5.0, down_s=0.5,
                                up_s=0.5, response_s=0.6, accel_mps2=3.0)
    assert v[0] == pytest.approx(10.0 - 3.0 * 1.0, abs=0.05)  # slowing at the most it can, the whole second
    assert p[0] == pytest.approx(10.0 * 1.0 - 0.5 * 3.0 * 1.0**2, abs=0.1)  # not the 10 m the measurement says
    held, _ = fw.predict_over_link((0.0, 0.0, 5.0), (10.0, 0.0, 0.0), [], now_s=0.0, rate=5.0, down_s=0.5,
                                   up_s=0.5, response_s=0.6, accel_mps2=3.0)
    assert held[0] == pytest.approx(10.0)  # nothing sent yet: it keeps its measured velocity


def test_the_commands_kept_for_the_prediction_start_with_the_one_in_effect():
    sent = fw.SentCommands()
    for t in (0.0, 0.1, 0.2, 0.3):
        sent.add(t, (t, 0.0, 0.0))
    sent.add(0.4, None)
    sent.drop_older(0.25)
    assert [t for t, _ in sent.commands] == [0.2, 0.3, 0.4]  # 0.2 was still in effect at 0.25
    assert sent.commands[-1][1] is None


def fly_behind_a_slow_link(predict: bool, one_way_s: float = 1.0, cap_mps: float = 6.0, seconds: float = 60.0):
    """Speeds (m/s, each 0.1 s) of a PX4-like vehicle (velocity = feed-forward + 0.95 /s x position error, a
    0.6 s lag, 3 m/s^2 at most) steered along a straight 1 km path under a sight cap, ``one_way_s`` each way."""
    path = fp.smooth_path(np.array([[0.0, 0.0, 5.0], [1000.0, 0.0, 5.0]]), cruise_mps=12.0, accel_mps2=3.0)
    dt, lag = 0.1, round(one_way_s / 0.1)
    pos, vel = np.array([0.0, 0.0, 5.0]), np.zeros(3)
    states, setpoints = [], []  # every step's measurement and setpoint: each reaches the other end lag steps on
    target, ff = pos.copy(), np.zeros(3)
    sent, ref_s, previous, speeds = fw.SentCommands(), 0.0, 0.0, []
    for k in range(int(seconds / dt)):
        now = k * dt
        states.append((pos.copy(), vel.copy()))
        seen_p, seen_v = states[max(len(states) - 1 - lag, 0)]
        rtt = 2 * one_way_s
        if predict:
            sent.drop_older(now - rtt - dt)
            at, at_v = fw.predict_over_link(seen_p, seen_v, sent.commands, now_s=now, rate=1.0, down_s=one_way_s,
                                            up_s=one_way_s, response_s=0.6, accel_mps2=3.0)
            ahead, delay = 0.2 + dt, dt
        else:
            at, at_v, ahead, delay = seen_p, seen_v, 0.2 + dt + rtt, dt + rtt
        sp = fw.steer(path, s_m=path.project(seen_p, 0.0), ref_s_m=ref_s, position=at, velocity=at_v,
                      ahead_s=ahead, accel_mps2=3.0, velocity_lag_s=0.15, heading_rad=0.0, previous_mps=previous,
                      dt_s=dt, speed_cap_mps=cap_mps, delay_s=delay)
        ref_s, previous = sp.ref_s, float(np.linalg.norm(sp.velocity)) if sp.velocity is not None else 0.0
        sent.add(now, sp.velocity)
        setpoints.append(sp)
        if k >= lag:
            arrived = setpoints[k - lag]
            target, ff = arrived.position, (np.zeros(3) if arrived.velocity is None else arrived.velocity)
        want = ff + 0.95 * (target - pos)
        dv = (want - vel) * dt / 0.6
        dv *= min(1.0, 3.0 * dt / max(float(np.linalg.norm(dv)), 1e-9))
        vel = vel + dv
        pos = pos + vel * dt
        speeds.append(float(np.linalg.norm(vel)))
    return np.array(speeds)


def test_a_slow_link_does_not_make_the_speed_swing_under_the_sight_cap():
    # a second each way (200 ms at 5x): steered from the measured state, the position loop closed over the round
    # trip and the speed swung 0-11 m/s round a 6 m/s cap (the fault campaign's latency flights, 3.5 m from a
    # building); flown on the commands already sent it settles at the cap
    settled = fly_behind_a_slow_link(predict=True)[200:]
    assert settled.max() < 6.0 + 0.5 and settled.min() > 6.0 - 1.0
    assert fly_behind_a_slow_link(predict=True, one_way_s=0.0)[200:].max() < 6.5  # no delay: the same


class CoastLimits:
    """ArduCopter-like: 3 s of coasting on the last velocity, then braking at 2.5 m/s^2."""

    cruise_mps, accel_mps2, link_loss, leaves_flying = math.inf, math.inf, "hovers", True
    hold_s, brake_mps2 = 3.0, 2.5

    def coast_m(self, v):
        return v * self.hold_s + v * v / (2 * self.brake_mps2)

    def speed_for_clearance_mps(self, c):  # solves v T + v^2 / 2a = c (quadratic formula, written out here)
        a, t = self.brake_mps2, self.hold_s
        return max(0.0, (-t + math.sqrt(t * t + 2.0 * c / a)) * a)


def wall_north_at(wall_n_m):
    """A clearance function: a wall across the map at north = ``wall_n_m`` (rays east or west are clear)."""

    def clearance(n, e, alt, dn, de, max_m):
        if dn <= 1e-9:
            return max_m
        return max(0.0, min(max_m, (wall_n_m - n) / dn))

    return clearance


def test_feedforward_is_capped_so_its_coast_stops_short_of_the_wall():
    limits = CoastLimits()
    cap = fw.feedforward_cap_mps(limits, wall_north_at(50.0), (20.0, 0.0, 10.0), np.array([1.0, 0.0, 0.0]), 10.0)
    assert limits.coast_m(cap) == pytest.approx(30.0)  # exactly the 30 m that are clear
    assert fw.feedforward_cap_mps(limits, wall_north_at(50.0), (20.0, 0.0, 10.0), np.array([0.0, 1.0, 0.0]),
                                  10.0) == 10.0  # along the wall: nothing to fear
    assert fw.feedforward_cap_mps(None, None, (0, 0, 0), np.array([1.0, 0.0, 0.0]), 10.0) == 10.0


def test_steer_never_sends_a_feedforward_that_could_coast_into_a_building():
    # 200 m north towards a wall at 150 m: at every point the command's coast ends short of the wall
    path = fp.smooth_path(np.array([[0.0, 0.0, 10.0], [200.0, 0.0, 10.0]]), cruise_mps=10.0, accel_mps2=3.0)
    limits = CoastLimits()
    for n in np.arange(0.0, 140.0, 5.0):
        sp = fw.steer(path, s_m=n, ref_s_m=0.0, position=(n, 0.0, 10.0), velocity=(10.0, 0.0, 0.0), ahead_s=0.3,
                      accel_mps2=3.0, velocity_lag_s=0.15, heading_rad=0.0, limits=limits,
                      clearance_fn=wall_north_at(150.0))
        reach_n = sp.position[0] + limits.coast_m(float(np.linalg.norm(sp.velocity)))
        assert reach_n <= 150.0 + 1e-6


# ---------------------------------------------------------------------------------------- fake vehicle
class FakeClock:
    """Monotonic time that only moves when ``sleep`` is called; ``at(t, fn)`` runs ``fn`` once t is passed."""

    def __init__(self):
        self.now = 0.0
        self.tickers = []
        self._events = []

    def __call__(self):
        return self.now

    def at(self, t, fn):
        self._events.append((t, fn))

    def sleep(self, dt):
        self.now += dt
        for tick in self.tickers:
            tick(dt)
        due = [e for e in self._events if e[0] <= self.now]
        self._events = [e for e in self._events if e[0] > self.now]
        for _, fn in due:
            fn()


class Refused(Exception):
    """Stands in for vehicle.VehicleError; ``permanent`` like a DENIED answer."""

    def __init__(self, text, permanent=False):
        super().__init__(text)
        self.permanent = permanent


@dataclass
class FakeTelemetry:
    armed: bool = False
    mode: str = "manual"
    lat_deg: float = ORIGIN.lat_deg
    lon_deg: float = ORIGIN.lon_deg
    amsl_at_zero_m: float = GROUND_AMSL_M  # AMSL altitude of local down = 0
    north_m: float = 0.0
    east_m: float = 0.0
    down_m: float = 0.0
    local_v_north_mps: float = 0.0
    local_v_east_mps: float = 0.0
    local_v_down_mps: float = 0.0
    local_time_s: float = math.nan
    on_ground: bool = True

    @property
    def alt_amsl_m(self):
        return self.amsl_at_zero_m - self.down_m


@dataclass
class FakeReadiness:
    missing: tuple

    @property
    def ready(self):
        return not self.missing

    def describe(self):
        return "ready" if self.ready else "waiting for " + ", ".join(self.missing)


@dataclass(frozen=True)
class Kind:
    value: str


KINDS = {"offboard": "ours", "hold": "hold", "land": "return", "rtl": "return", "return-hover": "return",
         "posctl": "pilot"}


class FakeVehicle:
    """A point that flies to its local setpoint at ``speed_mps`` in mode "offboard", lands at 1.5 m/s in "land",
    stays put otherwise; failure knobs below. Only the map offset's horizontal part is fixed (OFFSET)."""

    def __init__(self, clock, *, start=(0.0, 0.0), speed_mps=5.0, arm_refusals=0, climbs=True, ready_at_s=0.0,
                 land_drift_mps=0.0, lowest_down_m=math.inf):
        self.clock = clock
        self.lowest_down_m = lowest_down_m  # local down it cannot go below in our mode (something under it)
        self.land_drift_mps = land_drift_mps  # north, while landing (PX4 SIH's landing wanders off its point)
        clock.tickers.append(self._step)
        self.telemetry = FakeTelemetry(north_m=start[0], east_m=start[1])
        self.link_ok = True
        self.round_trip_s = 0.0
        self.speed_mps = speed_mps
        self.arm_refusals = arm_refusals
        self.arm_permanent = False
        self.disarm_refusals = 0
        self.climbs = climbs
        self.ready_at_s = ready_at_s
        self.hint = None  # failsafe_hint(): a failsafe on our side
        self.own = None  # own_failsafe(): the autopilot's words for a failsafe of its own
        self.limits = CoastLimits()
        self.limits.leaves_flying = False
        self.setpoint = None
        self.calls: list[str] = []
        self.gotos: list[tuple[float, float, float, float]] = []
        self.velocities: list[tuple[float, float, float] | None] = []
        self.accelerations: list[tuple[float, float, float] | None] = []
        self.feedforward = None
        self.grounds: list[float] = []
        self.fail_on = {}  # method name -> exception to raise (once, or always if the key ends in "!")

    @property
    def mode(self):
        return self.telemetry.mode

    @mode.setter
    def mode(self, value):
        self.telemetry.mode = value

    def _maybe_fail(self, name):
        self.calls.append(name)
        if not self.link_ok:
            raise Refused(f"{name}: link lost")
        exc = self.fail_on.pop(name, None) or self.fail_on.get(name + "!")
        if exc is not None:
            raise exc

    # state
    @property
    def in_control(self):
        return self.mode == "offboard"

    def mode_kind(self):
        return Kind(KINDS.get(self.mode, "other"))

    def readiness(self):
        return FakeReadiness(() if self.clock.now >= self.ready_at_s else ("a global position estimate",))

    def failsafe_hint(self, *, texts=True):
        # the generic-text rule, as the real vehicle words it: a text about our link counts either way
        generic = (self.hint or "").startswith("the autopilot said") and not names_our_link(self.hint)
        return self.hint if texts or not generic else None

    def own_failsafe(self):
        return self.own

    def map_offset(self, map_origin, ground_amsl_m):
        assert map_origin == ORIGIN
        self.grounds.append(ground_amsl_m)
        t = self.telemetry
        return LocalNED(OFFSET.north_m, OFFSET.east_m, -(t.alt_amsl_m - ground_amsl_m) - t.down_m)

    def flight_limits(self):
        self.calls.append("flight_limits")
        return self.limits

    # actions
    def prepare_flight(self):
        self._maybe_fail("prepare_flight")
        t = self.telemetry
        self.mode, self.setpoint, self.feedforward = "offboard", (t.north_m, t.east_m, t.down_m), None

    def take_control(self):
        self._maybe_fail("take_control")
        self.mode = "offboard"

    def arm(self):
        self._maybe_fail("arm")
        if self.arm_refusals > 0:
            self.arm_refusals -= 1
            raise Refused("COMPONENT_ARM_DISARM rejected: TEMPORARILY_REJECTED: Preflight Fail: ekf2 not ready",
                          permanent=self.arm_permanent)
        self.telemetry.armed = True

    def disarm(self):
        self._maybe_fail("disarm")
        if self.disarm_refusals > 0:
            self.disarm_refusals -= 1
            raise Refused("disarm refused: not landed")
        self.telemetry.armed = False

    def takeoff(self, altitude_m):
        self._maybe_fail("takeoff")
        t = self.telemetry
        self.mode, self.setpoint, self.feedforward = "offboard", (t.north_m, t.east_m, t.down_m - altitude_m), None
        return LocalNED(*self.setpoint)

    def goto_local(self, north_m, east_m, down_m, yaw_rad, velocity_ned=None, accel_ned=None):
        self._maybe_fail("goto_local")
        self.gotos.append((north_m, east_m, down_m, yaw_rad))
        self.velocities.append(velocity_ned)
        self.accelerations.append(accel_ned)
        self.setpoint = (north_m, east_m, down_m)
        self.feedforward = velocity_ned

    def land(self):
        self._maybe_fail("land")
        self.mode = "land"

    def hold(self):
        self._maybe_fail("hold")
        self.mode = "hold"

    def release_control(self):
        if self.link_ok:
            self._maybe_fail("release_control")
        else:  # as the link's: the stream stops here, whatever the link
            self.calls.append("release_control")
        self.setpoint = None

    def _step(self, dt):
        t = self.telemetry
        t.local_v_north_mps = t.local_v_east_mps = t.local_v_down_mps = 0.0
        if not t.armed:
            return
        if self.mode == "offboard" and self.setpoint is not None:
            target = np.array(self.setpoint)
            if not self.climbs:
                target[2] = t.down_m
            here = np.array([t.north_m, t.east_m, t.down_m])
            delta = target - here
            dist = float(np.linalg.norm(delta))
            step = min(dist, self.speed_mps * dt)
            if self.feedforward is not None:  # like PX4: feed-forward + 1/s x position error, capped
                velocity = np.array(self.feedforward) + delta
                if not self.climbs:
                    velocity[2] = 0.0
                speed = float(np.linalg.norm(velocity))
                if speed > self.speed_mps:
                    velocity *= self.speed_mps / speed
                t.north_m, t.east_m, t.down_m = here + velocity * dt
                t.local_v_north_mps, t.local_v_east_mps, t.local_v_down_mps = velocity
            elif dist > 0:
                velocity = delta / dist * step / dt
                t.north_m, t.east_m, t.down_m = here + delta / dist * step
                t.local_v_north_mps, t.local_v_east_mps, t.local_v_down_mps = velocity
            if t.down_m > self.lowest_down_m:
                t.down_m, t.local_v_down_mps = self.lowest_down_m, 0.0
        elif self.mode.lower() in ("land", "rtl") and t.down_m < 0:  # a return, simplified: down where it is
            t.down_m = min(0.0, t.down_m + 1.5 * dt)
            t.local_v_down_mps = 1.5
            t.north_m += self.land_drift_mps * dt
        t.on_ground = t.down_m >= 0.0


def straight_plan(calls):
    """A plan_fn: from the start (map frame) 60 m north, then 40 m east, at 10 m; records its arguments."""

    def plan(start_north_m, start_east_m):
        calls.append((start_north_m, start_east_m))
        return np.array([
            [start_north_m, start_east_m, 10.0, 0.0],
            [start_north_m + 30, start_east_m, 10.0, 0.0],  # collinear: flown through
            [start_north_m + 60, start_east_m, 10.0, 0.0],
            [start_north_m + 60, start_east_m + 40, 10.0, 0.0],
        ])

    return plan


def fixed_plan(calls):
    """A plan_fn to the fixed goal map (60 N, 40 E) at 10 m, via (60 N, start E): replans end at the same goal."""

    def plan(start_north_m, start_east_m):
        calls.append((start_north_m, start_east_m))
        return np.array([[start_north_m, start_east_m, 10.0, 0.0], [60.0, start_east_m, 10.0, 0.0],
                         [60.0, 40.0, 10.0, 0.0]])

    return plan


def make_mission(vehicle, clock, plan_fn, *, vehicle_errors=(Refused,), **kwargs):
    """Mission is told what a refusal looks like (``Refused`` stands in for vehicle.VehicleError)."""
    kwargs.setdefault("altitude_m", 10.0)
    return m.Mission(vehicle, plan_fn, map_origin=ORIGIN, vehicle_errors=vehicle_errors, clock=clock,
                     sleep=clock.sleep, **kwargs)


@pytest.fixture
def clock():
    return FakeClock()


class _Observed:
    """Observed obstacles as a mission without a sensor sees them: only their ``version``."""

    version = 0

    def discovered_ne(self):
        return np.empty((0, 2))


@pytest.mark.parametrize("told", [True, False])
def test_widened_corners_are_rounded_again_when_an_obstacle_is_observed_beside_them(clock, told):
    """straight_plan's corner (60 N, 0 E) in open air gets a 20 m arc (half the legs); a post observed inside
    the turn, 6 m off both legs, stands by that arc. Told (the obstacles' version changes), the mission rounds the
    corner again within the margin; not told, it flies the old arc into the post (the test's control)."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))  # = map (0, 0)
    posts, observed = [], _Observed()

    def room(p, alt):
        return np.full(len(p), np.inf) if not posts else _box_room(*posts[0])(p, alt)

    def observe(dt):
        if not posts and v.telemetry.north_m + OFFSET.north_m > 20.0:
            posts.append(((50.0, 6.0), (54.0, 8.0)))
            observed.version += told

    clock.tickers.append(observe)
    result = make_mission(v, clock, straight_plan([]), room_fn=room, obstacles=observed).run()
    assert result.completed and posts
    clearance = float(room(result.track[:, 1:3], 10.0).min())
    if told:
        assert clearance >= 5.0 - 1.0  # the margin, less what the fake's lag cuts (4.3 m)
    else:
        assert clearance < 2.5  # 1.6 m


def test_rounding_again_far_along_a_long_leg_keeps_the_vehicle_going_forward(clock):
    """Rounded again 70 m along a 100 m leg (beyond the 30 m that progress is usually searched within), the
    vehicle carries on from where it is: it never turns back."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))  # = map (0, 0)
    observed, seen_at = _Observed(), []

    def plan(n, e):
        return np.array([[n, e, 10.0, 0.0], [n + 100.0, e, 10.0, 0.0], [n + 100.0, e + 40.0, 10.0, 0.0]])

    def observe(dt):
        if not seen_at and v.telemetry.north_m + OFFSET.north_m > 70.0:
            seen_at.append(clock.now)
            observed.version += 1

    clock.tickers.append(observe)
    room = lambda p, alt: np.full(len(p), np.inf)  # noqa: E731
    result = make_mission(v, clock, plan, room_fn=room, obstacles=observed).run()
    assert result.completed and seen_at
    north = result.track[result.track[:, 0] >= seen_at[0], 1]
    assert np.all(np.diff(north) >= -0.05)


# ------------------------------------------------------------------------------------------- the flow
def test_full_mission(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))  # = map (0, 0): OFFSET is (100, -50)
    planned, lines = [], []
    result = make_mission(v, clock, straight_plan(planned), progress=lines.append).run()
    assert planned == [(pytest.approx(0.0), pytest.approx(0.0))]  # start converted to the map frame
    assert result.completed and result.final_state is S.MANUAL
    assert [h[2] for h in result.history] == [S.PREFLIGHT, S.PLANNING, S.ARMING, S.TAKEOFF, S.WAYPOINT,
                                              S.WAYPOINT, S.WAYPOINT, S.LANDING, S.DISARMING, S.MANUAL]
    # commanded in the autopilot's local frame: map - offset; heading along each leg; over the goal at 10 m, then
    # down over it to 1.5 m before the autopilot's landing takes over
    assert (60 - 100, 40 + 50, -10.0, math.pi / 2) in [pytest.approx(g) for g in v.gotos]
    assert v.gotos[-1] == pytest.approx((60 - 100, 40 + 50, -1.5, math.pi / 2), abs=0.05)
    assert v.gotos[1][3] == pytest.approx(0.0)
    assert not v.telemetry.armed and v.telemetry.on_ground and v.setpoint is None
    assert v.calls[-3:] == ["land", "disarm", "release_control"]
    assert result.landing_error_m < 0.3
    assert result.planned_length_m == pytest.approx(10 + 100 + 10)
    # flown: the last metre of the climb blends into the first leg (altitude tolerance 1 m) and the 90 deg
    # corner is rounded by an arc 0.5 m inside it: shorter than planned by a couple of metres, never longer
    assert 117.0 <= result.flown_length_m <= 120.0
    # climb, legs, our descent to 1.5 m at 1 m/s, the autopilot's landing
    assert result.flight_time_s == pytest.approx(10 / 5.0 + 100 / 5.0 + 8.5 / 1.0 + 1.5 / 1.5, abs=0.5)
    assert result.track.shape[1] == 4 and result.track[-1, 1:3] == pytest.approx([60.0, 40.0], abs=0.3)
    assert "planned 120.0 m" in result.summary() and "from the goal" in result.summary()
    # no silent steps: planning, the takeoff, each waypoint with the distance to go and the speed, the goal
    assert any(line.startswith("planning from map (0.0 N, 0.0 E)") for line in lines)
    assert any(line.startswith("taking off to 10.0 m") for line in lines)
    waypoint_lines = [line for line in lines if line.startswith("waypoint ")]
    assert len(waypoint_lines) == 2 and re.match(r"waypoint 1/3 reached: \d+ m to go at [\d.]+ m/s", waypoint_lines[0])
    assert any(line.startswith("goal reached") for line in lines)


def test_the_order_is_plan_then_mode_then_arm_then_takeoff_at_once(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    plans = []

    def plan(n, e):
        plans.append(list(v.calls))  # what had been called when the planner ran
        return straight_plan([])(n, e)

    make_mission(v, clock, plan).run()
    assert "arm" not in plans[0] and "prepare_flight" not in plans[0]  # planned before anything was commanded
    first = v.calls.index("prepare_flight")
    assert v.calls[first:first + 3] == ["prepare_flight", "arm", "takeoff"]  # nothing between arming and takeoff


def test_airborne_time_is_in_the_autopilots_clock_from_liftoff_to_touchdown(clock):
    # A simulator at 10x: the autopilot's time since boot runs ten times faster than ours.
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.tickers.append(lambda dt: setattr(v.telemetry, "local_time_s", 10.0 * clock.now))
    v.telemetry.local_time_s = 0.0
    takeoff_at, liftoff_at = [], []
    original_takeoff = v.takeoff
    v.takeoff = lambda alt: (takeoff_at.append(clock.now), original_takeoff(alt))[1]
    clock.tickers.append(lambda dt: liftoff_at.append(clock.now) if -v.telemetry.down_m > 0.1 and not liftoff_at
                         else None)
    result = make_mission(v, clock, straight_plan([])).run()
    touchdown_at = result.track[-1, 0]
    assert result.flight_time_s == pytest.approx(10.0 * (touchdown_at - takeoff_at[0]), abs=1.0)
    assert result.airborne_s == pytest.approx(10.0 * (touchdown_at - liftoff_at[0]), abs=0.5)
    assert result.airborne_s < result.flight_time_s


def test_landing_error_is_measured_to_the_goal_not_to_the_routes_end(clock):
    # a route that ends 1 m from the goal the user gave (beyond the goal's cell: it is landed at its end)
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([]), goal_ne=(60.0, 41.0)).run()
    assert result.landing_error_m == pytest.approx(1.0, abs=0.05)


# ---------------------------------------------------------------------------------------- before takeoff
def test_waits_for_the_vehicle_to_get_ready_with_progress_lines(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), ready_at_s=12.0)
    lines = []
    result = make_mission(v, clock, straight_plan([]), progress=lines.append, progress_every_s=5.0).run()
    assert result.completed
    waiting = [line for line in lines if line.startswith("waiting for a global position estimate")]
    assert len(waiting) == 3  # at 1, 6 and 11 s: one line every 5 s, not one a poll, none once it is ready
    assert v.calls.index("prepare_flight") > 0 and clock.now > 12.0


def test_a_vehicle_that_never_gets_ready_is_never_armed(clock):
    v = FakeVehicle(clock, ready_at_s=1e9)
    planned = []
    with pytest.raises(m.NotReady, match="did not get ready within 20 s: waiting for a global position") as err:
        make_mission(v, clock, straight_plan(planned), arm_timeout_s=20.0).run()
    assert clock.now == pytest.approx(20.0, abs=0.3)
    assert not planned and "arm" not in v.calls and "prepare_flight" not in v.calls
    assert err.value.result.final_state is S.MANUAL


def test_a_vehicle_already_in_the_air_is_refused(clock):
    v = FakeVehicle(clock)
    v.telemetry.on_ground, v.telemetry.down_m = False, -20.0
    with pytest.raises(m.NotReady, match="in the air"):
        make_mission(v, clock, straight_plan([])).run()
    assert "arm" not in v.calls


def test_map_altitudes_are_above_the_maps_ground_not_the_vehicles_start(clock):
    # the vehicle stands on an 8 m roof: its GPS says 12 + 8 m AMSL, the map shows the roof under it
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.amsl_at_zero_m = GROUND_AMSL_M + 8.0
    result = make_mission(v, clock, straight_plan([]), surface_fn=lambda n, e: 8.0 if abs(n) < 1 else 0.0).run()
    assert v.grounds == [pytest.approx(GROUND_AMSL_M)]
    assert result.completed
    # flown at 10 m above the map's ground: 2 m above the roof it started on (local down -2 m); come down over the
    # goal, never below 1.5 m above the street there (local down +6.5 m; this fake lands at its roof's level)
    assert min(g[2] for g in v.gotos) == pytest.approx(-2.0)
    assert -0.5 < v.gotos[-1][2] <= 6.5 + 0.05


def test_the_maps_ground_altitude_can_be_given(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    make_mission(v, clock, straight_plan([]), ground_amsl_m=GROUND_AMSL_M - 3.0).run()
    assert v.grounds == [GROUND_AMSL_M - 3.0]  # the vehicle stands 3 m above the map's ground
    assert min(g[2] for g in v.gotos) == pytest.approx(-10.0 + 3.0)


def test_speeds_are_fitted_to_the_autopilots_limits_and_a_hovering_failsafe_is_warned_about(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.limits.cruise_mps, v.limits.accel_mps2, v.limits.leaves_flying = 4.0, 2.5, True
    v.limits.lateral_accel_mps2 = 1.5
    v.limits.link_loss = "a lost link leaves the vehicle hovering"
    lines = []
    mission = make_mission(v, clock, straight_plan([]), progress=lines.append, cruise_mps=10.0, accel_mps2=3.0)
    mission.run()
    assert mission.speeds.cruise_mps == pytest.approx(4.0) and mission.speeds.accel_mps2 == pytest.approx(2.25)
    assert mission.speeds.lateral_accel_mps2 == pytest.approx(1.5)
    assert "warning: a lost link leaves the vehicle hovering" in lines
    speeds = [math.hypot(vn, ve) for vn, ve, _ in (x for x in v.velocities if x is not None)]
    assert max(speeds) <= 4.0 + 1e-9


class _LeansIntoDrag(FakeVehicle):
    """Reports the attitude a multicopter with a drag of 1/s holds at its velocity (leaning ``v`` m/s^2 into it)."""

    def _step(self, dt):
        t = self.telemetry
        before = np.array([t.local_v_north_mps, t.local_v_east_mps])
        super()._step(dt)
        v = np.array([t.local_v_north_mps, t.local_v_east_mps])
        an, ae = v + (v - before) / dt  # the drag's lean, and what changes the velocity
        t.heading_rad = 0.0  # nose north: pitch leans north, roll east
        t.pitch_rad = -math.atan(an / dg.GRAVITY_MPS2)
        t.roll_rad = math.atan(ae / dg.GRAVITY_MPS2 * math.cos(t.pitch_rad))


@pytest.mark.parametrize("takes_it", [True, False], ids=["px4", "ardupilot"])
def test_the_drag_learnt_from_the_attitude_is_sent_as_an_acceleration_only_where_the_autopilot_adds_it(
        clock, takes_it):
    v = _LeansIntoDrag(clock, start=(-100.0, 50.0), speed_mps=8.0)
    v.limits.acceleration_feedforward = takes_it
    mission = make_mission(v, clock, straight_plan([]), cruise_mps=8.0)  # 60 m north, then 40 m east
    assert mission.run().completed
    sent = [(np.array(vel), np.array(acc)) for vel, acc in zip(v.velocities, v.accelerations) if acc is not None]
    if not takes_it:
        assert not sent and any(vel is not None for vel in v.velocities)
        return
    assert mission.drag.k_1_s == pytest.approx(1.0, abs=0.25)  # a fake's jerky velocity: test_drag checks the fit
    assert len(sent) > 20  # from 3 s of level flight at speed on, every setpoint with a velocity carries one
    for vel, acc in sent:  # local NED: the lean along the velocity, k times it, nothing vertical
        assert acc[:2] == pytest.approx(vel[:2] * (acc[:2] @ vel[:2]) / (vel[:2] @ vel[:2]), abs=1e-9)
        assert acc[2] == 0.0
        assert 0.5 < np.linalg.norm(acc[:2]) / np.linalg.norm(vel[:2]) < 1.5


def test_arm_refused_then_accepted(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), arm_refusals=2)
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed
    assert v.calls.count("arm") == 3
    assert v.calls.count("prepare_flight") == 3  # the mode is selected again before each try


class _DisarmsBeforeTakeoff(FakeVehicle):
    """Disarms itself on the ground before the first ``disarms`` takeoff commands arrive and refuses them, as
    ArduCopter does 10 s after arming (DISARM_DELAY) when the takeoff is held up."""

    def __init__(self, clock, disarms=1, **kwargs):
        super().__init__(clock, **kwargs)
        self.disarms = disarms

    def takeoff(self, altitude_m):
        if self.disarms > 0:
            self.disarms -= 1
            self.telemetry.armed = False
            raise Refused("MAV_CMD_NAV_TAKEOFF rejected: MAV_RESULT_FAILED")
        return super().takeoff(altitude_m)


def test_a_vehicle_that_disarmed_itself_before_the_takeoff_is_armed_again_and_takes_off(clock):
    v = _DisarmsBeforeTakeoff(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("arm") == 2


class _TakeoffAnswerLost(FakeVehicle):
    """Takes off on the first command but its answer is lost; the repeat is refused, as ArduCopter refuses a
    takeoff when already flying."""

    def takeoff(self, altitude_m):
        if "takeoff" in self.calls:
            raise Refused("MAV_CMD_NAV_TAKEOFF rejected: MAV_RESULT_FAILED")
        self.calls.append("takeoff")
        super().takeoff(altitude_m)
        raise Refused("MAV_CMD_NAV_TAKEOFF rejected: MAV_RESULT_FAILED")  # the repeat's answer, the first lost


def test_a_takeoff_whose_answer_was_lost_and_whose_repeat_was_refused_goes_on_when_the_vehicle_climbs(clock):
    v = _TakeoffAnswerLost(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("arm") == 1


class _TakeoffAnswerLostWhileRetrying(_TakeoffAnswerLost):
    """The link retries the takeoff for its ACK (5 s) while the vehicle climbs to its altitude; the repeat is
    refused."""

    retried = False

    def takeoff(self, altitude_m):
        try:
            super().takeoff(altitude_m)
        finally:
            if not self.retried:
                self.retried = True
                self.clock.sleep(5.0)


def test_a_liftoff_unseen_behind_a_lost_takeoff_answer_still_gives_an_airborne_time(clock):
    """The vehicle was in the air before the mission could look (it had liftoff NaN and said "airborne nan s"): the
    airborne time is then counted from the takeoff command, in the autopilot's clock."""
    v = _TakeoffAnswerLostWhileRetrying(clock, start=(-100.0, 50.0))
    clock.tickers.append(lambda dt: setattr(v.telemetry, "local_time_s", 10.0 * clock.now))
    v.telemetry.local_time_s = 0.0
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and math.isfinite(result.airborne_s)
    assert result.airborne_s == pytest.approx(result.flight_time_s) and result.airborne_s > 10.0 * 5.0


def test_a_takeoff_refused_while_armed_or_refused_again_and_again_ends_the_flight(clock):
    v = _DisarmsBeforeTakeoff(clock, disarms=3)
    with pytest.raises(m.MissionError, match="NAV_TAKEOFF rejected"):
        make_mission(v, clock, straight_plan([])).run()
    assert v.calls.count("arm") == 3  # armed again twice, then given up
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["takeoff"] = Refused("MAV_CMD_NAV_TAKEOFF rejected: MAV_RESULT_DENIED")  # still armed: no retry
    with pytest.raises(m.MissionError, match="NAV_TAKEOFF rejected"):
        make_mission(v, clock, straight_plan([])).run()
    assert v.calls.count("arm") == 1 and not v.telemetry.armed


def test_arm_refused_until_timeout_quotes_the_autopilot(clock):
    v = FakeVehicle(clock, arm_refusals=10**6)
    mission = make_mission(v, clock, straight_plan([]), arm_timeout_s=10.0)
    with pytest.raises(m.ArmingFailed, match="ekf2 not ready") as err:
        mission.run()
    assert err.value.attempts == 11 and clock.now == pytest.approx(10.0)  # at t = 0, 1, ..., 10 s
    assert err.value.result.final_state is S.MANUAL
    assert "takeoff" not in v.calls and not v.telemetry.armed and v.setpoint is None


def test_a_permanent_refusal_of_a_ready_vehicle_fails_at_once(clock):
    # e.g. "Arm: LAND mode not armable" (FAILED): waiting will not change it
    v = FakeVehicle(clock, arm_refusals=10**6)
    v.arm_permanent = True
    with pytest.raises(m.ArmingFailed, match="waiting will not help") as err:
        make_mission(v, clock, straight_plan([]), arm_timeout_s=60.0).run()
    assert err.value.attempts == 1 and clock.now < 1.0


def test_a_refused_flight_mode_is_named_as_such_not_as_a_refusal_to_arm(clock):
    # PX4 arms in OFFBOARD: a DO_SET_MODE DENIED comes before any arm request
    v = FakeVehicle(clock)
    v.fail_on["prepare_flight!"] = Refused("MAV_CMD_DO_SET_MODE rejected: MAV_RESULT_DENIED", permanent=True)
    with pytest.raises(m.ArmingFailed, match="^the autopilot refused to take the flight mode we arm in and says it "
                                             "is ready, so waiting will not help") as err:
        make_mission(v, clock, straight_plan([]), arm_timeout_s=60.0).run()
    assert err.value.action != "arm" and "arm" not in v.calls and not v.telemetry.armed


def test_a_permanent_refusal_of_a_vehicle_not_ready_yet_is_retried(clock):
    # ArduCopter answers FAILED ("PreArm: ...") until its EKF is happy, and says it is not ready meanwhile (its
    # pre-arm flag may drop after the mission found it ready, e.g. the EKF re-converging)
    v = FakeVehicle(clock, start=(-100.0, 50.0), arm_refusals=3)
    v.arm_permanent = True
    real_readiness = v.readiness

    def readiness():
        if 0 < v.calls.count("arm") <= 3:  # not ready while it refuses
            return FakeReadiness(("the autopilot's pre-arm checks",))
        return real_readiness()

    v.readiness = readiness
    assert make_mission(v, clock, straight_plan([])).run().completed
    assert v.calls.count("arm") == 4


def test_no_path_is_never_armed(clock):
    class NoPathError(Exception):  # what planning_utils raises
        pass

    def plan(n, e):
        raise NoPathError("goal unreachable")

    v = FakeVehicle(clock)
    with pytest.raises(m.NoPathFound, match="goal unreachable") as err:
        make_mission(v, clock, plan, no_path_errors=(NoPathError,)).run()
    assert "arm" not in v.calls and "prepare_flight" not in v.calls and not v.telemetry.armed
    assert [h[1] for h in err.value.result.history] == [E.START, E.READY, E.NO_PATH]
    assert err.value.result.final_state is S.MANUAL


def test_empty_plan_is_no_path(clock):
    v = FakeVehicle(clock)
    with pytest.raises(m.NoPathFound):
        make_mission(v, clock, lambda n, e: np.empty((0, 4))).run()
    assert not v.telemetry.armed and "arm" not in v.calls


def test_planner_crash_is_never_armed(clock):
    def plan(n, e):
        raise RuntimeError("planner bug")

    v = FakeVehicle(clock)
    with pytest.raises(m.PlanningFailed, match="planner bug"):
        make_mission(v, clock, plan).run()
    assert not v.telemetry.armed and "arm" not in v.calls


# ----------------------------------------------------------------------------------------- in flight
def test_failure_mid_flight_lands(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: v.fail_on.update(goto_local=Refused("SET_POSITION_TARGET refused")))
    with pytest.raises(m.FlightAborted, match="refused.*landed at") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert "land" in v.calls and not v.telemetry.armed and v.telemetry.on_ground
    assert err.value.result.final_state is S.MANUAL and not err.value.result.completed
    assert E.ABORT in [h[1] for h in err.value.result.history]


def test_failure_mid_flight_holds_when_landing_fails(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["land!"] = Refused("NAV_LAND unsupported")

    def fail():
        v.fail_on["goto_local"] = Refused("boom")

    clock.at(8.0, fail)
    with pytest.raises(m.FlightAborted, match="holding") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert v.calls[-1] == "hold" and v.mode == "hold"
    assert err.value.result.final_state is S.FAILED


def test_a_failsafe_that_refuses_land_and_hold_is_followed_down_and_where_it_landed_is_said(clock):
    """PX4 SITL without a position estimate (its GPS switched off mid-route): the failsafe puts it in ALTCTL and
    lands it blind, refusing OFFBOARD, LAND and HOLD alike ("currently not available"). The mission cannot land or
    hold it: it watches the autopilot bring it down and says where it came down, not only that it let go."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def position_lost():
        v.mode, v.hint = "posctl", "the autopilot said 'Failsafe activated'"
        v.telemetry.gps_fix_type = 1  # NO_FIX
        for name in ("take_control!", "land!", "hold!"):
            v.fail_on[name] = Refused("DO_SET_MODE rejected: TEMPORARILY_REJECTED")

    def blind_land(dt):
        t = v.telemetry
        if v.mode == "posctl" and t.armed:
            t.down_m = min(0.0, t.down_m + 0.7 * dt)
            t.on_ground = t.down_m >= 0.0
            t.armed = not t.on_ground

    clock.tickers.append(blind_land)
    clock.at(8.0, position_lost)
    with pytest.raises(m.FlightAborted, match=r"TEMPORARILY_REJECTED \(the GPS reports no 3D fix, fix type 1: "
                                              r"without a position .*nor hold .*failsafe owns the vehicle; "
                                              r"it landed at map \(-?\d+\.\d N, -?\d+\.\d E\) and disarmed") as err:
        make_mission(v, clock, straight_plan([]), control_retries=3).run()
    assert v.telemetry.on_ground and not v.telemetry.armed
    assert err.value.result.final_state is S.FAILED


def test_a_failsafe_that_lands_the_vehicle_while_control_is_refused_ends_the_retries(clock):
    # the same failsafe, down before the second attempt to take control back: no "control taken back" over a
    # disarmed vehicle (a disarmed PX4 accepts OFFBOARD again), the mission says it was landed meanwhile
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def position_lost():
        v.mode, v.hint = "posctl", "the autopilot said 'Failsafe activated'"
        v.fail_on["take_control"] = Refused("DO_SET_MODE rejected: TEMPORARILY_REJECTED")

    def dropped(dt):
        if v.mode == "posctl" and v.telemetry.armed:
            v.telemetry.down_m, v.telemetry.on_ground, v.telemetry.armed = 0.0, True, False

    clock.tickers.append(dropped)
    clock.at(8.0, position_lost)
    with pytest.raises(m.LandedMeanwhile, match="left our flight mode for posctl; meanwhile the vehicle landed and "
                                                "disarmed at map"):
        make_mission(v, clock, straight_plan([]), control_retries=3).run()
    assert v.calls.count("take_control") == 1


def test_takeoff_timeout_lands(clock):
    v = FakeVehicle(clock, climbs=False)
    with pytest.raises(m.FlightAborted, match="takeoff did not reach"):
        make_mission(v, clock, straight_plan([]), takeoff_timeout_s=5.0).run()
    assert "land" in v.calls and not v.telemetry.armed


def test_ctrl_c_in_flight_lands_then_reraises(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def interrupt():
        raise KeyboardInterrupt

    clock.at(10.0, interrupt)
    mission = make_mission(v, clock, straight_plan([]))
    with pytest.raises(KeyboardInterrupt):
        mission.run()
    assert v.calls[-3:] == ["land", "disarm", "release_control"]
    assert v.telemetry.on_ground and not v.telemetry.armed
    assert mission.state is S.MANUAL and not mission.result.completed


def test_ctrl_c_while_planning_leaves_nothing_to_undo(clock):
    def plan(n, e):
        raise KeyboardInterrupt

    v = FakeVehicle(clock)
    mission = make_mission(v, clock, plan)
    with pytest.raises(KeyboardInterrupt):
        mission.run()
    assert not v.telemetry.armed and "arm" not in v.calls and mission.state is S.MANUAL


def test_disarm_refused_until_timeout_fails(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.disarm_refusals = 10**6
    with pytest.raises(m.MissionError, match="could not disarm") as err:
        make_mission(v, clock, straight_plan([]), disarm_timeout_s=2.0).run()
    assert err.value.result.final_state is S.FAILED


def test_waypoint_timeout_lands(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), speed_mps=0.5)
    with pytest.raises(m.FlightAborted, match="not reached in time.*landed"):
        make_mission(v, clock, straight_plan([]), leg_timeout_s=1.0, min_speed_mps=5.0,
                     takeoff_timeout_s=100.0).run()
    assert not v.telemetry.armed


def test_altitude_must_be_positive(clock):
    with pytest.raises(ValueError):
        make_mission(FakeVehicle(clock), clock, straight_plan([]), altitude_m=0.0)


def test_touchdown_not_confirmed_is_reported(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.land = lambda: v.calls.append("land")  # accepted, but the vehicle never descends
    with pytest.raises(m.FlightAborted, match="landing commanded but not confirmed") as err:
        make_mission(v, clock, straight_plan([]), landing_timeout_s=5.0).run()
    assert err.value.result.final_state is S.FAILED
    assert "hold" not in v.calls  # the autopilot keeps landing; we do not override it


def test_ctrl_c_while_landing_waits_for_touchdown(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    mission = make_mission(v, clock, straight_plan([]))
    real_land = v.land

    def land_then_interrupt():
        real_land()
        clock.at(clock.now + 1.0, lambda: (_ for _ in ()).throw(KeyboardInterrupt))

    v.land = land_then_interrupt
    with pytest.raises(KeyboardInterrupt):
        mission.run()
    assert v.telemetry.on_ground and not v.telemetry.armed and mission.state is S.MANUAL


# ----------------------------------------------------------------------- outages and lost control in flight
def outage(clock, v, start_s, duration_s, *, then_mode="hold"):
    """The link is silent from ``start_s`` for ``duration_s``; meanwhile the autopilot's failsafe switches to
    ``then_mode`` (PX4: Hold after COM_OF_LOSS_T) and the fake stops there."""

    def down():
        v.link_ok = False
        v.mode = then_mode

    clock.at(start_s, down)
    clock.at(start_s + duration_s, lambda: setattr(v, "link_ok", True))


def test_a_3_s_outage_mid_flight_is_ridden_out_and_the_mission_completes(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    outage(clock, v, 8.0, 3.0)
    seen = {}

    def look(when):
        t = v.telemetry
        seen[when] = (v.setpoint, (t.north_m, t.east_m, t.down_m))

    clock.at(10.5, lambda: look("outage"))
    clock.at(11.25, lambda: look("back"))
    planned, lines = [], []
    result = make_mission(v, clock, straight_plan(planned), progress=lines.append).run()
    assert result.completed and result.final_state is S.MANUAL and result.recoveries == 1
    # the last setpoint, reckoned from telemetry the outage froze, was re-sent through it (PX4 returns to OFFBOARD
    # the moment setpoints come back) and replaced by a hold where the vehicle is once the link was back
    stale, stopped_at = seen["outage"]
    held, at = seen["back"]
    assert math.dist(stale[:2], stopped_at[:2]) > 0.5
    assert math.dist(held[:2], at[:2]) < 0.3 and held[2] == pytest.approx(at[2], abs=0.3)
    events = [h[1] for h in result.history]
    assert events[events.index(E.LINK_LOST):events.index(E.LINK_LOST) + 2] == [E.LINK_LOST, E.RESUMED]
    assert v.calls.count("take_control") == 1 and len(planned) == 1  # it held on the path: no replan
    assert result.landing_error_m < 0.3
    assert any("the autopilot's failsafe has the vehicle" in line for line in lines)
    assert "control taken back: flying on from where the vehicle is" in lines


def test_after_an_outage_off_the_path_it_replans_from_where_the_vehicle_is(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    outage(clock, v, 8.0, 3.0)

    def drift():  # the wind carried it 10 m east while nobody steered
        v.telemetry.east_m += 10.0

    clock.at(9.0, drift)
    planned = []
    result = make_mission(v, clock, fixed_plan(planned), goal_ne=(60.0, 40.0)).run()
    assert result.completed and len(planned) == 2
    assert planned[1][1] == pytest.approx(10.0, abs=0.5)  # the new plan starts from where it drifted to
    assert result.landing_error_m < 0.3


def test_landed_and_disarmed_during_an_outage_is_reported_and_never_taken_off_again(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    outage(clock, v, 8.0, 20.0, then_mode="land")  # the failsafe lands it; it auto-disarms on the ground

    def auto_disarm(dt):
        if v.mode == "land" and v.telemetry.on_ground:
            v.telemetry.armed = False

    clock.tickers.append(auto_disarm)
    with pytest.raises(m.LandedMeanwhile, match="landed and disarmed.*not taking off again") as err:
        make_mission(v, clock, straight_plan([])).run()
    n_calls = v.calls.index("release_control")
    assert "arm" not in v.calls[v.calls.index("takeoff"):] and "takeoff" not in v.calls[n_calls:]
    assert err.value.result.final_state is S.MANUAL and not err.value.result.completed


def test_link_lost_for_good_is_left_to_the_failsafe_after_the_link_timeout(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(10.0, lambda: setattr(v, "link_ok", False))
    with pytest.raises(m.LinkLostInFlight, match="failsafe") as err:
        make_mission(v, clock, straight_plan([]), link_lost_timeout_s=5.0).run()
    assert err.value.result.final_state is S.FAILED
    assert err.value.result.history[-1][1] is E.LINK_TIMEOUT
    assert 15.0 <= clock.now <= 15.2  # waited the bounded time, then reported
    assert "land" not in v.calls


def test_a_mode_change_we_did_not_ask_for_is_taken_back_at_once(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    noticed = []
    clock.at(8.0, lambda: setattr(v, "mode", "hold"))  # PX4 left OFFBOARD (a setpoint gap under load)
    real_take = v.take_control
    v.take_control = lambda: (noticed.append(clock.now), real_take())[1]
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and noticed and noticed[0] - 8.0 <= 0.05  # within one poll, not at a leg timeout
    assert (S.WAYPOINT, E.CONTROL_LOST, S.RECOVERING) in result.history


def _to_the_goal(n, e):
    """straight_plan's route, to its goal from anywhere: (60, 40) at 10 m."""
    corners = [(n, e), (60.0, e), (60.0, 40.0)]
    kept = [c for k, c in enumerate(corners) if k == 0 or math.dist(c, corners[k - 1]) > 0.5]
    return np.array([[a, b, 10.0, 0.0] for a, b in kept])


def test_a_mode_change_during_the_descent_over_the_goal_is_taken_back_and_the_descent_goes_on(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    changed, sent_before = [], []

    def leave_offboard():
        changed.append(-v.telemetry.down_m)
        sent_before.append(len(v.gotos))
        v.mode = "hold"

    def watch(dt):  # once, 3 m into the descent over the goal
        if not changed and v.gotos and v.gotos[-1][2] > -7.0:
            leave_offboard()

    clock.tickers.append(watch)
    result = make_mission(v, clock, _to_the_goal).run()
    assert changed and result.completed and result.landing_error_m < 0.3
    assert (S.WAYPOINT, E.CONTROL_LOST, S.RECOVERING) in result.history  # taken back, not landed where it was
    assert v.calls.count("land") == 1
    # it came on down from where it was: no climb back to the flight altitude (10 m) to fly the route's end again
    assert max(-g[2] for g in v.gotos[sent_before[0]:]) < changed[0] + 0.3


@pytest.mark.parametrize("failsafe_mode", ["hold", "LAND"])
def test_an_outage_during_the_descent_over_the_goal_does_not_climb_back(clock, failsafe_mode):
    """The link is silent for 3 s, 3 m into the descent; the autopilot's failsafe holds (PX4: Hold) or lands
    (LAND) meanwhile. Held: control is taken back and the descent goes on from where the vehicle is. Landing over
    the goal: that is the landing, not a mode to take back."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    lost, sent_before = [], []

    def watch(dt):
        if not lost and v.gotos and v.gotos[-1][2] > -7.0:
            lost.append(-v.telemetry.down_m)
            sent_before.append(len(v.gotos))
            v.link_ok, v.mode = False, failsafe_mode
            clock.at(clock.now + 3.0, lambda: setattr(v, "link_ok", True))

    clock.tickers.append(watch)
    lines = []
    result = make_mission(v, clock, _to_the_goal, progress=lines.append).run()
    assert lost and result.completed and result.final_state is S.MANUAL and result.landing_error_m < 0.3
    assert (S.WAYPOINT, E.LINK_LOST, S.RECOVERING) in result.history
    assert max((-g[2] for g in v.gotos[sent_before[0]:]), default=-math.inf) < lost[0] + 0.3
    assert sum("the autopilot's failsafe has the vehicle" in line for line in lines) == 1
    if failsafe_mode == "LAND":
        assert "take_control" not in v.calls[v.calls.index("takeoff"):]
        assert any("landing over the goal by itself; that is the landing" in line for line in lines)
    else:
        assert v.calls.count("take_control") == 1


def test_the_autopilots_own_landing_during_the_descent_over_the_goal_is_the_landing(clock, caplog):
    """A failsafe (a low battery) puts the vehicle in LAND 3 m into the descent: it lands over the goal, which is
    the mission's end, not a mode to take back or a hand-over."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    failsafe = []

    def low_battery(dt):
        if not failsafe and v.gotos and v.gotos[-1][2] > -7.0:
            failsafe.append(clock.now)
            v.mode = "LAND"  # as the autopilot names it

    clock.tickers.append(low_battery)
    with caplog.at_level("INFO", logger="skyroute.flight.landing"):
        result = make_mission(v, clock, straight_plan([])).run()
    assert failsafe and result.completed and result.landing_error_m < 0.3
    assert "the autopilot is landing by itself" in caplog.text
    assert not any(event is E.CONTROL_LOST for _, event, _ in result.history)


def test_a_vehicle_that_stops_following_in_our_mode_is_given_its_mode_again(clock):
    # the autopilot still says OFFBOARD but ignores our setpoints (it dropped our stream without saying so)
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    frozen = []

    def freeze():
        frozen.append(True)
        v.speed_mps = 0.0

    clock.at(8.0, freeze)
    real_take = v.take_control

    def take_control():
        real_take()
        v.speed_mps = 5.0  # re-entering the mode makes it follow again

    v.take_control = take_control
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("take_control") == 1
    assert (S.WAYPOINT, E.CONTROL_LOST, S.RECOVERING) in result.history


def test_a_local_frame_that_jumps_in_flight_is_re_tied_to_the_map(clock):
    # an EKF reset (or an origin moved to where it armed) during the takeoff: every local coordinate jumps by
    # (-20, 15) m; a setpoint kept in the old numbers would now mean a place 25 m away
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    frame = {"offset": np.array(OFFSET, float)}  # map = local + offset
    shifts = []

    def map_offset_now(origin, ground):
        t = v.telemetry
        return LocalNED(frame["offset"][0], frame["offset"][1], -(t.alt_amsl_m - ground) - t.down_m)

    def jump():
        v.telemetry.north_m -= 20.0
        v.telemetry.east_m += 15.0
        frame["offset"] += (20.0, -15.0, 0.0)

    def shift_setpoint(dn, de, dd):
        shifts.append((dn, de, dd))
        n, e, d = v.setpoint
        v.setpoint = (n + dn, e + de, d + dd)

    v.map_offset_now, v.shift_setpoint = map_offset_now, shift_setpoint
    clock.at(1.0, jump)  # climbing straight up from map (0, 0)
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and shifts == [pytest.approx((-20.0, 15.0, 0.0))]
    true_end = (v.telemetry.north_m + frame["offset"][0], v.telemetry.east_m + frame["offset"][1])
    assert true_end == pytest.approx((60.0, 40.0), abs=0.3)  # the map goal, not 25 m off it


def test_a_pilot_taking_over_is_handed_over(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: setattr(v, "mode", "posctl"))  # position mode: we never select it
    with pytest.raises(m.ControlTakenOver, match="a pilot took over: the vehicle is in posctl") as err:
        make_mission(v, clock, straight_plan([]), pilot_grace_s=2.0).run()
    assert 10.0 <= clock.now <= 10.2  # after the grace for a failsafe's fallback to give way
    after = v.calls[v.calls.index("release_control"):]
    assert "take_control" not in v.calls and "land" not in v.calls and after == ["release_control"]
    assert err.value.result.final_state is S.HANDED_OVER


def test_a_pilot_mode_that_gives_way_to_ours_by_itself_is_no_pilot(clock):
    # a 3 s outage against the sim at 5x (0.6 s on our clock, heard as no outage): PX4's offboard-loss fallback
    # (position mode) with its "Failsafe activated" lost, and back to OFFBOARD by itself once setpoints arrive
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: setattr(v, "mode", "posctl"))
    clock.at(8.8, lambda: setattr(v, "mode", "offboard"))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and "take_control" not in v.calls and "release_control" in v.calls[-1:]
    assert (S.WAYPOINT, E.CONTROL_LOST, S.RECOVERING) in result.history


def test_a_pilot_mode_a_failsafe_explains_is_taken_back(clock):
    # PX4's offboard-loss failsafe (COM_OBL_RC_ACT = 0) is position mode, announced as "Failsafe activated"
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "posctl"), setattr(v, "hint", "the autopilot said 'Failsafe'")))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("take_control") == 1


def test_a_failsafe_the_autopilot_names_as_its_own_is_respected_not_fought(clock):
    # ArduCopter SITL with BATT_FS_LOW_ACT 2, its battery made low in flight (measured): "Battery 1 is low 10.00V
    # used 177 mAh", "Battery Failsafe", RTL. Taking GUIDED back flew the mission on against the autopilot.
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "rtl"), setattr(v, "own", "Battery Failsafe"),
                           setattr(v, "hint", "the autopilot said 'Battery Failsafe'")))
    with pytest.raises(m.ControlTakenOver, match=r"autopilot's own failsafe put the vehicle in rtl \(it said "
                                                  r"'Battery Failsafe'\); handed over, not taking control back; "
                                                  r"it landed at map") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert "take_control" not in v.calls[v.calls.index("takeoff"):] and "land" not in v.calls
    assert v.calls[-1] == "release_control"
    assert err.value.result.final_state is S.HANDED_OVER
    assert err.value.result.track[-1, 3] == pytest.approx(0.0, abs=0.1)  # the track follows it down


def test_a_return_that_does_not_end_is_followed_only_for_the_watch_time(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "return-hover"), setattr(v, "own", "Battery Failsafe")))
    with pytest.raises(m.ControlTakenOver, match="still in the air in return-hover after 20 s"):
        make_mission(v, clock, straight_plan([]), handover_watch_s=20.0).run()
    assert 28.0 <= clock.now <= 28.5


def test_a_hold_the_autopilot_chose_is_handed_over_at_once(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "hold"), setattr(v, "own", "Geofence breached")))
    with pytest.raises(m.ControlTakenOver, match="own failsafe put the vehicle in hold"):
        make_mission(v, clock, straight_plan([])).run()
    assert clock.now <= 8.5


@pytest.mark.parametrize("mode", ["hold", "posctl"])
def test_an_own_failsafe_is_respected_whatever_mode_it_chose(clock, mode):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", mode), setattr(v, "own", "Geofence breached")))
    with pytest.raises(m.ControlTakenOver, match="own failsafe"):
        make_mission(v, clock, straight_plan([])).run()
    assert "take_control" not in v.calls


def test_a_return_nothing_on_our_side_explains_is_handed_over(clock):
    # PX4 announces its geofence failsafe only as "Failsafe activated" (measured on PX4 1.15 SITL), and an operator
    # may send the vehicle home from another ground station
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "rtl"), setattr(v, "hint", "the autopilot said 'Failsafe activated'")))
    with pytest.raises(m.ControlTakenOver, match="went to rtl and nothing on our side explains it"):
        make_mission(v, clock, straight_plan([])).run()
    assert "take_control" not in v.calls


def test_a_return_after_a_failsafe_about_our_link_is_taken_back(clock):
    # ArduCopter's GCS failsafe (FS_GCS_ENABLE 1): "GCS Failsafe", RTL; our heartbeats were late, not an operator
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "rtl"), setattr(v, "hint", "the autopilot said 'GCS Failsafe'")))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("take_control") == 1


def test_a_return_our_own_setpoint_pause_explains_is_taken_back(clock):
    # PX4's offboard-loss failsafe with COM_OBL_RC_ACT 3 (Return): our setpoints paused, so it is ours to undo
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(8.0, lambda: (setattr(v, "mode", "land"), setattr(v, "hint", "our setpoints paused for 1.2 s")))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls.count("take_control") == 1


def test_a_route_that_leaves_the_autopilots_geofence_is_refused_before_arming(clock):
    # ArduCopter SITL, FENCE_ENABLE 1, FENCE_RADIUS 150: "Circle fence breached" and RTL 150 m out (measured)
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.limits.fence = Geofence(70.0, 98.0, "FENCE_RADIUS=72 m, FENCE_MARGIN=2 m; a breach does RTL or LAND")
    with pytest.raises(m.OutsideGeofence, match=r"leaves the autopilot's geofence: it goes 72 m from home, the fence "
                                                r"allows 70 m \(FENCE_RADIUS=72 m.*\); never armed") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert "arm" not in v.calls and err.value.result.final_state is S.MANUAL


def test_a_route_inside_the_geofence_flies(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.limits.fence = Geofence(75.0, 98.0, "FENCE_RADIUS=77 m")
    assert make_mission(v, clock, straight_plan([])).run().completed


@pytest.mark.parametrize("return_m, tower_m, warned", [(15.0, 40.0, True), (60.0, 40.0, False),
                                                      (15.0, 12.0, False)])
def test_a_route_whose_failsafe_return_would_meet_a_taller_building_is_flown_with_a_warning(
        clock, return_m, tower_m, warned):
    # a tower between the route's far end and home: the line home from there crosses it (Clearance's exact test)
    from skyroute.planning.clearance import Clearance

    v = FakeVehicle(clock, start=(-100.0, 50.0))
    start = (-100.0 + OFFSET.north_m, 50.0 + OFFSET.east_m)  # where it stands on the map
    tower = np.array([[start[0] + 55.0, start[1] + 20.0, tower_m / 2, 3.0, 3.0, tower_m / 2]])
    v.limits.return_altitude_m, v.limits.return_described = return_m, f"RTL_ALT={100 * return_m:g} cm"
    lines = []
    mission = make_mission(v, clock, straight_plan([]), progress=lines.append,
                           return_line_fn=Clearance(tower, 5.0).highest_crossed)
    assert mission.run().completed
    said = [line for line in lines if "autopilot's own return" in line]
    assert bool(said) is warned
    if warned:
        assert f"{tower_m:.0f} m tall at map ({start[0] + 55.0:.0f} N, {start[1] + 20.0:.0f} E)" in said[0]
        assert "RTL_ALT=1500 cm" in said[0]


@pytest.mark.parametrize("accuracy_m, warned", [(0.3, False), (0.9, False), (1.53, True), (float("nan"), False)])
def test_a_gps_accuracy_that_eats_most_of_the_margin_is_flown_with_a_warning(clock, accuracy_m, warned):
    """The autopilot flies its estimate along the route: three times the stated accuracy (the real SITLs state
    0.3 m and 0.9 m) may separate the vehicle from it, and beyond 70 % of the margin the mission says so."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.horizontal_accuracy_m = accuracy_m
    lines = []
    mission = make_mission(v, clock, straight_plan([]), progress=lines.append, replan_margin_m=5.0)
    assert mission.run().completed
    said = [line for line in lines if "horizontal accuracy" in line]
    assert bool(said) is warned
    if warned:
        assert "the vehicle itself may be 4.6 m off it" in said[0] and "--safety of 6.6 m or more" in said[0]


def test_control_that_cannot_be_taken_back_ends_in_a_landing(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["take_control!"] = Refused("DO_SET_MODE rejected: DENIED")
    clock.at(8.0, lambda: setattr(v, "mode", "hold"))
    with pytest.raises(m.FlightAborted, match="could not take control back.*landed at"):
        make_mission(v, clock, straight_plan([]), control_retries=3).run()
    assert v.calls.count("take_control") == 3 and v.telemetry.on_ground and not v.telemetry.armed


def test_a_vehicle_that_keeps_leaving_our_mode_is_landed(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    for k in range(4):
        clock.at(6.0 + k, lambda: setattr(v, "mode", "hold"))
    with pytest.raises(m.FlightAborted, match="control lost 4 times, giving up"):
        make_mission(v, clock, straight_plan([]), max_recoveries=3).run()
    assert v.telemetry.on_ground and not v.telemetry.armed


def test_the_link_lost_while_landing_is_waited_for(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    real_land = v.land

    def land():
        real_land()
        outage(clock, v, clock.now + 1.0, 2.0, then_mode="land")

    v.land = land
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and (S.LANDING, E.LINK_LOST, S.LANDING) in result.history


# ------------------------------------------------------------------------ disarmed between takeoff and touchdown
def disarm_at(clock, v, t_s, *, on_ground=False):
    """At ``t_s`` the autopilot disarms the vehicle where it is (the fake then stops moving, like a wreck).

    Returns a list that then holds the fake's map position ``(north_m, east_m, altitude_m)`` and its call count.
    """
    seen = []

    def kill():
        t = v.telemetry
        t.armed, t.on_ground = False, on_ground
        seen.extend([(t.north_m + OFFSET.north_m, t.east_m + OFFSET.east_m, -t.down_m), len(v.calls)])

    clock.at(t_s, kill)
    return seen


def reported_position(message):
    """``(north_m, east_m, altitude_m)`` from a VehicleDisarmedInFlight message."""
    found = re.search(r"at map position (-?[\d.]+) N, (-?[\d.]+) E, (-?[\d.]+) m above the map's ground", message)
    return tuple(float(x) for x in found.groups())


def test_disarm_in_the_air_on_a_leg_is_reported_at_once_and_not_landed(clock):
    # at t = 10 s the vehicle is on the first 30 m leg north, 10 m up (the leg alone has a 90 s timeout)
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    seen = disarm_at(clock, v, 10.0)
    with pytest.raises(m.VehicleDisarmedInFlight) as err:
        make_mission(v, clock, straight_plan([])).run()
    assert isinstance(err.value, m.FlightAborted) and isinstance(err.value, m.MissionError)  # the CLI's exit path
    message = str(err.value)
    assert message.startswith("the vehicle disarmed in the air in state WAYPOINT (crashed or killed by the autopilot)")
    where, n_calls = seen
    assert 10.0 < where[0] < 60.0 and where[2] == pytest.approx(10.0, abs=0.5)  # mid-leg, in the air
    assert reported_position(message) == pytest.approx(where, abs=0.051)  # printed to 0.1 m
    assert (err.value.position.north_m, err.value.position.east_m, err.value.position.altitude_m) == \
        pytest.approx(where)
    assert not err.value.on_ground and err.value.state is S.WAYPOINT
    assert 10.0 <= clock.now <= 10.0 + 0.05 + 1e-9  # noticed on the next poll, not after the leg timeout
    assert v.calls[n_calls:] == ["release_control"] and v.setpoint is None  # no land, no disarm
    result = err.value.result
    assert result.final_state is S.FAILED and not result.completed
    assert result.history[-1] == (S.WAYPOINT, E.DISARMED_IN_FLIGHT, S.FAILED)
    assert result.track[-1, 1:] == pytest.approx(where)


def test_disarm_during_takeoff_is_reported(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    seen = disarm_at(clock, v, 1.0)  # climbing at 5 m/s straight up from map (0, 0)
    with pytest.raises(m.VehicleDisarmedInFlight, match="in the air in state TAKEOFF") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert reported_position(str(err.value)) == pytest.approx((0.0, 0.0, 5.0), abs=0.051) == seen[0]
    assert "land" not in v.calls and "goto_local" not in v.calls


def test_disarm_on_the_ground_short_of_the_goal_is_an_abnormal_end(clock):
    # e.g. it came down on a roof: ON_GROUND but disarmed, 10 m above home, long before the goal
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    seen = disarm_at(clock, v, 10.0, on_ground=True)
    with pytest.raises(m.VehicleDisarmedInFlight,
                       match=r"disarmed on the ground in state WAYPOINT, before reaching the goal") as err:
        make_mission(v, clock, straight_plan([])).run()
    where, n_calls = seen
    assert where[2] == pytest.approx(10.0, abs=0.5)  # on a roof, 10 m above home
    assert reported_position(str(err.value)) == pytest.approx(where, abs=0.051)
    assert err.value.on_ground and err.value.result.final_state is S.FAILED
    assert v.calls[n_calls:] == ["release_control"] and v.setpoint is None


def test_disarm_in_the_air_during_the_final_descent_is_not_mission_complete(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    real_land = v.land

    seen = []

    def land():
        real_land()
        seen.append(disarm_at(clock, v, clock.now + 2.0))  # 3 m lower at 1.5 m/s: 7 m above home

    v.land = land
    with pytest.raises(m.VehicleDisarmedInFlight, match=r"in the air in state LANDING") as err:
        make_mission(v, clock, straight_plan([]), handover_m=0.0).run()  # the autopilot's landing from 10 m
    assert reported_position(str(err.value)) == pytest.approx((60.0, 40.0, 7.0), abs=0.1)
    assert seen[0][0] == pytest.approx((60.0, 40.0, 7.0), abs=0.1)
    result = err.value.result
    assert not result.completed and result.final_state is S.FAILED
    assert math.isnan(result.landing_error_m)  # no touchdown was recorded
    assert v.calls[-2:] == ["land", "release_control"]


@pytest.mark.parametrize("handover_m, error_m", [(1.5, 0.2), (0.0, 1.33)], ids=["from-1.5-m", "from-10-m"])
def test_the_vehicle_comes_down_over_the_goal_before_a_landing_that_wanders_takes_over(clock, handover_m, error_m):
    """Our setpoints bring it down over the goal to 1.5 m; the autopilot's landing (which drifts 0.2 m/s here, as
    PX4's wandered off its landing point) flies only the last second."""
    v = FakeVehicle(clock, start=(-100.0, 50.0), land_drift_mps=0.2)
    result = make_mission(v, clock, straight_plan([]), handover_m=handover_m).run()
    assert result.completed
    assert result.landing_error_m == pytest.approx(error_m, abs=0.05)
    lowest = max(g[2] for g in v.gotos)  # local down: the lowest setpoint
    assert lowest == pytest.approx(-max(handover_m, 10.0 * (handover_m == 0)), abs=0.05)
    assert v.calls[-3:] == ["land", "disarm", "release_control"]


@pytest.mark.parametrize("goal_ne, error_m", [((60.4, 39.6), 0.0), ((62.0, 40.0), 2.0)],
                         ids=["in-the-last-cell", "a-fallback-point"])
def test_the_descent_is_over_the_goal_itself_when_the_route_ends_in_its_cell(clock, goal_ne, error_m):
    """Planners end a route at the goal cell's centre, up to 0.71 m from the goal: the vehicle comes down over the
    goal. A route that ends elsewhere (a fallback point short of a goal out of reach) is landed at its end."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([]), goal_ne=goal_ne).run()
    assert result.completed and result.landing_error_m == pytest.approx(error_m, abs=0.05)


def test_a_lift_the_keep_off_holds_does_not_keep_the_descent_from_its_hand_over_height(clock, caplog):
    """Something read below lifted the route 1 m (the keep-off); the descent sends no lift and hands over at 1.5 m
    as flown, not after waiting out its time limit."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    mission = make_mission(v, clock, straight_plan([]))
    mission.keep_off = keepoff.KeepOff(4.0)
    clock.tickers.append(lambda dt: v.gotos and v.gotos[-1][2] > -9.9 and setattr(mission.keep_off, "lift_m", 1.0))
    with caplog.at_level("INFO", logger="skyroute.flight.landing"):
        result = mission.run()
    assert result.completed and "coming down" in caplog.text and "not settled in time" not in caplog.text
    assert v.gotos[-1][2] == pytest.approx(-1.5, abs=0.05)


def test_a_descent_that_stops_short_is_handed_to_the_autopilots_landing_after_a_second(clock, caplog):
    """Something under the goal the map does not show (or an altitude estimate that reads high) stops the descent 4 m
    up: one second later the autopilot's landing, which finds the ground itself, takes over."""
    v = FakeVehicle(clock, start=(-100.0, 50.0), lowest_down_m=-4.0)
    with caplog.at_level("INFO", logger="skyroute.flight.landing"):
        result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and v.calls[-3:] == ["land", "disarm", "release_control"]
    assert "it stopped coming down" in caplog.text
    assert "4.0 m above the map's surface: landing from there" in caplog.text
    assert max(g[2] for g in v.gotos) > -4.0 + 0.5  # it was told to go lower


def test_autopilot_disarming_itself_on_touchdown_is_a_landing(clock):
    # PX4/ArduPilot auto-disarm after touchdown and say ON_GROUND: that is a normal end
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def auto_disarm(dt):
        if v.mode == "land" and v.telemetry.on_ground:
            v.telemetry.armed = False

    clock.tickers.append(auto_disarm)
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.final_state is S.MANUAL
    assert v.calls[-2:] == ["land", "release_control"]  # already disarmed: no disarm command


def test_disarm_during_the_abort_landing_is_reported_with_the_first_failure(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["goto_local"] = Refused("SET_POSITION_TARGET refused")  # right after the climb
    real_land = v.land

    def land():
        real_land()
        disarm_at(clock, v, clock.now + 1.0)

    v.land = land
    with pytest.raises(m.VehicleDisarmedInFlight,
                       match=r"SET_POSITION_TARGET refused; landing; then the vehicle disarmed in the air in state "
                             r"LANDING") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert err.value.result.final_state is S.FAILED
    assert v.calls.count("land") == 1 and "disarm" not in v.calls


def test_link_back_to_a_disarmed_vehicle_does_not_land_it(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    clock.at(10.0, lambda: setattr(v, "link_ok", False))
    disarm_at(clock, v, 11.0)
    clock.at(12.0, lambda: setattr(v, "link_ok", True))
    with pytest.raises(m.VehicleDisarmedInFlight, match="the link was lost; then the vehicle disarmed in the air"):
        make_mission(v, clock, straight_plan([]), link_lost_timeout_s=5.0).run()
    assert "land" not in v.calls


# ----------------------------------------------------------------------------- making safe after a failure
def test_link_lost_for_good_while_landing_after_a_failure_is_not_reported_as_landed(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["goto_local"] = Refused("SET_POSITION_TARGET refused")  # at t = 2 s, 10 m up
    real_land = v.land

    def land():
        real_land()
        clock.at(clock.now + 1.0, lambda: setattr(v, "link_ok", False))  # for good, 8.5 m up

    v.land = land
    with pytest.raises(m.LinkLostInFlight,
                       match="SET_POSITION_TARGET refused; landing commanded, then the link was lost while landing") \
            as err:
        make_mission(v, clock, straight_plan([]), link_lost_timeout_s=2.0).run()
    assert not isinstance(err.value, m.FlightAborted) and "landed" not in str(err.value)
    assert err.value.result.final_state is S.FAILED
    assert not v.telemetry.on_ground  # the autopilot is still descending: it had not landed


def test_ctrl_c_after_the_mission_failed_says_so(clock, caplog):
    # landing refused -> LAND_FAILED (FAILED); Ctrl-C while asking to hold: the vehicle is in the air
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["goto_local"] = Refused("boom")
    v.fail_on["land!"] = Refused("NAV_LAND unsupported")

    def hold():
        v.calls.append("hold")
        raise KeyboardInterrupt

    v.hold = hold
    mission = make_mission(v, clock, straight_plan([]))
    with caplog.at_level("WARNING", logger="mission"), pytest.raises(KeyboardInterrupt):
        mission.run()
    assert mission.state is S.FAILED
    assert "interrupted (Ctrl-C): the mission had already failed" in caplog.text
    assert "may still be in the air" in caplog.text and "not armed by us" not in caplog.text


# ----------------------------------------------------------------------------------- bugs are not refusals
def test_vehicle_errors_must_be_given(clock):
    with pytest.raises(TypeError, match="vehicle_errors"):
        m.Mission(FakeVehicle(clock), straight_plan([]), altitude_m=10.0, map_origin=ORIGIN)


def test_a_bug_while_arming_is_not_retried_as_a_refusal(clock):
    v = FakeVehicle(clock)

    def arm():
        v.calls.append("arm")
        raise AttributeError("'NoneType' object has no attribute 'mav'")

    v.arm = arm
    with pytest.raises(AttributeError, match="mav"):
        make_mission(v, clock, straight_plan([])).run()
    assert v.calls == ["flight_limits", "prepare_flight", "arm", "release_control"] and clock.now == 0.0


def test_a_bug_in_flight_lands_then_propagates_as_itself(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["goto_local"] = TypeError("goto_local() got an unexpected keyword argument")
    mission = make_mission(v, clock, straight_plan([]))
    with pytest.raises(TypeError, match="unexpected keyword"):
        mission.run()
    assert v.calls[-3:] == ["land", "disarm", "release_control"]
    assert v.telemetry.on_ground and not v.telemetry.armed and mission.state is S.MANUAL


# ----------------------------------------------------------------------------- the final waypoint's tolerance
def biased(v, offset_east_m):
    """The vehicle settles ``offset_east_m`` east of a position-only setpoint (GPS noise, a biased controller)."""
    real_goto = v.goto_local

    def goto(north_m, east_m, down_m, yaw_rad, velocity_ned=None):  # the goal comes without a velocity
        real_goto(north_m, east_m + (offset_east_m if velocity_ned is None else 0.0), down_m, yaw_rad, velocity_ned)

    v.goto_local = goto


def test_a_steady_offset_over_the_goal_is_trimmed_out(clock):
    # the autopilot holds 0.5 m east of every plain position setpoint (PX4 SIH hovered 0.4-0.5 m off): the
    # mission moves its hold setpoint against the offset until the vehicle is over the goal
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    biased(v, 0.5)
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.landing_error_m <= 0.3
    commanded_east = v.gotos[-1][1] - 0.5  # gotos records what reached the fake, 0.5 m east of the command
    assert -0.5 <= commanded_east - (40 + 50) <= -0.2  # told to hold west of the goal, it sits over it


def test_an_offset_too_large_to_trim_lands_there_after_the_leg_timeout(clock):
    # 2 m east of every hold setpoint, trims go up to 1.5 m: never within the tolerance; the last leg (40 m) gets
    # 60 s + 40 m / 1 m/s = 100 s, then it lands where it is
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    biased(v, 2.0)
    with pytest.raises(m.FlightAborted, match=r"waypoint 3 \(60\.0 N, 40\.0 E, 10\.0 m\) not reached in time "
                                              r"\(100 s\): 0\.50 m off horizontally.*landed at \(60\.0 N, 40\.5 E\)"
                       ) as err:
        make_mission(v, clock, straight_plan([])).run()
    assert "the goal needs <= 0.3 m" in str(err.value)
    result = err.value.result
    assert result.final_state is S.MANUAL and not result.completed
    assert result.landing_error_m == pytest.approx(0.5, abs=0.01)
    assert v.calls[-3:] == ["land", "disarm", "release_control"] and v.telemetry.on_ground
    # climb 2 s + 60 m at 5 m/s + the last leg's 100 s timeout + 10 m descent at 1.5 m/s
    assert clock.now == pytest.approx(2 + 12 + 100 + 10 / 1.5, abs=1.0)


def test_settling_just_outside_the_tolerance_lands_after_settle_s(clock):
    # position noise keeps the vehicle 0.4 m off (within 1.5 x 0.3 m) whatever it is told: accepted after 3 s
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    goto = v.goto_local
    v.goto_local = lambda n, e, d, yaw, velocity_ned=None: goto(n, e, d, yaw, velocity_ned) if velocity_ned \
        else goto(60 - 100, 40 + 50 + 0.4, d, yaw)  # wherever the hold setpoint goes, it sits 0.4 m east
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.landing_error_m == pytest.approx(0.4, abs=0.01)


# ------------------------------------------------------- what the mutants of the mission showed unguarded
def test_the_summary_names_recoveries_and_replans_only_when_there_were_some():
    quiet = m.MissionResult(S.MANUAL, planned_length_m=120.0, flown_length_m=118.0, airborne_s=30.0,
                            landing_error_m=0.1)
    assert "recoveries" not in quiet.summary() and "replans" not in quiet.summary()
    eventful = m.MissionResult(S.MANUAL, planned_length_m=120.0, flown_length_m=118.0, airborne_s=30.0,
                               landing_error_m=0.1, recoveries=2, replans=["a", "b", "c"])
    assert eventful.summary().endswith(", 2 recoveries, 3 replans")


def standing(v, north_m=0.0, east_m=0.0, altitude_m=10.0, v_north_mps=0.0, v_east_mps=0.0):
    """Put the fake at a map position (no offset before preflight) with a horizontal velocity."""
    t = v.telemetry
    t.north_m, t.east_m, t.down_m = north_m, east_m, -altitude_m
    t.local_v_north_mps, t.local_v_east_mps = v_north_mps, v_east_mps


@pytest.mark.parametrize("where, over_the_goal", [
    (dict(north_m=2.0), False),  # 2 m north of it, standing still
    (dict(east_m=2.0), False),
    (dict(v_north_mps=2.0), False),  # over it, still flying north at 2 m/s
    (dict(v_east_mps=2.0), False),
    (dict(altitude_m=15.0), False),  # 5 m above it
    (dict(north_m=0.5), True),  # the tolerances are inclusive: 0.5 m off, 0.25 m/s, 1 m vertically
    (dict(east_m=0.5, v_north_mps=0.25), True),
    (dict(altitude_m=11.0), True),
])
def test_over_the_goal_means_within_the_tolerance_horizontally_and_vertically_and_slow(clock, where, over_the_goal):
    v = FakeVehicle(clock)
    mission = make_mission(v, clock, straight_plan([]), goal_tolerance_m=0.5, stop_speed_mps=0.25)
    standing(v, **where)
    assert mission._at_goal(np.array([0.0, 0.0, 10.0, 0.0])) is over_the_goal


@pytest.mark.parametrize("where, settles", [
    (dict(north_m=0.7), True),  # within 1.5 x 0.5 m, still
    (dict(north_m=-0.75), True),  # exactly 1.5 x the tolerance
    (dict(north_m=0.6, v_east_mps=0.5), True),  # exactly 2 x the stop speed
    (dict(north_m=0.6, v_east_mps=0.6), False),  # a little faster: not settling
    (dict(north_m=0.6, v_north_mps=1.0), False),  # drifting through at 1 m/s
    (dict(north_m=0.8), False),  # outside 1.5 x the tolerance
])
def test_a_vehicle_settled_near_the_goal_counts_after_exactly_settle_s(clock, where, settles):
    v = FakeVehicle(clock)
    mission = make_mission(v, clock, straight_plan([]), goal_tolerance_m=0.5, stop_speed_mps=0.25, settle_s=3.0)
    standing(v, **where)
    wp = np.array([0.0, 0.0, 10.0, 0.0])
    answers = []
    for now in (10.0, 11.0, 12.0, 12.5, 13.0):
        clock.now = now
        answers.append(mission._at_goal(wp))
    assert answers == [False, False, False, False, settles]  # 3 s after the first look, not before


@pytest.mark.parametrize("elapsed_s, autopilot_s, rate", [
    (2.0, 20.0, 10.0),  # a simulator sped up 10 x
    (1.0, 10.0, 10.0),
    (2.0, 0.8, 0.4),  # one running slow
    (0.1, 1.0, 1.0),  # too soon after the takeoff to tell
    (2.0, 0.0, 1.0),  # a clock that stands still says nothing
    (2.0, math.nan, 1.0),  # no clock at all: a real autopilot's pace
])
def test_the_autopilot_rate_is_its_clock_over_ours_since_the_takeoff(clock, elapsed_s, autopilot_s, rate):
    v = FakeVehicle(clock)
    mission = make_mission(v, clock, straight_plan([]))
    mission._takeoff_s, mission._takeoff_autopilot_s = 5.0, 100.0  # the takeoff command at 5 s ours, 100 s its
    clock.now = 5.0 + elapsed_s
    v.telemetry.local_time_s = 100.0 + autopilot_s
    assert mission._autopilot_rate() == pytest.approx(rate)


def test_a_frame_jump_is_re_tied_after_two_readings_a_quarter_second_apart_and_a_glitch_is_not(clock):
    v = FakeVehicle(clock)
    base, j1, j2 = LocalNED(0.0, 0.0, 0.0), LocalNED(3.0, 0.0, 0.0), LocalNED(3.0, 3.0, 0.0)  # 3 m jumps count
    # what map_offset_now reads at each time (s): a one-reading glitch, a jump that stays, a glitch, a jump
    readings = {-0.25: j1, 0.0: base, 0.25: j1, 0.5: base, 0.75: base, 1.0: j1, 1.25: j1, 1.5: j2, 1.75: j1,
                2.0: j2, 2.25: j2, 2.5: j2}  # the very first reading is a glitch too
    expected = {-0.25: base, 0.0: base, 0.25: base, 0.5: base, 0.75: base, 1.0: base, 1.25: j1, 1.5: j1, 1.75: j1,
                2.0: j1, 2.25: j2, 2.5: j2}
    asked = []

    def map_offset_now(origin, ground):
        asked.append(origin)
        return readings[clock.now]

    v.map_offset_now, v.shift_setpoint = map_offset_now, lambda dn, de, dd: None
    mission = make_mission(v, clock, straight_plan([]))
    offsets = {}
    for now in readings:
        clock.now = now
        mission._check_local_frame()
        mission._check_local_frame()  # a second look within the quarter second reads nothing
        offsets[now] = mission._offset
    assert offsets == expected
    assert asked == [ORIGIN] * len(readings)  # one reading per quarter second, of the map's origin


def test_a_disarm_refused_for_a_while_is_retried_every_half_second_until_accepted(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.disarm_refusals = 20  # refused for 10 s at one try per 0.5 s, within the 15 s timeout
    result = make_mission(v, clock, straight_plan([]), disarm_timeout_s=15.0).run()
    assert result.completed and not v.telemetry.armed
    assert v.calls.count("disarm") == 21


def test_the_progress_lines_give_the_distance_left_and_the_speed_flown(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    seen = []  # each line with where the vehicle was (map) and how fast it moved then

    def progress(line):
        t = v.telemetry
        seen.append((line, t.north_m + 100.0, t.east_m - 50.0, math.hypot(t.local_v_north_mps, t.local_v_east_mps)))

    make_mission(v, clock, straight_plan([]), progress=progress, progress_every_s=1.0).run()
    numbered = [(re.match(r"(?:flying: |waypoint \d/\d reached: )(\d+) m to go at ([\d.]+) m/s", line), n, e, speed)
                for line, n, e, speed in seen]
    numbered = [(float(x.group(1)), float(x.group(2)), n, e, speed) for x, n, e, speed in numbered if x]
    assert len(numbered) >= 15
    for to_go_m, said_mps, n, e, speed in numbered:
        assert said_mps == pytest.approx(speed, abs=0.051)
        if 55.0 < n and e < 5.0:
            continue  # rounding the corner: the planned legs are no oracle for the distance there
        left_m = (60.0 - n) + 40.0 if n < 59.0 else 40.0 - e  # along the planned legs: 60 m north, 40 m east
        assert to_go_m == pytest.approx(left_m, abs=2.0)
    east_leg = [said for to_go, said, n, e, speed in numbered if 5.0 < e < 35.0]
    north_leg = [said for to_go, said, n, e, speed in numbered if 5.0 < n < 55.0]
    assert east_leg and north_leg and min(east_leg + north_leg) > 4.0  # 5 m/s on both legs, not 0


def biased_north(v, offset_north_m):
    """The vehicle settles ``offset_north_m`` north of a position-only setpoint."""
    real_goto = v.goto_local

    def goto(north_m, east_m, down_m, yaw_rad, velocity_ned=None):
        real_goto(north_m + (offset_north_m if velocity_ned is None else 0.0), east_m, down_m, yaw_rad, velocity_ned)

    v.goto_local = goto


def test_a_steady_offset_to_the_north_over_the_goal_is_trimmed_out(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    biased_north(v, 0.5)
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.landing_error_m <= 0.3
    commanded_north = v.gotos[-1][0] - 0.5
    assert -0.5 <= commanded_north - (60 - 100) <= -0.2  # told to hold south of the goal


def test_a_legs_deadline_is_the_leg_timeout_plus_the_leg_at_the_minimum_speed(clock):
    # 0.5 m/s where 1 m/s is the least expected: the 60 m north leg (at east 50 m) gets 5 s + 60 m / (1 m/s)
    v = FakeVehicle(clock, start=(-100.0, 100.0), speed_mps=0.5)
    with pytest.raises(m.FlightAborted, match=r"waypoint 1 \(60\.0 N, 50\.0 E, 10\.0 m\) not reached in time \(65 s\)"):
        make_mission(v, clock, fixed_plan([]), leg_timeout_s=5.0, min_speed_mps=1.0, takeoff_timeout_s=100.0,
                     poll_s=0.1).run()
    # fast enough for the same leg: 5 m/s flies it in 12 s, well within; the last leg is 10 m east
    v = FakeVehicle(clock, start=(-100.0, 100.0), speed_mps=5.0)
    assert make_mission(v, clock, fixed_plan([]), leg_timeout_s=5.0, min_speed_mps=1.0).run().completed


def test_the_corner_cut_and_the_speed_limits_given_shape_the_flight(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([]), corner_cut_m=2.0, lateral_accel_mps2=0.5,
                          accel_mps2=0.5).run()
    assert result.completed
    corner = np.array([60.0, 0.0])
    nearest_m = min(float(np.linalg.norm(row[1:3] - corner)) for row in result.track)
    assert nearest_m == pytest.approx(2.0 * math.sqrt(2), abs=0.5)  # the arc's middle 2 m inside both legs
    commands = [(np.array(g[:2]) + (100.0, -50.0), np.linalg.norm(vel[:2]))
                for g, vel in zip(v.gotos, v.velocities, strict=True) if vel is not None]
    radius_m = 2.0 / (1.0 - math.cos(math.pi / 4))
    on_arc = [speed for at, speed in commands if np.linalg.norm(at - corner) < 4.0]
    assert on_arc and max(on_arc) <= math.sqrt(0.5 * radius_m) + 0.3  # 1.85 m/s at 0.5 m/s^2 sideways
    # braking at 0.5 m/s^2: 10 m before the arc the path allows sqrt(1.85^2 + 2 x 0.5 x 10) = 3.7 m/s
    # braking at 0.5 m/s^2 towards the arc (it starts r tan 45 deg = r before the corner): at d m before it the path
    # allows sqrt(1.85^2 + 2 x 0.5 x d)
    before = [(60.0 - radius_m - at[0], speed) for at, speed in commands if 30.0 < at[0] < 60.0 - radius_m
              and abs(at[1]) < 1.0]
    assert len(before) > 20 and all(speed <= math.sqrt(0.5 * radius_m + 2 * 0.5 * d) + 0.3 for d, speed in before)


def test_a_climbing_leg_is_flown_within_the_vertical_speed_given(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def climb(n, e):
        return np.array([[n, e, 10.0, 0.0], [n + 60.0, e, 30.0, 0.0]])

    assert make_mission(v, clock, climb, vertical_mps=0.5).run().completed
    climbs = [-vel[2] for vel in v.velocities if vel is not None]
    assert max(climbs) == pytest.approx(0.5, abs=0.05)


def test_the_track_is_sampled_every_track_interval_s(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, straight_plan([]), track_interval_s=0.5).run()
    steps = np.diff(result.track[:, 0])
    assert len(result.track) == pytest.approx(result.flight_time_s / 0.5, abs=5)
    assert np.median(steps) == pytest.approx(0.5, abs=0.03)


def test_the_takeoff_from_a_roof_asks_for_the_height_above_the_roof(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.amsl_at_zero_m = GROUND_AMSL_M + 8.0  # standing on an 8 m roof
    asked = []
    real_takeoff = v.takeoff
    v.takeoff = lambda altitude_m: asked.append(altitude_m) or real_takeoff(altitude_m)
    result = make_mission(v, clock, straight_plan([]), ground_amsl_m=GROUND_AMSL_M).run()
    assert result.completed and asked == [pytest.approx(2.0)]  # to 10 m above the map's ground: 2 m above it


def test_a_goal_next_to_the_start_or_at_it_is_flown_and_landed(clock):
    for goal_north_m in (0.4, 0.0):  # 0.4 m: settling distance from the first look; 0: a plan of one waypoint
        v = FakeVehicle(clock, start=(-100.0, 50.0))

        def plan(n, e, goal_north_m=goal_north_m):
            if goal_north_m == 0.0:
                return np.array([[n, e, 10.0, 0.0]])
            return np.array([[n, e, 10.0, 0.0], [n + goal_north_m, e, 10.0, 0.0]])

        result = make_mission(v, clock, plan).run()
        assert result.completed and result.landing_error_m <= 0.3 and not v.telemetry.armed
        assert result.waypoints[0, 3] == 0.0  # no leg to turn to: north


def test_a_vehicle_that_stops_following_is_noticed_after_stuck_s_and_given_up_on_after_max_recoveries(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    lines, retaken_at = [], []
    clock.at(8.0, lambda: setattr(v, "speed_mps", 0.0))  # it stops following for good at 8 s
    real_take = v.take_control
    v.take_control = lambda: retaken_at.append(clock.now) or real_take()
    with pytest.raises(m.FlightAborted, match="control lost 3 times, giving up.*landed"):
        make_mission(v, clock, straight_plan([]), progress=lines.append, stuck_s=3.0, max_recoveries=2,
                     accel_mps2=6.0).run()  # 6 m/s^2: its first command after each retake is over 1 m/s
    assert len(retaken_at) == 2 and 11.0 <= retaken_at[0] <= 11.2  # standing still for 3 s, not at once
    assert retaken_at[1] - retaken_at[0] >= 3.0
    assert any("stopped following our setpoints" in line for line in lines)
    assert not v.telemetry.armed and v.telemetry.on_ground


def test_the_link_lost_while_arming_leaves_the_vehicle_on_the_ground(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    real_prepare = v.prepare_flight

    def prepare_then_lose_the_link():
        real_prepare()
        v.link_ok = False

    v.prepare_flight = prepare_then_lose_the_link
    with pytest.raises(m.LinkLostInFlight, match="while arming; the vehicle is on the ground") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert err.value.result.final_state is S.FAILED and not v.telemetry.armed


class Busy(Exception):
    """A vehicle error that says nothing about being permanent (no ``permanent`` attribute)."""


def test_an_arm_refusal_that_does_not_say_it_is_permanent_is_retried(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.fail_on["arm"] = Busy("busy")
    result = make_mission(v, clock, straight_plan([]), vehicle_errors=(Refused, Busy)).run()
    assert result.completed and v.calls.count("arm") == 2



def test_any_positive_altitude_is_accepted_even_below_a_metre(clock):
    assert make_mission(FakeVehicle(clock), clock, straight_plan([]), altitude_m=0.5).altitude_m == 0.5


def test_the_first_setpoint_after_the_takeoff_is_the_start_of_the_path(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    assert make_mission(v, clock, straight_plan([])).run().completed
    first = v.gotos[0]
    assert (first[0] + 100.0, first[1] - 50.0, -first[2]) == pytest.approx((0.0, 0.0, 10.0), abs=0.3)


def test_path_length_of_one_two_and_more_points():
    assert fp.path_length_m(np.array([[1.0, 2.0, 3.0]])) == 0.0
    assert fp.path_length_m(np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]])) == pytest.approx(5.0)


def test_a_planner_of_integers_without_altitudes_gets_float_headings_and_the_flight_altitude(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def plan(n, e):  # plain Python numbers; NaN altitude: "fly at altitude_m"
        return [[0, 0, math.nan, 0], [60, 0, math.nan, 0], [60, 40, 12, 0]]

    result = make_mission(v, clock, plan, altitude_m=8.0).run()
    assert result.completed
    assert result.waypoints[:, 2].tolist() == [8.0, 8.0, 12.0]
    assert result.waypoints[:, 3] == pytest.approx([0.0, 0.0, math.pi / 2])  # along each leg, not truncated
    # planned: the climb to 8 m, the legs (60 m; 40 m rising 4 m), the descent from the last waypoint's 12 m
    assert result.planned_length_m == pytest.approx(8.0 + 60.0 + math.hypot(40.0, 4.0) + 12.0)


def test_repeated_progress_lines_come_once_per_progress_every_s(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), arm_refusals=12)  # refused for 12 s at one try a second
    times, lines = [], []

    def progress(line):
        times.append(clock.now)
        lines.append(line)

    result = make_mission(v, clock, straight_plan([]), progress=progress, progress_every_s=5.0).run()
    assert result.completed
    for prefix in ("arming refused", "flying:"):
        at = [t for t, line in zip(times, lines, strict=True) if line.startswith(prefix)]
        assert len(at) >= 2 and min(np.diff(at)) >= 5.0 - 1e-9, prefix
    assert 2 <= sum(line.startswith("arming refused") for line in lines) <= 3  # 12 s of refusals: at 0, 5, 10 s


def test_arming_gives_up_at_the_readiness_deadline_not_a_retry_later(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), arm_refusals=10**6)
    with pytest.raises(m.ArmingFailed):
        make_mission(v, clock, straight_plan([]), arm_timeout_s=10.0, arm_retry_s=0.7).run()
    assert clock.now == pytest.approx(10.0, abs=1e-9)  # the last wait is cut to the deadline


def test_the_link_lost_while_waiting_for_readiness_is_reported_before_takeoff(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0), ready_at_s=30.0)
    clock.at(2.0, lambda: setattr(v, "link_ok", False))
    with pytest.raises(m.LinkLostInFlight, match="before takeoff"):
        make_mission(v, clock, straight_plan([])).run()
    assert "arm" not in v.calls


def test_the_offset_line_says_whether_the_vehicle_stands_on_a_roof(clock):
    said = {}
    for name, kwargs, amsl in (("roof", dict(surface_fn=lambda n, e: 8.0 if abs(n) < 1 else 0.0), 8.0),
                               ("given", dict(ground_amsl_m=GROUND_AMSL_M), 0.0)):
        clock = FakeClock()
        v = FakeVehicle(clock, start=(-100.0, 50.0))
        v.telemetry.amsl_at_zero_m = GROUND_AMSL_M + amsl
        lines = []
        make_mission(v, clock, straight_plan([]), progress=lines.append, **kwargs).run()
        said[name] = next(line for line in lines if line.startswith("map ground at"))
    assert "(the vehicle stands on a 8.0 m roof)" in said["roof"]
    assert "(the vehicle stands on the ground)" in said["given"]  # ground given outright: no roof measured


def test_the_autopilots_response_time_makes_it_brake_earlier(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.limits.response_s = 0.8
    mission = make_mission(v, clock, straight_plan([]))
    assert mission.run().completed and mission.brake_lag_s == 0.8


def test_an_outage_during_the_takeoff_is_ridden_out_and_the_mission_completes(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    outage(clock, v, 1.0, 2.0)  # climbing at 5 m/s: lost at 5 m
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.recoveries == 1 and result.replans == []


def test_a_vertical_leg_keeps_the_heading_and_the_last_leg_follows_the_path(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def plan(n, e):  # up 10 m on the spot, then 30 m east, then 30 m north
        return np.array([[n, e, 10.0, 0.0], [n, e, 20.0, 0.0], [n, e + 30.0, 20.0, 0.0],
                         [n + 30.0, e + 30.0, 20.0, 0.0]])

    takeoffs = []
    real_takeoff = v.takeoff
    v.takeoff = lambda altitude_m: takeoffs.append(altitude_m) or real_takeoff(altitude_m)
    result = make_mission(v, clock, plan).run()
    assert result.completed and takeoffs == [pytest.approx(10.0)]  # to the first waypoint, then up the leg
    yaws = [g[3] for g in v.gotos]
    assert all(isinstance(y, float) and math.isfinite(y) for y in yaws)
    corners = np.array([[0.0, 0.0], [0.0, 30.0], [30.0, 30.0]])
    streamed = [np.array(g[:2]) + (100.0, -50.0) for g, vel in zip(v.gotos, v.velocities, strict=True)
                if vel is not None]
    last_leg = [at for at in streamed if at[0] > 3.0 and np.linalg.norm(at - (30.0, 30.0)) > 5.0]
    assert last_leg and max(_distance_to_polyline(at, corners) for at in last_leg) < 0.6  # on the path, not the goal


def test_the_feedforward_never_coasts_into_a_wall_beyond_the_goal(clock):
    # the goal 5 m short of a wall across the map; the autopilot coasts 3 s and brakes at 2.5 m/s^2 on a lost link
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def plan(n, e):
        return np.array([[n, e, 10.0, 0.0], [n + 60.0, e, 10.0, 0.0]])

    result = make_mission(v, clock, plan, clearance_fn=wall_north_at(65.0)).run()
    assert result.completed
    for g, vel in zip(v.gotos, v.velocities, strict=True):
        if vel is not None:
            north_m = g[0] + 100.0
            assert north_m + v.limits.coast_m(float(np.linalg.norm(vel[:2]))) <= 65.0 + 1e-6


def test_a_planner_of_plain_integers_gets_float_headings(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    result = make_mission(v, clock, lambda n, e: [[0, 0, 10, 0], [60, 0, 10, 0], [60, 40, 10, 0]]).run()
    assert result.completed and result.waypoints[:, 3] == pytest.approx([0.0, 0.0, math.pi / 2])


def test_a_vehicle_not_yet_standing_disarmed_on_the_ground_is_waited_for_with_a_line_every_5_s(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.on_ground = False  # its estimator still says it moves; it settles at 11.1 s
    clock.at(11.1, lambda: setattr(v.telemetry, "on_ground", True))
    lines, planned_at = [], []
    plan = straight_plan([])
    result = make_mission(v, clock, lambda n, e: planned_at.append(clock.now) or plan(n, e),
                          progress=lines.append).run()
    assert result.completed
    assert sum(line.startswith("waiting for the vehicle to stand disarmed") for line in lines) == 3  # 0, 5, 10 s
    assert 11.1 <= planned_at[0] <= 11.1 + 0.2 + 1e-9  # looked at every 0.2 s


def test_an_armed_vehicle_is_refused_as_armed(clock):
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.armed = True  # armed on the ground
    with pytest.raises(m.NotReady, match="the vehicle is armed: a mission starts from a vehicle disarmed"):
        make_mission(v, clock, straight_plan([]), arm_timeout_s=2.0).run()


# ------------------------------------------------------------------------- missions against sim/
# conftest's map: one building, north 25..35 m, east -5..5 m, 20 m tall, at the map origin 37.79248, -122.39745.
SIM_ORIGIN = Geodetic(37.792480, -122.397450, 0.0)


def around_the_building(start_north_m, start_east_m):
    """Hand-made plan at 10 m: from the start, 12 m east of the building (>= 7 m clear), to 60 m north."""
    return np.array([[start_north_m, start_east_m, 10.0, 0.0], [18.0, 12.0, 10.0, 0.0], [42.0, 12.0, 10.0, 0.0],
                     [60.0, 0.0, 10.0, 0.0]])


def fly(sim, plan_fn=around_the_building, **kwargs):
    from skyroute import vehicle as vh  # pymavlink only in the flight tests

    with vh.MavlinkVehicle(f"tcp:127.0.0.1:{sim.port}", heartbeat_timeout_s=5.0,
                           link_floor_s=kwargs.pop("link_floor_s", 2.0)) as v:
        mission = m.Mission(v, plan_fn, altitude_m=10.0, map_origin=SIM_ORIGIN, vehicle_errors=(vh.VehicleError,),
                            **kwargs)
        return mission.run()


@pytest.mark.flight
@pytest.mark.parametrize("autopilot, start, origin", [
    ("px4", None, "home"),
    ("px4", (37.792300, -122.397300), "boot"),  # ~20 m S, 13 m E of the map origin; EKF origin = boot point
    ("ardupilot", None, "home"),
])
def test_mission_against_sim(sim_start, autopilot, start, origin):
    sim = sim_start(strict=True, autopilot=autopilot, start=start, origin=origin)
    result = fly(sim)
    report = sim.stop()
    assert result.completed and result.final_state is S.MANUAL
    assert report["landed"]["north_m"] == pytest.approx(60.0, abs=1.0)
    assert report["landed"]["east_m"] == pytest.approx(0.0, abs=1.0)
    assert not report["collisions"] and not report["crashed"]
    assert report["min_clearance_m"] >= 5.0
    assert not report["final"]["armed"]
    assert result.landing_error_m < 1.0


@pytest.mark.flight
def test_mission_retries_arming_against_sim(sim_start):
    sim = sim_start(strict=True, faults={"deny_arm_count": 2})
    result = fly(sim, arm_retry_s=0.2)
    report = sim.stop()
    arms = [c for c in report["commands"] if c["name"] == "MAV_CMD_COMPONENT_ARM_DISARM" and c["params"][0] == 1]
    assert [c["result_name"] for c in arms] == ["MAV_RESULT_TEMPORARILY_REJECTED"] * 2 + ["MAV_RESULT_ACCEPTED"]
    assert result.completed


@pytest.mark.flight
def test_mission_no_path_never_takes_off_against_sim(sim_start):
    sim = sim_start(strict=True)

    def no_path(n, e):
        raise m.NoPathFound("walled in")

    with pytest.raises(m.NoPathFound):
        fly(sim, no_path)
    report = sim.stop()
    assert not report["airborne_time_s"] and not report["landings"]  # never left the ground
    assert not report["final"]["armed"]


@pytest.mark.flight
def test_mission_link_outage_against_sim(sim_start):
    # the link drops for 5 s (wall) in flight, then comes back: the mission takes control back and completes (the
    # sim's faults run on its clock: at speed-up 2 that is 10 s of its time, from 8 s, when it flies)
    sim = sim_start(strict=True, speedup=2.0, faults={"outage_start_s": 8.0, "outage_duration_s": 10.0})
    result = fly(sim, link_lost_timeout_s=10.0)
    report = sim.stop()
    assert result.completed and result.recoveries >= 1
    assert (S.WAYPOINT, E.LINK_LOST, S.RECOVERING) in result.history or \
        (S.TAKEOFF, E.LINK_LOST, S.RECOVERING) in result.history
    assert report["final"]["on_ground"] and not report["final"]["armed"] and not report["collisions"]
    assert report["landed"]["north_m"] == pytest.approx(60.0, abs=1.0)


@pytest.mark.flight
def test_mission_link_lost_for_good_against_sim(sim_start):
    # speed-up 1: the sim's clock is the wall clock, whichever its link faults run on; airborne from ~4 s
    sim = sim_start(strict=True, speedup=1.0, faults={"outage_start_s": 8.0, "outage_duration_s": 600.0})
    with pytest.raises(m.LinkLostInFlight, match="failsafe") as err:
        fly(sim, link_lost_timeout_s=2.0)
    assert err.value.result.final_state is S.FAILED
    assert not sim.stop()["collisions"]


@pytest.mark.flight
def test_600_m_mission_time_against_sim(sim_start, tmp_path):
    # ~630 m with two right-angle turns; the issue's bound: 1.3 x (flown / cruise + takeoff + landing)
    def plan(n, e):
        return np.array([[a, b, 10.0, 0.0] for a, b in
                         [(n, e), (n, e + 100), (n + 300, e + 100), (n + 300, e + 300), (n + 310, e + 310)]])

    from sim.params import table_for

    sim = sim_start(strict=True, speedup=10.0, tlog_path=tmp_path / "sim.tlog")
    result = fly(sim, plan, handover_m=0.0)  # the autopilot's landing all the way down: its sink rate is checked
    report = sim.stop()
    px4 = table_for("px4")  # the simulated PX4's parameters (PX4 1.15's defaults), not the client's numbers
    # cruise: the mission's documented 10 m/s, within MPC_XY_VEL_MAX; climb MPC_Z_VEL_MAX_UP; a landing sinks at
    # MPC_LAND_SPEED (0.7 m/s, not the 1.5 m/s of MPC_Z_VEL_MAX_DN this test once assumed)
    cruise_mps = min(10.0, px4["MPC_XY_VEL_MAX"].default)
    climb_mps, landing_mps = px4["MPC_Z_VEL_MAX_UP"].default, px4["MPC_LAND_SPEED"].default
    # the landing's sink rate as flown, from the sim's own track (GLOBAL_POSITION_INT in its tlog, stamped in
    # simulated time): from 8 m to 2 m above home on the way down
    sink = _final_descent_rate_mps(tmp_path / "sim.tlog", from_m=8.0, to_m=2.0)
    print(f"\nlanding sink {sink:.3f} m/s against MPC_LAND_SPEED {landing_mps} m/s")
    assert sink == pytest.approx(landing_mps, rel=0.1)
    ideal_s = (report["distance_flown_m"] - 20.0) / cruise_mps + 10.0 / climb_mps + 10.0 / landing_mps
    assert result.completed and not report["collisions"]
    assert report["airborne_time_s"] <= 1.3 * ideal_s


def _final_descent_rate_mps(tlog, from_m: float, to_m: float) -> float:
    """Mean sink rate (m/s, simulated time) of the last descent from ``from_m`` to ``to_m`` above home."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tlog))
    track = []  # (sim s, m above home) of the vehicle (system 1)
    try:
        while (msg := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
            if msg.get_srcSystem() == 1:
                track.append((msg.time_boot_ms / 1e3, msg.relative_alt / 1e3))
    finally:
        log.close()
    below = max(k for k, (_, up) in enumerate(track) if up >= from_m)  # the last time it was that high
    end = next(k for k in range(below, len(track)) if track[k][1] <= to_m)
    (t0, up0), (t1, up1) = track[below], track[end]
    return (up0 - up1) / (t1 - t0)


@pytest.mark.flight
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_corners_are_flown_round_within_a_metre_of_the_legs_against_sim(sim_start, autopilot):
    # two right angles round the building (N 25..35, E -5..5): 15 m east, 45 m north, 30 m west, at 10 m
    def plan(n, e):
        return np.array([[n, e, 10.0, 0.0], [0.0, 15.0, 10.0, 0.0], [45.0, 15.0, 10.0, 0.0],
                         [45.0, -15.0, 10.0, 0.0]])

    sim = sim_start(strict=True, autopilot=autopilot, speedup=5.0)
    result = fly(sim, plan, track_interval_s=0.02)
    report = sim.stop()
    assert result.completed and not report["collisions"]
    legs = result.waypoints[:, :3]
    at_altitude = result.track[np.abs(result.track[:, 3] - 10.0) < 0.5, 1:4]
    deviation = max(_distance_to_polyline(np.array([n, e, 10.0]), legs) for n, e, _ in at_altitude)
    # the arcs are 0.5 m inside each corner (corner_cut_m); tracking adds the rest
    assert deviation <= 1.0
    assert report["landed"]["north_m"] == pytest.approx(45.0, abs=1.0)
    assert report["landed"]["east_m"] == pytest.approx(-15.0, abs=1.0)
    print(f"\n{autopilot}: max deviation from the legs {deviation:.2f} m, airborne {report['airborne_time_s']:.1f} s")


# ------------------------------------------------------------------------ vehicle errors no step retries
def test_a_vehicle_error_before_arming_is_not_ready_and_never_arms(clock):
    # the frame read in preflight times out (a radio dropout): one MissionError, not the raw vehicle error
    v = FakeVehicle(clock, start=(-100.0, 50.0))

    def map_offset(origin, ground):
        raise Refused("timed out after 5 s waiting for GPS_GLOBAL_ORIGIN")

    v.map_offset = map_offset
    with pytest.raises(m.NotReady, match="the vehicle failed in state PREFLIGHT: timed out after 5 s") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert "arm" not in v.calls and not v.telemetry.armed
    assert err.value.result is not None


def test_a_vehicle_error_after_arming_lands_and_is_a_flight_abort(clock):
    # the frame is re-read right after arming (map_offset_now); if that read fails, the armed vehicle is landed
    # and disarmed and the error says so, instead of escaping as a traceback
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    real = v.map_offset
    reads = []

    def map_offset(origin, ground):
        reads.append(v.telemetry.armed)
        if v.telemetry.armed:
            raise Refused("timed out after 5 s waiting for LOCAL_POSITION_NED")
        return real(origin, ground)

    v.map_offset, v.map_offset_now = map_offset, map_offset
    with pytest.raises(m.FlightAborted, match="the vehicle failed in state .*LOCAL_POSITION_NED") as err:
        make_mission(v, clock, straight_plan([])).run()
    assert reads[-1] is True and not v.telemetry.armed and v.telemetry.on_ground
    assert err.value.result is not None


def test_after_an_outage_the_mode_is_judged_from_a_heartbeat_sent_after_it(clock):
    # the failsafe's mode change reaches us with the next heartbeat, up to a second after the link is back: a
    # recovery that judged the stale "offboard" would not take control back and would fly on in HOLD
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    v.telemetry.last_heartbeat_s = 0.0
    clock.at(8.0, lambda: setattr(v, "link_ok", False))
    clock.at(11.0, lambda: setattr(v, "link_ok", True))
    clock.at(11.8, lambda: (setattr(v, "mode", "hold"), setattr(v.telemetry, "last_heartbeat_s", 11.8)))
    result = make_mission(v, clock, straight_plan([])).run()
    assert result.completed and result.recoveries == 1
    assert v.calls.count("take_control") == 1


def test_after_a_return_above_a_roof_it_gets_over_free_ground_before_descending(clock):
    """The autopilot's return took the vehicle to 25 m, over a roof; the new plan starts at the nearest point free
    at the flight altitude, 12 m off. The vehicle goes there at 25 m and descends only over it."""
    v = FakeVehicle(clock, start=(-100.0, 50.0))
    outage(clock, v, 8.0, 3.0)

    def carried_up():  # RTL: climbed to its return altitude and moved off the path
        v.telemetry.east_m += 10.0
        v.telemetry.down_m = -25.0

    clock.at(9.0, carried_up)
    planned = []

    def plan(start_north_m, start_east_m):  # replans start 12 m west of the vehicle: the roof's edge plus margin
        planned.append((start_north_m, start_east_m))
        first = (start_north_m, start_east_m - (12.0 if len(planned) > 1 else 0.0))
        return np.array([[*first, 10.0, 0.0], [60.0, first[1], 10.0, 0.0], [60.0, 40.0, 10.0, 0.0]])

    result = make_mission(v, clock, plan, goal_ne=(60.0, 40.0)).run()
    assert result.completed and len(planned) == 2
    start = (planned[1][0], planned[1][1] - 12.0)
    after = result.track[result.track[:, 0] >= 11.0]
    low = after[after[:, 3] < 24.0]
    first_low = low[0]
    assert math.dist(first_low[1:3], start) <= 1.5, first_low  # it left 25 m only over the free start
    assert result.landing_error_m < 0.3
