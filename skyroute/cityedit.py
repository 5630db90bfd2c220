"""Changed cities for tests and demos: walls across the route a map-trusting planner takes, a goal walled in,
buildings removed. ``python -m skyroute.cityedit MAP -o OUT ...`` writes the changed map; the original stays the
client's (stale) map and the changed one the simulator's truth.

Walls are axis-aligned boxes (the map format has no other), standing on the ground, ``thickness_m`` thick across
the street: each sits where the grid planner's route on the ORIGINAL map runs along a straight leg (away from its
corners, the start and the goal), across the leg's main axis, and reaches from the building on one side of the
street to the building on the other (at the flight altitude, up to ``max_half_m`` each way; in an open square it
simply ends there). With ``keep_reachable`` the walls are drawn again (from the same seeded stream) until the goal
can still be reached on the changed map with the same altitude and margin, so a detour exists; the route itself
is always blocked. All positions are map-frame metres (north, east) from the map's home.

>>> boxes = np.array([[0.0, 20.0, 10, 100, 10, 10], [0.0, -20.0, 10, 100, 10, 10]])  # a 20 m wide N-S street
>>> change = walls_across_route(boxes, (-60.0, 0.0), (60.0, 0.0), altitude_m=5, safety_m=2, count=1, seed=0,
...                             keep_reachable=False)
>>> wall = change.added[0]
>>> bool(wall[4] * 2 >= 20.0), float(wall[3]), float(wall[2] * 2)   # spans the street, 2 m thick, 30 m tall
(True, 1.0, 30.0)
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyroute.citygen import write_colliders
from skyroute.maps import MapFormatError, read_colliders
from skyroute.planning.cspace import create_grid, map_to_cell
from skyroute.planning.errors import PlanningError
from skyroute.planning.grid import GridMap

#: Walls keep at least this far (m, along the route) from its corners, start and goal, beyond the margin.
CLEAR_OF_ENDS_M = 15.0


@dataclass(frozen=True)
class CityChange:
    """A changed city: ``obstacles`` (N, 6) the new map's boxes, ``added`` the walls, ``removed`` the rows of the
    original map that are gone, ``route`` the map-trusting planner's waypoints on the original map (K, 4)."""

    obstacles: np.ndarray
    added: np.ndarray
    removed: tuple[int, ...] = ()
    route: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))


def _route_points(route: np.ndarray, spacing_m: float = 1.0) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``(point, unit direction, distance to the nearest corner/end)`` every ``spacing_m`` along the route."""
    out = []
    pts = route[:, :2]
    for a, b in zip(pts[:-1], pts[1:]):
        leg = b - a
        length = float(np.hypot(*leg))
        if length < 1e-9:
            continue
        u = leg / length
        for s in np.arange(0.0, length, spacing_m):
            out.append((a + u * s, u, min(s, length - s)))
    return out


def _span(footprint: np.ndarray, cell: tuple[int, int], axis: int, max_cells: int) -> tuple[int, int]:
    """Cells from ``cell`` along ``axis`` (0 north, 1 east) to the first blocked cell each way (exclusive), at most
    ``max_cells``: the returned ``(low, high)`` are offsets (<= 0, >= 0) of the last free cells."""
    n, m = footprint.shape
    ends = []
    for step in (-1, 1):
        k = 0
        while abs(k + step) <= max_cells:
            i = cell[0] + (k + step if axis == 0 else 0)
            j = cell[1] + (k + step if axis == 1 else 0)
            if not (0 <= i < n and 0 <= j < m) or footprint[i, j]:
                break
            k += step
        ends.append(k)
    return ends[0], ends[1]


def _wall_at(footprint: np.ndarray, north_offset: int, east_offset: int, point: np.ndarray, direction: np.ndarray,
             *, thickness_m: float, height_m: float, max_half_m: float) -> np.ndarray:
    """A wall box across ``direction`` at ``point``, from building face to building face (see the module notes)."""
    across = 1 if abs(direction[0]) >= abs(direction[1]) else 0  # a north-south leg gets an east-west wall
    cell = map_to_cell(point[0], point[1], north_offset, east_offset)
    low, high = _span(footprint, cell, across, int(max_half_m))
    origin = (north_offset, east_offset)[across]
    # Half a metre into the building; at the map's edge, to the edge and no further: a wall sticking out would
    # grow the changed map's grid by a row the original's lacks, and a route round its end there exists on the
    # truth alone (a held-out mission's true route ran along that row).
    lo = max(origin + cell[across] + low - 0.5, origin)
    hi = min(origin + cell[across] + high + 1.5, origin + footprint.shape[across])
    centre_across, half_across = (lo + hi) / 2.0, (hi - lo) / 2.0
    half_along = thickness_m / 2.0
    if across == 1:
        return np.array([point[0], centre_across, height_m / 2, half_along, half_across, height_m / 2])
    return np.array([centre_across, point[1], height_m / 2, half_across, half_along, height_m / 2])


def _reachable(obstacles: np.ndarray, start_ne, goal_ne, altitude_m: float, safety_m: float) -> bool:
    try:
        GridMap.build(obstacles, altitude_m, safety_m).plan(start_ne, goal_ne, snap_start=True)
    except PlanningError:
        return False
    return True


def walls_across_route(obstacles: np.ndarray, start_ne: Sequence[float], goal_ne: Sequence[float], *,
                       altitude_m: float, safety_m: float, count: int, seed: int, height_m: float = 30.0,
                       thickness_m: float = 2.0, max_half_m: float = 60.0, keep_reachable: bool = True,
                       attempts: int = 40) -> CityChange:
    """Put ``count`` walls across the route the grid planner takes on ``obstacles`` from ``start_ne`` to ``goal_ne``.

    Raises
    ------
    PlanningError
        If the original map has no route; or, with ``keep_reachable``, no draw of ``attempts`` left the goal
        reachable (the message says so).
    ValueError
        If the route is too short to hold ``count`` walls clear of its corners and ends and of each other (no
        draw of ``attempts`` spaced them all out: before, a draw that could not returned fewer walls than asked).
    """
    obstacles = np.asarray(obstacles, dtype=float)
    route = GridMap.build(obstacles, altitude_m, safety_m).plan(start_ne, goal_ne, snap_start=True).waypoints
    footprint, north_offset, east_offset = create_grid(obstacles, altitude_m, 0.0)
    candidates = [(p, u) for p, u, corner_m in _route_points(route)
                  if corner_m >= CLEAR_OF_ENDS_M and math.dist(p, start_ne) > safety_m + CLEAR_OF_ENDS_M
                  and math.dist(p, goal_ne) > safety_m + CLEAR_OF_ENDS_M]
    spacing = max(3.0 * safety_m + thickness_m, 20.0)
    if len(candidates) < count:
        raise ValueError(f"the route ({len(route)} waypoints) has too little straight street for {count} wall(s)")
    rng = np.random.default_rng(seed)
    placed = False
    for _ in range(attempts):
        chosen: list[tuple[np.ndarray, np.ndarray]] = []
        for k in rng.permutation(len(candidates)):
            p, u = candidates[k]
            if all(math.dist(p, q) >= spacing for q, _ in chosen):
                chosen.append((p, u))
            if len(chosen) == count:
                break
        if len(chosen) < count:
            continue  # this order spaced out fewer walls than asked for; another may fit them all
        placed = True
        walls = np.array([_wall_at(footprint, north_offset, east_offset, p, u, thickness_m=thickness_m,
                                   height_m=height_m, max_half_m=max_half_m) for p, u in chosen]).reshape(-1, 6)
        changed = np.vstack([obstacles, walls])
        if not keep_reachable or _reachable(changed, start_ne, goal_ne, altitude_m, safety_m):
            return CityChange(changed, walls, (), route)
    if not placed:
        raise ValueError(f"the route has too little straight street for {count} wall(s) {spacing:g} m apart")
    raise PlanningError(f"no draw of {count} wall(s) across the route in {attempts} attempts left the goal "
                        "reachable; try fewer walls or another seed")


def enclose_goal(goal_ne: Sequence[float], *, ring_m: float, height_m: float = 30.0,
                 thickness_m: float = 1.0) -> np.ndarray:
    """Four walls forming a closed square ring round the goal, its inner faces ``ring_m`` from the goal: the goal
    itself stays free of a margin below ``ring_m`` but cannot be reached.

    >>> enclose_goal((0.0, 0.0), ring_m=10.0, height_m=20.0)[:, [0, 1, 3, 4]].tolist()
    [[10.5, 0.0, 0.5, 11.0], [-10.5, 0.0, 0.5, 11.0], [0.0, 10.5, 11.0, 0.5], [0.0, -10.5, 11.0, 0.5]]
    """
    n, e = float(goal_ne[0]), float(goal_ne[1])
    half_t, reach = thickness_m / 2.0, ring_m + thickness_m
    c = ring_m + half_t
    h = height_m / 2.0
    return np.array([[n + c, e, h, half_t, reach, h], [n - c, e, h, half_t, reach, h],
                     [n, e + c, h, reach, half_t, h], [n, e - c, h, reach, half_t, h]])


def remove_boxes(obstacles: np.ndarray, count: int, seed: int) -> tuple[np.ndarray, tuple[int, ...]]:
    """Remove ``count`` boxes drawn at random (seeded): ``(kept boxes, removed row indices, ascending)``."""
    obstacles = np.asarray(obstacles, dtype=float)
    count = min(int(count), len(obstacles) - 1)
    removed = np.sort(np.random.default_rng(seed).choice(len(obstacles), size=count, replace=False))
    keep = np.ones(len(obstacles), dtype=bool)
    keep[removed] = False
    return obstacles[keep], tuple(int(i) for i in removed)


def _pair(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 2 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected NORTH_M,EAST_M, got {text!r}")
    return values


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        self.exit(2, f"cityedit: error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    """Command line: change a map and write it. Returns the exit code (2 for bad input)."""
    p = _Parser(prog="python -m skyroute.cityedit",
                description="Make a changed city from a colliders.csv map: walls across the route a map-trusting "
                "planner takes, a goal walled in, buildings removed (seeded). Points are map metres NORTH,EAST "
                "from the map's home.", formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("map", type=Path, help="the original map")
    p.add_argument("-o", "--output", type=Path, required=True, help="where to write the changed map")
    p.add_argument("--start", type=_pair, default=(0.0, 0.0), metavar="N,E", help="route start")
    p.add_argument("--goal", type=_pair, default=None, metavar="N,E", help="route goal (needed by --walls and "
                   "--enclose-goal)")
    p.add_argument("--walls", type=int, default=0, help="walls across the route")
    p.add_argument("--enclose-goal", type=float, default=None, metavar="RING_M",
                   help="wall the goal in with a square ring this far from it")
    p.add_argument("--remove", type=int, default=0, help="buildings to remove at random")
    p.add_argument("--height", type=float, default=30.0, help="height of the new walls (m)")
    p.add_argument("--alt", type=float, default=5.0, help="flight altitude of the route (m)")
    p.add_argument("--safety", type=float, default=5.0, help="safety margin of the route (m)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--allow-unreachable", action="store_true", help="do not redraw walls that cut the goal off")
    args = p.parse_args(argv)
    if (args.walls or args.enclose_goal is not None) and args.goal is None:
        p.error("--walls and --enclose-goal need --goal N,E")
    if args.walls < 0 or args.remove < 0 or not 0 < args.height <= 1000:
        p.error("--walls and --remove must be >= 0 and --height in (0, 1000] m")
    try:
        city = read_colliders(args.map)
    except (MapFormatError, OSError) as exc:
        print(f"cityedit: error: {exc}", file=sys.stderr)
        return 2
    boxes, removed = city.obstacles, ()
    try:
        if args.remove:
            boxes, removed = remove_boxes(boxes, args.remove, args.seed)
        added = np.empty((0, 6))
        if args.walls:
            change = walls_across_route(boxes, args.start, args.goal, altitude_m=args.alt, safety_m=args.safety,
                                        count=args.walls, seed=args.seed, height_m=args.height,
                                        keep_reachable=not args.allow_unreachable)
            boxes, added = change.obstacles, change.added
        if args.enclose_goal is not None:
            ring = enclose_goal(args.goal, ring_m=args.enclose_goal, height_m=args.height)
            boxes, added = np.vstack([boxes, ring]), np.vstack([added, ring])
    except (PlanningError, ValueError) as exc:
        print(f"cityedit: error: {exc}", file=sys.stderr)
        return 2
    write_colliders(args.output, boxes, city.lat0_deg, city.lon0_deg)
    print(f"wrote {len(boxes)} boxes to {args.output}: {len(added)} added, {len(removed)} removed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
