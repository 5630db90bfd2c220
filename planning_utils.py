"""The classic exercise's planning API, as students know it: ``create_grid``, ``a_star``, ``heuristic``, pruning,
``read_home`` and map loading.

Everything here is re-exported from the ``skyroute`` package, so ``from planning_utils import create_grid, a_star``
keeps working; new code can import from the package modules directly:

* :mod:`skyroute.maps`: ``read_colliders``, ``read_home``, ``CityMap``, ``MapFormatError``
* :mod:`skyroute.planning.cspace`: ``create_grid``, cells <-> map points, nearest free cell
* :mod:`skyroute.planning.search`: ``GridPlanner``, ``a_star``, ``heuristic``
* :mod:`skyroute.planning.pruning`: ``line_of_sight``, ``prune_path`` and friends, ``waypoints_from_cells``
* :mod:`skyroute.planning.grid`: ``GridMap``, the grid planner from map points to a ``Plan``

Frames and conventions: see :mod:`skyroute.planning.grid`.
"""

from __future__ import annotations

from skyroute.maps import COLLIDERS_HEADER, CityMap, MapFormatError, read_colliders, read_home
from skyroute.planning.cspace import (
    cell_to_map,
    create_grid,
    map_to_cell,
    nearest_free_cell,
    snap_start_cell,
)
from skyroute.planning.errors import BlockedCellError, NoPathError, OutsideGridError, PlanningError
from skyroute.planning.grid import GridMap
from skyroute.planning.plan import Plan
from skyroute.planning.pruning import (
    headings_along,
    line_of_sight,
    path_length,
    prune_collinear,
    prune_line_of_sight,
    prune_path,
    supercover,
    waypoints_from_cells,
)
from skyroute.planning.search import GridPath, GridPlanner, a_star, heuristic

__all__ = [
    "COLLIDERS_HEADER", "BlockedCellError", "CityMap", "GridMap", "GridPath", "GridPlanner", "MapFormatError",
    "NoPathError", "OutsideGridError", "Plan", "PlanningError", "a_star", "cell_to_map", "create_grid",
    "headings_along", "heuristic", "line_of_sight", "map_to_cell", "nearest_free_cell", "path_length",
    "prune_collinear", "prune_line_of_sight", "prune_path", "read_colliders", "read_home", "snap_start_cell",
    "supercover", "waypoints_from_cells",
]
