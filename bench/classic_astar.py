"""The classic students' grid A*, kept as a benchmark peer.

Behaviour-faithful re-implementation of ``a_star``/``valid_actions``/``heuristic`` from the starter code of
udacity/FCND-Motion-Planning (``planning_utils.py``), with the four diagonal actions (cost sqrt(2)) that the
exercise asks students to add, in the order a published student version lists them. The upstream repository
has no license file, so its text is not copied: this module is written from a reading of it, keeping the
algorithm, the data structures and every quirk, because the benchmark must measure what students actually ran:

- ``queue.PriorityQueue`` (a lock-protected heap) of ``(f, node)`` tuples, nodes being ``(row, col)`` tuples;
- a node is marked visited when it is *pushed* and never updated afterwards, so the first (not the cheapest)
  way into a cell wins: paths can be longer than optimal;
- ``visited = set(start)`` builds the set of the start's two coordinates, not a set holding the start cell;
- an ``Action`` enum whose members carry ``(d_row, d_col, cost)``; an action is dropped only if its *target*
  cell is off the grid or blocked (``grid[x, y] == 1``, fine for bool grids), so a diagonal step may squeeze
  between two blocked orthogonal neighbours, which our planner's graph does not allow;
- the heuristic is the Euclidean distance computed with ``np.linalg.norm`` on fresh arrays, once per neighbour;
- one line printed on success, a banner on failure; the cost of a failed search is 0 and the path empty.

Do not "fix" anything here: fixes belong in planning_utils.py.
"""

from enum import Enum
from queue import PriorityQueue

import numpy as np

SQRT2 = np.sqrt(2)


class Action(Enum):
    """A move on the grid: (delta row, delta column, cost). Row -1 is the starter's "NORTH"."""

    WEST = (0, -1, 1)
    EAST = (0, 1, 1)
    NORTH = (-1, 0, 1)
    SOUTH = (1, 0, 1)
    SOUTH_EAST = (1, 1, SQRT2)
    NORTH_EAST = (-1, 1, SQRT2)
    SOUTH_WEST = (1, -1, SQRT2)
    NORTH_WEST = (-1, -1, SQRT2)

    @property
    def cost(self):
        return self.value[2]

    @property
    def delta(self):
        return (self.value[0], self.value[1])


def valid_actions(grid, current_node):
    """Actions from ``current_node`` whose target cell is on the grid and not an obstacle."""
    rows, cols = grid.shape
    row, col = current_node
    allowed = list(Action)
    for action in Action:
        r, c = row + action.value[0], col + action.value[1]
        if r < 0 or c < 0 or r >= rows or c >= cols or grid[r, c] == 1:
            allowed.remove(action)
    return allowed


def a_star(grid, h, start, goal):
    """Classic A*: returns ``(path, path_cost)``, path a list of (row, col) tuples from start to goal."""
    frontier = PriorityQueue()
    frontier.put((0, start))
    visited = set(start)  # sic: the set of start's coordinates, as in the starter
    came_from = {}  # node -> (cost from start, previous node, action)
    reached = False
    while not frontier.empty():
        node = frontier.get()[1]
        g = 0.0 if node == start else came_from[node][0]
        if node == goal:
            print("Found a path.")
            reached = True
            break
        for action in valid_actions(grid, node):
            step = action.delta
            nxt = (node[0] + step[0], node[1] + step[1])
            g_next = g + action.cost
            f_next = g_next + h(nxt, goal)
            if nxt not in visited:  # first push wins, never relaxed
                visited.add(nxt)
                came_from[nxt] = (g_next, node, action)
                frontier.put((f_next, nxt))
    if not reached:
        print("Failed to find a path!")
        return [], 0
    path = [goal]
    while path[-1] != start:
        path.append(came_from[path[-1]][1])
    return path[::-1], came_from[goal][0]


def heuristic(position, goal_position):
    """Euclidean distance in cells, via numpy as in the starter."""
    return np.linalg.norm(np.array(position) - np.array(goal_position))
