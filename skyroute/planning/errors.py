"""The planners' errors: a bad start or goal, no path. Every planner raises these."""

from __future__ import annotations


class PlanningError(Exception):
    """Base class for planning failures that users can cause (bad start, bad goal, no path)."""


class OutsideGridError(PlanningError):
    """A start or goal cell outside the map's grid."""

    def __init__(self, which: str, cell: tuple[int, int], shape: tuple[int, int]):
        self.which, self.cell, self.shape = which, cell, shape
        super().__init__(
            f"{which} cell {cell} is off the map (grid is {shape[0]} x {shape[1]} cells, north x east)"
        )


class BlockedCellError(PlanningError):
    """A start or goal cell inside an obstacle or its safety margin; ``nearest_free`` is the closest free cell."""

    def __init__(self, which: str, cell: tuple[int, int], nearest_free: tuple[int, int] | None):
        self.which, self.cell, self.nearest_free = which, cell, nearest_free
        hint = f"; nearest free cell is {nearest_free}" if nearest_free is not None else "; no free cell on the map"
        super().__init__(f"{which} cell {cell} is inside an obstacle or its safety margin{hint}")


class NoPathError(PlanningError):
    """Start and goal are both free but not connected."""

    def __init__(self, start: tuple[int, int], goal: tuple[int, int], expanded: int):
        self.start, self.goal, self.expanded = start, goal, expanded
        super().__init__(f"no path from cell {start} to cell {goal} (searched {expanded} cells)")
