"""skyroute: plan a collision-free route through a city map and fly it over MAVLink.

The package follows the data path (see ARCHITECTURE.md)::

    skyroute.maps        colliders.csv -> CityMap (home + obstacle boxes)
    skyroute.planning    obstacles -> configuration-space grid or graph -> search -> prune -> waypoints
    skyroute.flight      waypoints -> flyable path -> the mission state machine
    skyroute.vehicle     the MAVLink link to the autopilot (the only owner of pymavlink)
    skyroute.view        pictures of plans and flights (the only owner of matplotlib)
    skyroute.cli         the ``motion_planning.py`` command line
    skyroute.frames      geodetic <-> local NED
    skyroute.citygen     the generator of the project's own city maps

Importing ``skyroute`` imports nothing else: each layer is imported where it is used, so a plan alone never loads
pymavlink, matplotlib or the graph libraries.
"""

__version__ = "0.1.0"
