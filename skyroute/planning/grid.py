"""The grid planner: read a city map, build the configuration space, search it with A*, prune, make waypoints.

The data flows one way::

    colliders.csv --read_colliders--> obstacles (N, 6) --create_grid--> grid[north_idx, east_idx]
        --GridPlanner.plan / a_star--> cells --prune_path--> cells --waypoints_from_cells--> (K, 4) waypoints

Conventions
-----------
* Map frame: local NED metres relative to the map's home ``lat0, lon0`` (see ``frames.py``). Obstacle rows are
  ``north, east, alt, half_north, half_east, half_alt``: box centre and half sizes in metres, ``alt`` upwards.
* Grid: a ``bool`` array, ``True`` = blocked, indexed ``grid[north_idx, east_idx]``. Row 0 is the *southern*
  edge; the north index increases northwards. Cell ``(i, j)`` is the 1 m square
  ``north in [north_offset + i, north_offset + i + 1)``, ``east in [east_offset + j, east_offset + j + 1)``.
  Plot it with ``origin="lower"`` to get north up.
* Moves: 8-connected, straight cost 1, diagonal cost sqrt(2). A diagonal move is only allowed when both
  orthogonal neighbours it passes are free, so a path never squeezes between two blocked cells that touch at a
  corner.
* Waypoints: ``[north_m, east_m, altitude_m, heading_rad]`` of cell centres; heading is the direction of the leg
  that arrives at the waypoint (radians from north towards east).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skyroute.planning.cspace import cell_to_map, create_grid, map_to_cell, snap_start_cell
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import headings_along, path_length, prune_path, waypoints_from_cells
from skyroute.planning.search import GridPlanner


@dataclass(frozen=True)
class GridMap:
    """A configuration-space grid for one altitude and safety margin (metres), with its planner.

    The grid spans the obstacles' footprints, so two low posts mark the corners of this 80 m map; the wall is
    2 m thick, 60 m long and 20 m tall, and with a 2 m margin the route passes its end 32.5 m east:

    >>> boxes = np.array([[0, 0, 10, 1, 30, 10], [-40, -40, 1, 1, 1, 1], [40, 40, 1, 1, 1, 1]])
    >>> plan = GridMap.build(boxes, altitude_m=5, safety_m=2).plan((-20.0, 0.0), (20.0, 0.0))
    >>> plan.waypoints[:, :3].tolist()
    [[-19.5, 0.5, 5.0], [-3.5, 32.5, 5.0], [3.5, 32.5, 5.0], [20.5, 0.5, 5.0]]
    """

    obstacles: np.ndarray
    grid: np.ndarray
    north_offset: int
    east_offset: int
    altitude_m: float
    safety_m: float
    planner: GridPlanner

    @classmethod
    def build(cls, obstacles: np.ndarray, altitude_m: float, safety_m: float) -> GridMap:
        grid, north_offset, east_offset = create_grid(obstacles, altitude_m, safety_m)
        return cls(obstacles, grid, north_offset, east_offset, altitude_m, safety_m, GridPlanner(grid))

    def cell_of(self, north_m: float, east_m: float) -> tuple[int, int]:
        """Grid cell containing the map point ``(north_m, east_m)``."""
        return map_to_cell(north_m, east_m, self.north_offset, self.east_offset)

    def centre_of(self, cell: Sequence[int]) -> tuple[float, float]:
        """Map point ``(north_m, east_m)`` at the centre of ``cell``."""
        return cell_to_map(cell, self.north_offset, self.east_offset)

    def inside_obstacle(self, north_m: float, east_m: float) -> bool:
        """True if the point is inside an obstacle's footprint taller than the altitude (ignoring the margin)."""
        n, e, alt, dn, de, da = self.obstacles.T
        return bool(
            ((np.abs(n - north_m) < dn) & (np.abs(e - east_m) < de) & (alt + da > self.altitude_m)).any()
        )

    def snap_start(self, start_ne: Sequence[float]) -> tuple[tuple[int, int], np.ndarray | None]:
        """The start cell to search from, and the lead-in point when the start lies inside the safety margin.

        A start whose cell is blocked (but that touches no building) moves to the nearest free cell reachable by
        a straight leg that passes no building (:func:`snap_start_cell`); the route then begins at the centre of
        the start cell (the vehicle takes off inside that obstacle-free cell) and leads out to the snapped cell.
        Otherwise the start cell is returned unchanged with no lead-in, and the search reports the problem.
        """
        start_cell = self.cell_of(*start_ne)
        if not self.planner.is_blocked_inside(start_cell):
            return start_cell, None
        footprint = create_grid(self.obstacles, self.altitude_m, 0.0)[0]
        snapped = snap_start_cell(self.grid, footprint, start_cell)
        if snapped is None:
            return start_cell, None
        return snapped, np.array(self.centre_of(start_cell))

    def plan(self, start_ne: Sequence[float], goal_ne: Sequence[float], *, snap_start: bool = False) -> Plan:
        """Plan from map point ``start_ne`` to ``goal_ne`` (``(north_m, east_m)``), prune, make waypoints.

        The route runs between cell centres (within 0.71 m of the points). With ``snap_start``, a start inside
        the safety margin (but not touching a building) leads out to the nearest free cell (:meth:`snap_start`).

        Raises
        ------
        OutsideGridError, BlockedCellError, NoPathError
            As :meth:`GridPlanner.plan`.
        """
        start_cell, lead_in = self.snap_start(start_ne) if snap_start else (self.cell_of(*start_ne), None)
        goal_cell = self.cell_of(*goal_ne)
        t0 = time.perf_counter()
        path = self.planner.plan(start_cell, goal_cell)
        search_ms = (time.perf_counter() - t0) * 1e3
        pruned = prune_path(self.grid, path.cells)
        waypoints = waypoints_from_cells(pruned, self.north_offset, self.east_offset, self.altitude_m)
        raw = path.cells + (self.north_offset + 0.5, self.east_offset + 0.5)
        if lead_in is not None:
            points = np.vstack([lead_in, waypoints[:, :2]])
            waypoints = np.column_stack([points, np.full(len(points), self.altitude_m), headings_along(points)])
            raw = np.vstack([lead_in, raw])
        return Plan(
            planner="grid",
            waypoints=waypoints,
            raw_path_ne=raw,
            length_m=path_length(waypoints[:, :2]),
            cost_m=path.cost,
            search_ms=search_ms,
            expanded=path.expanded,
            extra={"start_cell": list(start_cell), "goal_cell": list(goal_cell)},
        )
