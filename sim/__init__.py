"""Mock autopilot: a quadcopter in the city map that speaks MAVLink 2 over TCP like PX4 or ArduCopter, and tells
the truth.

``python -m sim --help`` lists the options. In-process::

    from sim import SimConfig, Simulator
    with Simulator(SimConfig(map_path="colliders.csv", port=0, speedup=10, strict=True)) as sim:
        fly_against(f"tcp:127.0.0.1:{sim.port}")
        report = sim.report()

The sim never imports the project's client modules: it is the oracle the client is checked against.

The spec is the real autopilot
------------------------------
Both personalities follow what ArduCopter SITL (V4.7.0-dev, ``../shared/sitl``) and PX4 SITL (v1.15.4 with its
SIH quadcopter) were measured to do with pymavlink; ``tests/test_sim_vs_sitl.py`` (marker ``sitl``) sends the
same requests to both and compares. Where each rule lives, with its measurements:

* :mod:`sim.boot` -- the boot timeline: GPS fix, EKF origin (GPS_GLOBAL_ORIGIN), home, LOCAL_POSITION_NED,
  global position, armable, in simulated seconds. ``boot="fast"`` (default) keeps the real order in 2 s;
  ``"arducopter"``, ``"px4"`` and ``"px4-fast-align"`` follow the measured timelines; ``"instant"`` is ready at 0.
* :mod:`sim.arming` -- arming refusals in the autopilots' words (ArduCopter FAILED "Arm: Need Position
  Estimate", "Arm: LAND mode not armable", and its periodic "PreArm: ..."; PX4 TEMPORARILY_REJECTED
  "Arming denied: Resolve system health failures first" in two 50-byte chunks), the land detector (ON_GROUND
  ~1.7 s / ~1 s after touchdown) and auto-disarm (DISARM_DELAY 10 s, COM_DISARM_PRFLT 10 s, COM_DISARM_LAND 2 s;
  ArduCopter's LAND disarms once landed). ArduCopter arms in GUIDED without setpoints; PX4 without RC arms in
  Hold (LOITER), TAKEOFF and, with a setpoint stream, OFFBOARD. After a disarm PX4 returns to the last mode the
  user selected that allows arming (after an OFFBOARD mission and NAV_LAND: OFFBOARD), ArduCopter stays in LAND.
* :mod:`sim.commands` -- result codes, COMMAND_ACK fields (target = the sender) and the order of acks and the
  messages they answer, per autopilot (table in its docstring). Neither real autopilot answers the commands
  modelled here with IN_PROGRESS, so the sim never does.
* :mod:`sim.params` -- parameter names, defaults, MAV_PARAM_TYPEs and PARAM_VALUE encodings (PX4 INT32
  bytewise, ArduPilot as floats with index 65535 for reads by name). PARAM_SET changes what the sim does.
* :mod:`sim.streams` -- what a fresh link gets: ArduCopter only HEARTBEAT (plus GPS_GLOBAL_ORIGIN and
  HOME_POSITION when they are set, and STATUSTEXT); anything else on request (SET_MESSAGE_INTERVAL, or
  REQUEST_DATA_STREAM groups). PX4 its onboard/API-link set at its rates. PX4 sends STATUSTEXT only to a link
  it has had a ground station's HEARTBEAT (type GCS) on.
* :mod:`sim.failsafes` -- PX4 offboard loss after COM_OF_LOSS_T (1.0 s) -> COM_OBL_RC_ACT (default Position:
  without RC the vehicle sinks to the ground; it goes back to OFFBOARD when setpoints return); data-link loss
  (COM_DL_LOSS_T, NAV_DLL_ACT, default nothing but a text); ArduCopter's GCS failsafe (FS_GCS_ENABLE, default 0:
  nothing happens, the vehicle stays GUIDED and armed).
* ArduCopter GUIDED: a setpoint's velocity moves its position target along for GUID_TIMEOUT (3 s), then the
  target stops (SITL: a target 10 m ahead with 2 m/s ended 16 m out). PX4 OFFBOARD holds the setpoint's position
  with the velocity as feed-forward.
* Home is where the vehicle boots (on the ground or roof there) and moves to wherever it arms, on both autopilots;
  the EKF origin (GPS_GLOBAL_ORIGIN, also answerable with MAV_CMD_REQUEST_MESSAGE 49) stays where it booted.
  ``origin="boot"`` gives LOCAL_POSITION_NED relative to it, as the real ones do; the default ``origin="home"``
  makes the local frame follow home (it moves at DO_SET_HOME and at every arming away from the boot point).

* :mod:`sim.sensors` -- the obstacle sensors, on by default, cast against the TRUE boxes: a 360 degree horizontal
  range sensor in the vehicle's plane (PX4: OBSTACLE_DISTANCE, 72 north-aligned 5 degree sectors on the onboard
  link; ArduPilot: DISTANCE_SENSOR per 45 degree proximity sector relative to the heading, as
  ``GCS_MAVLINK::send_proximity`` sends them, when asked) and a downward rangefinder (DISTANCE_SENSOR,
  PITCH_270). ``--sensor-range`` (30 m), ``--sensor-rate`` (10 Hz simulated), ``--sensor-noise``,
  ``--sensor-dropout``, ``--no-sensor``. A client given a stale map sees the city as it is.

Time
----
Everything the autopilot times runs in simulated time, as on SITL with a speed-up: the boot, stream rates and
the 1 Hz heartbeat, failsafe timeouts, auto-disarm, GUID_TIMEOUT, and the link faults. Physics runs on a fixed
step (``physics_dt_s``, 20 ms) and simulated time advances ``speedup`` times faster than the wall clock.

A client paces its own streams on the wall clock, so at ``--speedup N`` its 20 Hz setpoints arrive at 20/N Hz of
the vehicle's time: PX4 needs more than 2 Hz (COM_OF_LOSS_T = 1 s), so a 20 Hz client is fine up to a speed-up
of about 5 and loses OFFBOARD at 20, as it would on PX4 SITL sped up. Such a harness can pass
``scale_timeouts=True`` (``--scale-timeouts``): COM_OF_LOSS_T, COM_DL_LOSS_T and FS_GCS_TIMEOUT are multiplied by
the speedup, as PX4's own SITL startup (rcS) does with PX4_SIM_SPEED_FACTOR; parameters can also be set at boot
(``params={...}``, ``--param NAME=VALUE``). By default the timeouts keep their real values, so that a link
outage of 3 simulated seconds trips PX4's offboard failsafe at every speed-up, as it would in real flight.

To bound the wall-clock load, a stream sends at most once per physics step and at most 50 messages of a kind per
wall-clock second per link (at ``--speedup 10`` a 50 Hz stream arrives at 5 Hz of simulated time). ``time_boot_ms``,
``time_usec`` and the report use simulated time.

Link faults and signing
-----------------------
Per TCP client, in simulated time (:mod:`sim.faults`): packet loss in each direction, latency in simulated
milliseconds each way, an outage from T for D simulated seconds; so a run at ``--speedup 5`` meets the same link
as one at ``--speedup 1``. ``--deny-arm N`` and ``--deny-command NAME`` inject refusals; ``--battery-low T``
makes the battery read low from T simulated seconds on (its failsafe acts as COM_LOW_BAT_ACT / BATT_FS_LOW_ACT
say; PX4 only warns at that level; :mod:`sim.failsafes`); ``--gps-loss T[,D]`` takes the GPS's fix away from T
(for D seconds, or for good): the estimate dead-reckons, and after the estimator's timeout PX4 lands blind in
Altitude mode refusing the modes that need a position, ArduCopter takes its EKF failsafe's LAND.

``signing_key`` / ``--signing-key KEY`` (:mod:`sim.signing`): 64 hex characters are the 32-byte key, other text
a passphrase whose SHA-256 is the key (MAVProxy's rule). The sim then signs what it sends (pymavlink's signing)
and drops unsigned or wrongly signed frames, counting them (report ``signing`` and ``links``).

Dialects
--------
Default mode serves PX4-convention clients (MAVSDK, QGroundControl, pymavlink) and the classic
udacidrone API (``PX4=False``) at the same time. A TCP link is switched to the *classic dialect*
when it (a) sends SET_POSITION_TARGET_LOCAL_NED with ``type_mask & 0x3000`` set (0x1000 takeoff,
0x2000 land, 0x3000 loiter), or (b) asks for OFFBOARD before it has sent any setpoint (standard
clients must stream setpoints first). On a classic link the ``z`` of LOCAL_NED setpoints is a
positive altitude; on every other link it is NED (negative up). Outside ``--strict`` PX4's OFFBOARD may
be armed in without a setpoint stream (the vehicle holds) and has no setpoint timeout.

Bytes that are not MAVLink are skipped without losing the packets around them (``sim/framing.py``),
and reported as a ``client`` event: the course's motion_planning.py ``send_waypoints()`` writes raw
msgpack into the TCP stream for the Unity simulator to draw. The sim does not draw or use them.

``--strict`` behaves like PX4: ``z`` is always NED, the 0x1000/0x2000 bits are ignored (with a
STATUSTEXT warning), arming in OFFBOARD needs a setpoint received in the last COM_OF_LOSS_T, and armed
the offboard-loss failsafe acts. The project's own client is tested against ``--strict``.

Map and start
-------------
The map reader (:mod:`sim.mapfile`) refuses, in one line naming the file, line and why, what the client refuses:
not UTF-8, a bad home line, no header at line 2, rows that are not 6 finite numbers, negative half sizes, boxes
beyond 25 km / 10 km, no rows. ``start`` must lie on the map (its extent plus 50 m) and not inside a building;
``(lat, lon, alt)`` boots on the surface at or below ``alt`` (a roof). Every numeric option of ``python -m sim``
is range-checked with a one-line error and exit code 2.

Known differences from the real autopilots
------------------------------------------
Listed with their reasons in ``tests/test_sim_vs_sitl.py`` (``KNOWN_DIFFERENCES``), notably: the sim builds a
subset of PX4's streams and of ArduCopter's REQUEST_DATA_STREAM groups; no EVENT messages (pymavlink 2.4.50 has no
EVENT in any dialect); no TIMESYNC/PING requests from the vehicle; parameter tables hold only what the sim
models; no motor spool-up before an ArduCopter takeoff; manual modes without RC hold position on ArduCopter
(SITL sinks or falls); modes the sim cannot fly (missions, follow-me, circle) are refused; the sim is always
system 1; stream rates belong to a TCP connection (ArduPilot keeps them per serial port); every PX4 link streams
the onboard/API link's set (PX4's GCS link streams more, faster).

Truth and report
----------------
The vehicle is a sphere (``radius_m``) whose lowest point is the vehicle position. Every physics
step it is checked against the true boxes; a collision is a STATUSTEXT at CRITICAL severity, an
entry in the report, and the vehicle stops: crashed, disarmed, dropped to the surface below it, and
refusing to arm again. :meth:`Simulator.report` (and ``--report``) return a dict with keys:

``config`` (the SimConfig, with ``boot`` as its timeline), ``sim_time_s``, ``wall_time_s``, ``start`` / ``home``
(place dicts: ``lat_deg, lon_deg, alt_m, north_m, east_m, up_m``; map frame, alt = up; ``home`` is the latest
home, ``{}`` before the boot sets it), ``final`` (true state: ``position`` place, ``velocity_neu_m_s``,
``yaw_deg``, ``armed``, ``on_ground``, ``crashed``, ``mode``, ``task``, ``landed_state``, ``ready``), ``landed``
(place where the vehicle is on the ground now, else its last touchdown, else null), ``landings`` (every
touchdown), ``armed_time_s``, ``airborne_time_s``, ``distance_flown_m``, ``max_altitude_m`` (map up),
``max_height_above_home_m``, ``min_clearance_m`` (sphere surface to nearest box while airborne; capped at
``clearance_search_cap_m`` = 50), ``min_clearance_at``, ``crashed``, ``collisions`` (``sim_time_s``,
``speed_m_s``, place, ``box``), ``commands`` (every COMMAND_LONG/COMMAND_INT/SET_MODE: ``sim_time_s``,
``link``, ``source``, ``command``, ``name``, ``params``, ``frame``, ``result``, ``result_name``,
``reason``), ``setpoints_received``, ``last_setpoint_sim_time_s``, ``last_gcs_heartbeat_sim_time_s`` (the
last HEARTBEAT that counts as the ground station's), ``events`` (every status line:
``sim_time_s``, ``kind``, ``text``), ``links`` (per TCP client: ``packets_in/out``, ``dropped_in/out``,
``rejected_signature``, ``junk_bytes``), ``signing`` (``enabled``, ``rejected_frames``), ``sensor`` (its
settings, ``scans``, ``min_reading_m``; or ``{"enabled": false}``), ``targets`` (``--targets``, :mod:`sim.targets`:
per target ``index``, ``north_m``, ``east_m``, ``first_seen_s``, ``visited_s``, ``closest_low_m``; ``[]`` without).
"""

from .boot import BootTimeline
from .config import SimConfig
from .faults import FaultConfig
from .simulator import Simulator, SimulatorError
from .world import CityMap, write_colliders

__all__ = ["BootTimeline", "CityMap", "FaultConfig", "SimConfig", "Simulator", "SimulatorError", "write_colliders"]
