"""The ``motion_planning.py`` command line: ``main`` (argv -> exit code) and ``run`` (options -> exit code).

``main`` parses options and calls ``run``; ``setting`` loads the map and plans; ``flying`` connects, flies the
mission and turns its outcome into an exit code; ``bundled_sim`` runs the simulator as a child for ``--sim``;
``exits`` holds the exit codes and the one-line :class:`UserError`.
"""
