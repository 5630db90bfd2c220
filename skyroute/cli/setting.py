"""The planning half of the command line: the map and grid for one flight, endpoint checks, plan output."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyroute.cli.exits import EXIT_NO_PATH, UserError
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic
from skyroute.maps import CityMap, MapFormatError, read_colliders
from skyroute.planning.cspace import nearest_free_in_map
from skyroute.planning.errors import BlockedCellError, NoPathError, OutsideGridError, PlanningError
from skyroute.planning.grid import GridMap
from skyroute.planning.plan import Plan

# ---------------------------------------------------------------------------------------------------------------
# Planning


@dataclass(frozen=True)
class Setting:
    """The map and the grid for the flight altitude, with the home point the map frame is relative to."""

    city: CityMap
    home: Geodetic
    grid_map: GridMap
    altitude_m: float
    safety_m: float

    def landing_point(self, cell: tuple[int, int]) -> tuple[tuple[int, int] | None, bool]:
        """Whether the vehicle may descend in ``cell`` (at least the safety margin from every obstacle, however
        low), and the nearest cell where it may: ``(nearest landing cell or None, blocked)``. Only the
        neighbourhood of ``cell`` is rasterised."""
        grid_map = self.grid_map
        return nearest_free_in_map(self.city.obstacles, 0.0, self.safety_m, grid_map.north_offset,
                                   grid_map.east_offset, grid_map.grid.shape, cell)

    def to_geodetic(self, north_m: float, east_m: float) -> Geodetic:
        return ned_to_geodetic(LocalNED(north_m, east_m, 0.0), self.home)

    def describe(self, north_m: float, east_m: float) -> str:
        """``lat, lon (N .. m, E .. m)`` for messages."""
        p = self.to_geodetic(north_m, east_m)
        return f"{p.lat_deg:.6f}, {p.lon_deg:.6f} (N {north_m:.1f} m, E {east_m:.1f} m)"


def load_setting(map_path: str | Path, altitude_m: float, safety_m: float, *, map_given: bool = True) -> Setting:
    """Read the map and build the configuration-space grid; map problems become :class:`UserError`.

    ``map_given`` says the user named the file (``--map``); only a default map that is missing gets the hint to
    pass one.
    """
    try:
        city = read_colliders(map_path)
    except MapFormatError as exc:
        raise UserError(f"bad map file {exc}") from None
    except OSError as exc:
        hint = " (pass --map FILE)" if isinstance(exc, FileNotFoundError) and not map_given else ""
        raise UserError(f"cannot read map file {map_path}: {exc.strerror or exc}{hint}") from None
    home = Geodetic(city.lat0_deg, city.lon0_deg, 0.0)
    try:
        grid_map = GridMap.build(city.obstacles, altitude_m, safety_m)
    except ValueError as exc:  # e.g. a map over the grid size limit, read with a custom reader
        raise UserError(f"cannot plan on {map_path}: {exc}") from None
    return Setting(city, home, grid_map, altitude_m, safety_m)


def check_endpoint(
    setting: Setting, which: str, north_m: float, east_m: float, *, allow_margin: bool = False,
    on_map_only: bool = False,
) -> None:
    """Raise :class:`UserError` if a start or goal point is off the map or inside an obstacle or its margin.

    With ``allow_margin`` a point inside the safety margin (but outside every obstacle) passes: the planner then
    starts from the nearest free cell. ``on_map_only`` checks only that the point is on the map (a 3D goal, which
    the 3D planner checks at its own altitude). A goal must also keep the margin from buildings lower than the
    flight altitude, since the vehicle descends there.
    """
    grid_map = setting.grid_map
    n, m = grid_map.grid.shape
    i, j = grid_map.cell_of(north_m, east_m)
    where = setting.describe(north_m, east_m)
    if not (0 <= i < n and 0 <= j < m):
        raise UserError(
            f"{which} {where} is off the map, which spans N {grid_map.north_offset}..{grid_map.north_offset + n} m, "
            f"E {grid_map.east_offset}..{grid_map.east_offset + m} m from home"
        )
    if on_map_only:
        return
    if not grid_map.grid[i, j]:
        nearest, blocked = setting.landing_point((i, j)) if which == "goal" else (None, False)
        if blocked:
            hint = "no free point on the map"
            if nearest is not None:
                hint = "nearest free landing point: " + setting.describe(*grid_map.centre_of(nearest))
            raise UserError(
                f"{which} {where} is within the {setting.safety_m:g} m safety margin of a building lower than the "
                f"flight altitude, which the descent would pass; {hint}"
            )
        return
    inside = grid_map.inside_obstacle(north_m, east_m)
    if allow_margin and not inside:
        return
    try:
        grid_map.planner.check_cell(which, (i, j))
    except BlockedCellError as exc:
        what = "inside a building" if inside else f"within the {setting.safety_m:g} m safety margin of a building"
        hint = "no free point on the map"
        if exc.nearest_free is not None:
            hint = "nearest free point: " + setting.describe(*grid_map.centre_of(exc.nearest_free))
        raise UserError(f"{which} {where} is {what} at {setting.altitude_m:g} m altitude; {hint}") from None


def make_plan(
    setting: Setting,
    start_ne: Sequence[float],
    goal_ne: Sequence[float],
    planner: str = "grid",
    *,
    goal_alt_m: float | None = None,
    seed: int = 0,
    snap_start: bool = False,
    samples: int = 1000,
) -> Plan:
    """Plan with the named planner; bad endpoints and "no path" become :class:`UserError` (exit 2 or 3).

    ``seed`` and ``samples`` set the ``prm`` roadmap (its random seed and node count).
    """
    check_endpoint(setting, "start", *start_ne, allow_margin=snap_start)
    if goal_alt_m is None:
        check_endpoint(setting, "goal", *goal_ne)
    try:
        if planner == "grid":
            return setting.grid_map.plan(start_ne, goal_ne, snap_start=snap_start)
        from skyroute.planning import graphs  # the other planners pull in networkx, scipy and scikit-image

        return graphs.plan(
            planner, setting.city.obstacles, start_ne, goal_ne, setting.altitude_m, setting.safety_m,
            goal_alt_m=goal_alt_m, seed=seed, snap_start=snap_start, samples=samples,
        )
    except NoPathError as exc:
        why = str(exc)
        if planner == "prm":
            from skyroute.planning.sampling import RoadmapNoPathError  # the roadmap falls back to grid3d
            if isinstance(exc, RoadmapNoPathError):
                why = why.replace("another seed or more samples", "another --seed or more --samples")
            else:
                why += "; neither the random roadmap nor the complete grid3d search it falls back to found one"
        raise UserError(
            f"no path from {setting.describe(*start_ne)} to {setting.describe(*goal_ne)} at "
            f"{setting.altitude_m:g} m with a {setting.safety_m:g} m safety margin ({why})",
            EXIT_NO_PATH,
        ) from None
    except BlockedCellError as exc:  # e.g. a 3D goal whose altitude is inside a building's margin
        where = setting.describe(*(start_ne if exc.which == "start" else goal_ne))
        hint = ""
        if exc.nearest_free is not None:
            hint = "; nearest free point: " + setting.describe(*setting.grid_map.centre_of(exc.nearest_free))
        raise UserError(f"cannot plan with {planner}: the {exc.which} {where} is blocked{hint}") from None
    except (OutsideGridError, PlanningError) as exc:
        raise UserError(f"cannot plan with {planner}: {exc}") from None


def plan_summary(plan: Plan) -> str:
    s = plan.stats()
    return (
        f"{plan.planner} plan: cost {s['cost_m']:.1f} m, length {s['length_m']:.1f} m, "
        f"{s['expanded']} nodes expanded, search {s['search_ms']:.1f} ms, "
        f"waypoints {s['waypoints_before_pruning']} -> {s['waypoints_after_pruning']} after pruning"
    )


def plan_document(setting: Setting, plan: Plan, start_ne, goal_ne) -> dict:
    """The ``--json`` output: waypoints, stats, and where things are."""

    def point(north_m, east_m):
        p = setting.to_geodetic(north_m, east_m)
        return {"north_m": float(north_m), "east_m": float(east_m), "lat_deg": p.lat_deg, "lon_deg": p.lon_deg}

    return {
        "waypoints": np.round(plan.waypoints, 4).tolist(),
        "waypoint_fields": ["north_m", "east_m", "altitude_m", "heading_rad"],
        "stats": plan.stats(),
        "home": {"lat_deg": setting.home.lat_deg, "lon_deg": setting.home.lon_deg},
        "start": point(*start_ne),
        "goal": point(*goal_ne),
        "map": setting.city.path,
        "altitude_m": setting.altitude_m,
        "safety_m": setting.safety_m,
    }


def print_plan(plan: Plan, out=sys.stdout) -> None:
    print("waypoints: north_m east_m altitude_m heading_rad", file=out)
    for k, (north, east, alt, heading) in enumerate(plan.waypoints):
        print(f"{k:4d} {north:9.2f} {east:9.2f} {alt:7.2f} {heading:8.4f}", file=out)
    print(plan_summary(plan), file=out)


def save_plot(path, setting: Setting, plan: Plan, track_ne=None, *, discovered_ne=None, replans=None) -> None:
    """The plan's picture: over the configuration space at the flight altitude, or, for a route that changes
    altitude, over the height map with its altitude profile; a flight that sensed obstacles adds them and every
    replan."""
    from skyroute.view import plotting  # matplotlib only when a picture is asked for

    floor = None
    if np.ptp(plan.waypoints[:, 2]) > 0:
        floor = plan.structure.get("floor")  # grid3d hands over its height map; otherwise build it
        if floor is None:
            from skyroute.planning.grid3d import floor_map

            floor = floor_map(setting.city.obstacles, setting.safety_m)
    plotting.save_plan_figure(
        path, setting.city.obstacles, plan, altitude_m=setting.altitude_m, safety_m=setting.safety_m,
        track_ne=track_ne,
        grid=(setting.grid_map.grid, setting.grid_map.north_offset, setting.grid_map.east_offset),
        floor=floor, discovered_ne=discovered_ne, replans=replans,
    )
