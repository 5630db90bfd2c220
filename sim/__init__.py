"""Mock autopilot: a quadcopter in the city map that speaks MAVLink 2 over TCP, and tells the truth.

``python -m sim --help`` lists the options. In-process::

    from sim import SimConfig, Simulator
    with Simulator(SimConfig(map_path="colliders.csv", port=0, speedup=10, strict=True)) as sim:
        fly_against(f"tcp:127.0.0.1:{sim.port}")
        report = sim.report()

The sim never imports the project's client modules: it is the oracle the client is checked against.

Time
----
Physics runs on a fixed step (``physics_dt_s``, simulated seconds) and simulated time advances
``speedup`` times faster than the wall clock. Everything a client times with its own clock is
wall-clock: heartbeats (1 Hz), stream intervals (SET_MESSAGE_INTERVAL), the ``--strict`` offboard
setpoint timeout (COM_OF_LOSS_T, 0.5 s), link faults. Position/attitude streams default to 10 Hz
times the speedup, capped at 50 Hz. ``time_boot_ms`` and the report use simulated time.

Dialects
--------
Default mode serves PX4-convention clients (MAVSDK, QGroundControl, pymavlink) and the classic
udacidrone API (``PX4=False``) at the same time. A TCP link is switched to the *classic dialect*
when it (a) sends SET_POSITION_TARGET_LOCAL_NED with ``type_mask & 0x3000`` set (0x1000 takeoff,
0x2000 land, 0x3000 loiter), or (b) asks for OFFBOARD before it has sent any setpoint (standard
clients must stream setpoints first). On a classic link the ``z`` of LOCAL_NED setpoints is a
positive altitude; on every other link it is NED (negative up). Outside ``--strict`` OFFBOARD may
be entered without a setpoint stream (the vehicle holds) and has no setpoint timeout.

Bytes that are not MAVLink are skipped without losing the packets around them (``sim/framing.py``),
and reported as a ``client`` event: the course's motion_planning.py ``send_waypoints()`` writes raw
msgpack into the TCP stream for the Unity simulator to draw. The sim does not draw or use them.

``--strict`` behaves like PX4: ``z`` is always NED, the 0x1000/0x2000 bits are ignored (with a
STATUSTEXT warning), OFFBOARD (and arming in it) is refused without a setpoint received in the last
COM_OF_LOSS_T seconds, and when setpoints stop for that long the vehicle switches to hold
(AUTO.LOITER). The project's own client is tested against ``--strict``.

Truth and report
----------------
The vehicle is a sphere (``radius_m``) whose lowest point is the vehicle position. Every physics
step it is checked against the true boxes; a collision is a STATUSTEXT at CRITICAL severity, an
entry in the report, and the vehicle stops: crashed, disarmed, dropped to the surface below it, and
refusing to arm again. :meth:`Simulator.report` (and ``--report``) return a dict with keys:

``config`` (the SimConfig), ``sim_time_s``, ``wall_time_s``, ``start`` / ``home`` (place dicts:
``lat_deg, lon_deg, alt_m, north_m, east_m, up_m``; map frame, alt = up), ``final`` (true state:
``position`` place, ``velocity_neu_m_s``, ``yaw_deg``, ``armed``, ``on_ground``, ``crashed``,
``mode``, ``task``, ``landed_state``), ``landed`` (place where the vehicle is on the ground now,
else its last touchdown, else null), ``landings`` (every touchdown), ``armed_time_s``,
``airborne_time_s``, ``distance_flown_m``, ``max_altitude_m`` (map up), ``max_height_above_home_m``,
``min_clearance_m`` (sphere surface to nearest box while airborne; capped at
``clearance_search_cap_m`` = 50), ``min_clearance_at``, ``crashed``, ``collisions`` (``sim_time_s``,
``speed_m_s``, place, ``box``), ``commands`` (every COMMAND_LONG/COMMAND_INT/SET_MODE: ``sim_time_s``,
``link``, ``source``, ``command``, ``name``, ``params``, ``frame``, ``result``, ``result_name``,
``reason``), ``setpoints_received``, ``events`` (every status line: ``sim_time_s``, ``kind``, ``text``).
"""

from .config import SimConfig
from .faults import FaultConfig
from .simulator import Simulator, SimulatorError
from .world import CityMap, write_colliders

__all__ = ["CityMap", "FaultConfig", "SimConfig", "Simulator", "SimulatorError", "write_colliders"]
