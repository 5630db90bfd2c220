"""Flight: waypoints -> a flyable path (``path``) -> the mission that flies it (``mission``).

``states`` is the mission's state machine as data, ``errors`` its typed outcomes, ``protocol`` what it needs from
a vehicle and the callables the command line injects, ``preflight`` readiness, the altitude datum and the
autopilot's limits, ``follower`` the steering and the last-command bound. The mission talks to the vehicle only
through its ``Vehicle`` protocol; nothing here imports pymavlink or the planners.
"""
