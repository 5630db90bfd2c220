"""Flight: waypoints -> a flyable path (``path``) -> the mission state machine that flies it (``mission``).

The mission talks to the vehicle only through its ``Vehicle`` protocol; nothing here imports pymavlink.
"""
