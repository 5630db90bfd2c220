"""Planners: obstacles -> configuration space -> search -> prune -> waypoints.

==================  =================================================================================
module              what it holds
==================  =================================================================================
``cspace``          obstacles -> occupancy grid for one altitude and margin; cells <-> map points
``kernels``         the compiled search loops (numba): A*, jump point search, supercover walk, heap
``search``          :class:`GridPlanner` (optimal 8-connected search) and the classic ``a_star``
``pruning``         line of sight, pruning, cells -> waypoints
``grid``            :class:`GridMap`: the grid planner from map points to a :class:`Plan`
``plan``            :class:`Plan`, what every planner returns
``errors``          a bad start or goal, no path
``graphs``          the other planners behind one call (medial axis, Voronoi, any-angle, 3D, PRM)
``any_angle``       Lazy Theta* and roadmap A* kernels
``grid3d``          the 2.5D height-map planner (climb over buildings, rooftop goals)
``sampling``        the probabilistic roadmap
==================  =================================================================================
"""

#: Every planner the command line offers; ``graphs.plan`` dispatches on these names.
PLANNERS = ("grid", "medial-axis", "voronoi", "prm", "grid3d", "any-angle")
#: The planners that can end at another altitude (a rooftop goal).
PLANNERS_3D = ("prm", "grid3d")
