"""Planners: obstacles -> configuration space -> search -> prune -> waypoints.

==================  =================================================================================
module              what it holds
==================  =================================================================================
``cspace``          obstacles -> occupancy grid (Euclidean margin) for one altitude; cells <-> map points
``kernels``         the compiled loops (numba): JPS and A*, bit-packed scans, search state, rasteriser, lines
``search``          :class:`GridPlanner` (optimal 8-connected search) and the classic ``a_star``
``pruning``         line of sight, pruning, cells -> waypoints
``grid``            :class:`GridMap`: the grid planner from map points to a :class:`Plan`
``plan``            :class:`Plan`, what every planner returns
``errors``          a bad start or goal, no path
``graphs``          the other planners behind one call (medial axis, Voronoi, any-angle, 3D, PRM)
``any_angle``       line of sight, the any-angle string puller, roadmap A* kernels
``grid3d``          the 2.5D height-map planner (climb over buildings, rooftop goals), 3D collision rule
``sampling``        the probabilistic roadmap (falling back to grid3d where it misses)
==================  =================================================================================
"""

#: Every planner the command line offers; ``graphs.plan`` dispatches on these names.
PLANNERS = ("grid", "medial-axis", "voronoi", "prm", "grid3d", "any-angle")
#: The planners that can end at another altitude (a rooftop goal).
PLANNERS_3D = ("prm", "grid3d")
