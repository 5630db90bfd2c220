"""The result every planner returns: :class:`Plan`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Plan:
    """A planned route and how it was found; every planner returns one.

    ``waypoints`` is ``(K, 4)``: ``[north_m, east_m, altitude_m, heading_rad]`` in the map frame, the first at the
    start. ``raw_path_ne`` ``(R, 2)`` is the route before pruning in map metres (cell centres for grid planners),
    ``length_m`` the length of the flown (pruned) route, ``cost_m`` the optimal cost on the planner's own graph,
    ``search_ms`` the search time, ``expanded`` the number of nodes the search expanded. ``extra`` holds
    planner-specific numbers; ``structure`` what a plot may draw under the path (e.g. a graph's edges).
    """

    planner: str
    waypoints: np.ndarray
    raw_path_ne: np.ndarray
    length_m: float
    cost_m: float
    search_ms: float
    expanded: int
    extra: dict = field(default_factory=dict)
    structure: dict = field(default_factory=dict)

    def stats(self) -> dict:
        """Plain-number summary for printing or JSON."""
        return {
            "planner": self.planner,
            "cost_m": round(self.cost_m, 3),
            "length_m": round(self.length_m, 3),
            "expanded": int(self.expanded),
            "search_ms": round(self.search_ms, 3),
            "waypoints_before_pruning": int(len(self.raw_path_ne)),
            "waypoints_after_pruning": int(len(self.waypoints)),
            **self.extra,
        }
