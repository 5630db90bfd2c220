"""The autopilot: boot, modes, setpoints, flight tasks and the physics step.

Owned by the simulation thread; nothing here is thread-safe on its own (the :class:`Simulator`
holds a lock around every call). Commands are :mod:`sim.commands`, arming and the land detector
:mod:`sim.arming`, link-loss failsafes :mod:`sim.failsafes`.

Dialects (see ``sim/__init__.py`` for the full story): a link is marked *classic* (the udacidrone
``PX4=False`` API) when, outside ``--strict``, it sends a SET_POSITION_TARGET_LOCAL_NED whose
type_mask has bit 0x1000 (takeoff) or 0x2000 (land), or requests OFFBOARD before it has sent any
setpoint. On a classic link the ``z`` of SET_POSITION_TARGET_LOCAL_NED is a positive altitude;
everywhere else it is NED down.
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from . import streams
from . import telemetry as tm
from .arming import GroundLogic, arm_refusal, readiness_reason
from .boot import resolve_boot
from .commands import CommandHandlers, LinkState
from .config import START_MARGIN_M, SimConfig
from .dynamics import GRAVITY_M_S2, ControlTarget, Limits, PointMassQuad
from .failsafes import Failsafes
from .faults import CommandFaults
from .modes import ArduCopter, Behaviour, Mode, Task, make_personality
from .params import ParamTable
from .report import Collision, FlightRecorder
from .sensors import SENSOR_MESSAGE_IDS, ObstacleSensor
from .setpoints import global_int_target, local_ned_target
from .streams import StreamScheduler
from .targets import GroundTargets
from .tasks import TaskControl
from .world import CityMap

log = logging.getLogger(__name__)
M = mavlink
NAN = math.nan
#: ``--gps-noise``: the estimator smooths the drift (``--gps-correlation``) over this long (s): a real EKF's
#: position does not jump between its updates.
GPS_SMOOTHING_S = 2.0
#: ``--gps-loss``: without GPS the estimate dead-reckons on the IMU and its horizontal error grows, here at this
#: rate (m/s) in one direction drawn when the GPS goes (a model, not a measurement: an error growing with time).
DEAD_RECKONING_DRIFT_M_S = 0.3
#: ... until the estimator gives its horizontal position up and the position-loss failsafe acts: this long after
#: the GPS went (simulated s), measured: PX4 1.15 SIH with GPS fusion switched off in OFFBOARD flight, "Failsafe
#: activated" 6.5 s after (EKF2_NOAID_TOUT 5 s, then the failsafe's own hold-off); ArduCopter 4.7 SITL with
#: SIM_GPS1_ENABLE 0, "EKF variance" and "EKF Failsafe" 7.3 s after (while landing; "EKF Failsafe: changed to LAND
#: Mode" when it changed the mode, measured mid-route).
POSITION_LOSS_AFTER_S = {"px4": 6.5, "ardupilot": 7.3}
#: PX4 modes that prevent arming: the mode PX4 returns to after a disarm is never one of them.
_PX4_PREVENTS_ARMING = {"LAND", "RTL"}


class Autopilot(CommandHandlers, TaskControl):
    """Mock PX4/ArduCopter flight stack around a :class:`PointMassQuad`.

    Parameters
    ----------
    config : SimConfig
    city : CityMap
    recorder : FlightRecorder
    send : callable
        ``send(link, msg)`` queues a message on one link; ``send(None, msg)`` broadcasts.
    emit : callable
        ``emit(kind, text)`` reports a status event.

    Raises
    ------
    ValueError
        If ``config.start`` is off the map or inside a building.
    """

    def __init__(self, config: SimConfig, city: CityMap, recorder: FlightRecorder,
                 send: Callable, emit: Callable[[str, str], None]) -> None:
        self.cfg = config
        self.city = city
        self.recorder = recorder
        self.send = send
        self.emit = emit
        self.personality = make_personality(config.autopilot)
        self.is_px4 = not isinstance(self.personality, ArduCopter)
        self.params = ParamTable(config.autopilot, config.params, config.speedup, config.scale_timeouts)
        self.boot = resolve_boot(config.boot)
        self.command_faults = CommandFaults(config.faults)
        sensing = config.sensor.enabled
        self.sensor = ObstacleSensor(config.sensor, city, config.autopilot, config.seed) if sensing else None
        self.targets = GroundTargets(config.targets) if config.targets else None
        self.scheduler = StreamScheduler(config.autopilot, config.speedup, config.physics_dt_s,
                                         config.sensor.rate_hz if sensing else None)
        self.rng = random.Random(config.seed)
        self.sim_time_s = 0.0
        self.boot_neu = city.boot_point(config.start, config.radius_m, START_MARGIN_M)
        #: local metres per map metre, north and east: the personality's local frame (CityMap.local_scale)
        self.local_scale = np.array([*city.local_scale(config.autopilot), 1.0])
        self.origin_set = False
        self.home_neu: np.ndarray | None = None
        self.quad = PointMassQuad(Limits(), self.boot_neu)
        self.armed = False
        self.crashed = False
        self.mode: Mode = self.personality.boot_mode
        self._apply_params()
        self.mode_after_disarm: Mode = self.mode  # PX4: the last user mode that does not prevent arming
        self.task = Task(Behaviour.HOLD, self.boot_neu.copy())
        self.setpoint: ControlTarget | None = None
        self.setpoint_s = -math.inf  # simulated time the last setpoint arrived
        self.following = False
        self.speed_limit_m_s = NAN
        self.gps_noise = np.zeros(3)  # the estimate's error (m, map frame; height stays 0)
        self.gps_drift = np.zeros(2)  # the drift behind it, before the estimator's smoothing
        self.dead_reckoning = np.zeros(3)  # the estimate's error grown since the GPS went (--gps-loss; m, map frame)
        self._dead_reckoning_rate = np.zeros(3)
        self.gps_lost_since: float | None = None  # simulated s the GPS went (None: it has a fix)
        self.gust = np.zeros(3)
        self.ground = GroundLogic(self)
        self.failsafes = Failsafes(self)
        self._commands = self.command_table()
        self._after_ack: list[tuple[object, object]] = []

    # ------------------------------------------------------------------ frames and state
    @property
    def origin_neu(self) -> np.ndarray:
        """Local NED origin in the map frame (see ``SimConfig.origin``)."""
        if self.cfg.origin == "home" and self.home_neu is not None:
            return self.home_neu
        return self.boot_neu

    @property
    def position_neu(self) -> np.ndarray:
        """Where the autopilot believes it is (map frame, m): the truth plus :meth:`estimate_error_neu`. What its
        controller, its modes and its commands act on; the truth is ``quad.state.position_neu``."""
        return self.quad.state.position_neu + self.estimate_error_neu()

    def estimate_error_neu(self) -> np.ndarray:
        """The position estimate's error (m, map frame): the horizontal ``--gps-noise``. Height comes from the
        barometer, as PX4's (EKF2_HGT_REF) and ArduPilot's (EK3_SRC1_POSZ) estimators take it by default, so the
        GPS's vertical error shows in neither the altitude held nor the altitude reported (GPS_RAW_INT states it
        as ``v_acc``)."""
        error = self.dead_reckoning.copy()
        if self.cfg.gps_noise_m > 0:
            error[:2] += self.gps_noise[:2]
        return error

    @property
    def position_valid(self) -> bool:
        """Whether the estimator still has a horizontal position: the GPS has a fix, or went less than
        ``POSITION_LOSS_AFTER_S`` ago (dead reckoning)."""
        return (self.gps_lost_since is None
                or self.sim_time_s - self.gps_lost_since < POSITION_LOSS_AFTER_S[self.cfg.autopilot])

    def _track_gps(self, dt_s: float) -> None:
        """``--gps-loss``: start or stop the dead reckoning; grow its error while the GPS is gone. The fix back, the
        estimator resets onto it (the error drops to zero)."""
        if self.cfg.faults.gps_lost(self.sim_time_s):
            if self.gps_lost_since is None:
                self.gps_lost_since = self.sim_time_s
                bearing = self.rng.uniform(0.0, 2.0 * math.pi)
                self._dead_reckoning_rate = DEAD_RECKONING_DRIFT_M_S * np.array([math.cos(bearing),
                                                                                 math.sin(bearing), 0.0])
                self.emit("gps", "GPS fix lost: the estimate dead-reckons")
            self.dead_reckoning += self._dead_reckoning_rate * dt_s
        elif self.gps_lost_since is not None:
            self.gps_lost_since = None
            self.dead_reckoning[:] = 0.0
            self.emit("gps", "GPS fix back: the estimate resets onto it")

    @property
    def airborne(self) -> bool:
        return not self.quad.state.on_ground

    def setpoint_fresh(self) -> bool:
        """A setpoint arrived within COM_OF_LOSS_T (PX4's offboard signal, simulated time; 1 s for ArduPilot)."""
        timeout = self.params["COM_OF_LOSS_T"] if "COM_OF_LOSS_T" in self.params else 1.0
        return self.sim_time_s - self.setpoint_s <= timeout + 1e-9

    def _apply_params(self) -> None:
        lim, p = self.quad.limits, self.params
        if self.is_px4:
            lim.max_horizontal_speed_m_s = p["MPC_XY_VEL_MAX"]
            lim.max_horizontal_accel_m_s2 = p["MPC_ACC_HOR_MAX" if self.mode.behaviour == Behaviour.OFFBOARD
                                              else "MPC_ACC_HOR"]
            lim.max_climb_m_s = p["MPC_Z_VEL_MAX_UP"]
            lim.max_descent_m_s = p["MPC_Z_VEL_MAX_DN"]
            tilt_deg = p["MPC_TILTMAX_AIR"]
        else:
            lim.max_horizontal_speed_m_s = p["WPNAV_SPEED"] / 100.0
            lim.max_horizontal_accel_m_s2 = p["WPNAV_ACCEL"] / 100.0
            lim.max_climb_m_s = p["WPNAV_SPEED_UP"] / 100.0
            lim.max_descent_m_s = p["WPNAV_SPEED_DN"] / 100.0
            tilt_deg = p["ANGLE_MAX"] / 100.0
        # How fast the velocity loop learns the drag: what a position step overshoots by, as the learnt lean lags
        # the braking. Measured, a 60 m step at 5 m: PX4 1.15 SIH 2.4 m past it (the sim at 1 s: 2.1 m),
        # ArduCopter 4.7 SITL 0.8 m, its stops shaped sooner (the sim at 0.5 s: 0.9 m; at 1 s it was 2.1 m).
        lim.wind_integrator_s = 1.0 if self.is_px4 else 0.5
        lim.max_tilt_accel_m_s2 = GRAVITY_M_S2 * math.tan(math.radians(min(max(tilt_deg, 10.0), 80.0)))
        for attr in ("max_horizontal_speed_m_s", "max_horizontal_accel_m_s2", "max_climb_m_s", "max_descent_m_s"):
            setattr(lim, attr, max(0.05, getattr(lim, attr)))

    def _land_speed(self) -> float:
        return max(0.05, self.params["MPC_LAND_SPEED"] if self.is_px4 else self.params["LAND_SPEED"] / 100.0)

    def _ground_fn(self, north_m: float, east_m: float, below_up_m: float) -> float:
        return self.city.ground_up_m(north_m, east_m, below_up_m, self.cfg.radius_m)

    def landed_state(self) -> int:
        """EXTENDED_SYS_STATE landed state, as the land detector sees it."""
        kind = self.task.kind
        landing = kind == Behaviour.LAND or (kind == Behaviour.RTL and self.task.phase == 2)
        if self.ground.landed:
            return M.MAV_LANDED_STATE_ON_GROUND
        if landing:
            return M.MAV_LANDED_STATE_LANDING
        if kind == Behaviour.TAKEOFF and self.airborne:
            return M.MAV_LANDED_STATE_TAKEOFF
        return M.MAV_LANDED_STATE_IN_AIR

    def statustext(self, severity: int, text: str, link=None) -> None:
        for msg in tm.statustext(severity, text):
            self.send(link, msg)

    def streamable(self, msg_id: int) -> bool:
        """Whether the sim can send ``msg_id`` (a telemetry builder, or a sensor message with the sensors on)."""
        return msg_id in tm.BUILDERS or (self.sensor is not None and msg_id in SENSOR_MESSAGE_IDS)

    def build_messages(self, msg_id: int, link, snapshot_fn) -> list:
        """The message(s) ``msg_id`` stands for now on ``link`` (ArduPilot's DISTANCE_SENSOR is one per sector)."""
        if msg_id in SENSOR_MESSAGE_IDS:
            return [] if self.sensor is None else self.sensor.messages(msg_id, link)
        msg = streams.build(self, msg_id, snapshot_fn()) if msg_id in tm.BUILDERS else None
        return [] if msg is None else [msg]

    def delivers(self, link, msg) -> bool:
        """Whether ``msg`` goes out on ``link``: PX4 sends STATUSTEXT only to a link it has had a ground station's
        HEARTBEAT on (measured: no text at all for a client without one, or with an onboard-controller one)."""
        return not (self.is_px4 and msg.get_type() == "STATUSTEXT" and not getattr(link, "gcs_seen", True))

    # ------------------------------------------------------------------ modes and tasks
    def enter_mode(self, mode: Mode, task: Task | None = None, user: bool = True) -> None:
        """Switch to ``mode`` (with ``task``, else the mode's default task); ``user``: the user's own choice."""
        pos = self.position_neu.copy()
        if task is None:
            b = mode.behaviour
            if b == Behaviour.TAKEOFF:
                target = pos.copy()
                target[2] = self._ground_fn(pos[0], pos[1], pos[2] + 0.05) + self._default_takeoff_height()
                task = Task(b, target)
            else:
                task = Task(b, pos)
        if mode.behaviour == Behaviour.OFFBOARD:
            self.following = self.setpoint_fresh() if self.is_px4 else False
        changed = mode != self.mode
        self.mode, self.task = mode, task
        self._apply_params()  # PX4's acceleration limit depends on the mode
        if user and mode.name not in _PX4_PREVENTS_ARMING:
            self.mode_after_disarm = mode
        if changed:
            self.emit("mode", f"mode {mode.name}")

    def _default_takeoff_height(self) -> float:
        if self.is_px4:
            return self.params["MIS_TAKEOFF_ALT"]
        return max(1.0, self.params["PILOT_TKOFF_ALT"] / 100.0)

    def set_armed(self, armed: bool, why: str = "") -> None:
        self.armed = armed
        if armed:
            self.ground.on_arm()
            if self.task.kind in (Behaviour.HOLD, Behaviour.OFFBOARD):
                self.task.position_neu = self.position_neu.copy()
            self._reset_home_at_arming()
        text = ("ARMED" if armed else "DISARMED") + (f" ({why})" if why else "")
        self.emit("armed" if armed else "disarmed", text)
        if not armed and self.is_px4 and self.mode != self.mode_after_disarm:
            self.enter_mode(self.mode_after_disarm)

    def disarm(self, why: str, text: str) -> None:
        """Disarm on the vehicle's own decision (auto-disarm), announcing ``text``."""
        self.statustext(M.MAV_SEVERITY_INFO, text)
        self.set_armed(False, why)

    def cut_motors(self, why: str) -> None:
        """Terminate / disarm: on the ground a disarm, in the air a fall."""
        if self.airborne:
            self._crash(None, why)
        elif self.armed:
            self.set_armed(False, why)

    def _reset_home_at_arming(self) -> None:
        """Both autopilots move home to where they arm (the EKF origin stays)."""
        self.set_home(self.position_neu.copy(), "arming")

    def set_home(self, home_neu: np.ndarray, why: str) -> None:
        self.home_neu = np.array(home_neu, dtype=float)
        self.recorder.home = self.recorder.place(*self.home_neu)
        lat, lon, alt = self.city.map_to_geodetic(*self.home_neu)
        self.emit("home", f"home set to {lat:.7f},{lon:.7f},{alt:.2f} ({why})")
        snap = self.snapshot()
        self._broadcast_later(tm.home_position(snap))
        if not self.is_px4 and self.origin_set:
            self._broadcast_later(tm.gps_global_origin(snap))

    def _broadcast_later(self, msg) -> None:
        """Send after the current command's ack (or now, outside a command)."""
        if self._in_command:
            self._after_ack.append((None, msg))
        else:
            self.send(None, msg)

    _in_command = False

    # ------------------------------------------------------------------ boot
    def _boot_events(self) -> None:
        t, b = self.sim_time_s, self.boot
        if not self.origin_set and t >= b.origin_s:
            self.origin_set = True
            lat, lon, alt = self.city.map_to_geodetic(*self.boot_neu)
            self.emit("boot", f"EKF origin set at {lat:.7f},{lon:.7f},{alt:.2f}")
            if not self.is_px4:
                self.statustext(M.MAV_SEVERITY_INFO, "EKF3 IMU0 origin set")
            self.send(None, tm.gps_global_origin(self.snapshot()))
        if self.home_neu is None and t >= b.home_s:
            self.set_home(self.boot_neu.copy(), "boot")
        if not self._estimate_announced and t >= b.local_position_s:
            self._estimate_announced = True
            self.emit("boot", "position estimate ready")
            if not self.is_px4:
                self.statustext(M.MAV_SEVERITY_INFO, "EKF3 IMU0 is using GPS")

    _estimate_announced = False

    # ------------------------------------------------------------------ message dispatch
    def handle(self, link: LinkState, msg) -> None:
        """Act on one received MAVLink message."""
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._on_command(link, msg)
        elif kind == "SET_MODE":
            self._on_set_mode_msg(link, msg)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_setpoint(link, msg, local_ned_target)
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
            self._on_setpoint(link, msg, global_int_target)
        elif kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            self._on_param(link, msg)
        elif kind == "REQUEST_DATA_STREAM":
            self._on_request_data_stream(link, msg)
        elif kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:
                link.gcs_seen = True
            self.failsafes.on_heartbeat(msg)
        elif kind == "PING" and msg.target_system == 0 and self.is_px4:  # ArduPilot does not answer
            self.send(link, M.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                  msg.get_srcComponent()))
        elif kind == "TIMESYNC" and msg.tc1 == 0:
            self.send(link, M.MAVLink_timesync_message(int(self.sim_time_s * 1e9), msg.ts1))

    # ------------------------------------------------------------------ setpoints and params
    def _on_setpoint(self, link: LinkState, msg, convert) -> None:
        if msg.target_system not in (0, tm.SYSTEM_ID):
            return
        target = convert(self, link, msg)
        self.recorder.setpoints_received += 1
        if target is None:
            return
        self.setpoint = target
        self.setpoint_s = self.sim_time_s
        self.recorder.last_setpoint_sim_time_s = round(self.sim_time_s, 3)
        link.sent_setpoint = True
        if self.mode.behaviour == Behaviour.OFFBOARD:
            if self.task.kind != Behaviour.OFFBOARD:
                self.task = Task(Behaviour.OFFBOARD, self.position_neu.copy())
            self.following = True

    def _on_param(self, link: LinkState, msg) -> None:
        if msg.target_system not in (0, tm.SYSTEM_ID):
            return
        p = self.params
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for name in p.names:
                self.send(link, p.value_message(name, named=False))
        elif kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:
                if msg.param_index < len(p.names):
                    self.send(link, p.value_message(p.names[msg.param_index], named=False))
            elif msg.param_id in p:
                self.send(link, p.value_message(msg.param_id, named=True))
        else:
            value = p.decode_set(msg.param_id, msg.param_value)
            if value is None:
                return  # neither autopilot answers a set of an unknown name
            p.set(msg.param_id, value)
            self._apply_params()
            self.emit("param", f"{msg.param_id} = {p[msg.param_id]:g}")
            self.send(None, p.value_message(msg.param_id, named=True))

    # ------------------------------------------------------------------ physics step
    def step(self, dt_s: float) -> None:
        """Advance the vehicle by one physics step of ``dt_s`` simulated seconds."""
        self._boot_events()
        s = self.quad.state
        # the air, still or moving: the airframe's drag is relative to it (real airframes drag in still air too:
        # PX4 SIH ~1.1/s and ArduCopter SITL ~0.5/s as the client measures them)
        if self.cfg.gust_m_s > 0:
            k = dt_s / 3.0
            for i in (0, 1):
                kick = self.cfg.gust_m_s * math.sqrt(2 * k) * self.rng.gauss(0, 1)
                self.gust[i] += -k * self.gust[i] + kick
        wind = np.array([self.cfg.wind_m_s[0], self.cfg.wind_m_s[1], 0.0]) + self.gust
        motors = self.armed and not self.crashed
        touched = self.quad.step(dt_s, self.control_target(), motors, self._ground_fn, wind,
                                 self.estimate_error_neu())
        self.sim_time_s += dt_s
        if self.cfg.gps_noise_m > 0:
            self._drift_gps(dt_s)
        if self.cfg.faults.gps_loss_start_s is not None:
            self._track_gps(dt_s)
        speed = float(np.linalg.norm(s.velocity_neu))
        hit = self.recorder.truth.check(s.position_neu, self.airborne, self.sim_time_s, speed)
        if hit is not None:
            self._crash(hit, "collision")
        if touched and not self.crashed:
            entry = self.recorder.add_landing(self.sim_time_s, s.position_neu)
            self.ground.on_touchdown()
            self.emit("landed", f"touchdown at N {entry['north_m']:.2f} E {entry['east_m']:.2f} "
                                f"alt {entry['up_m']:.2f} ({entry['lat_deg']:.7f},{entry['lon_deg']:.7f})")
        self._advance_task()
        self.ground.step()
        self.failsafes.step()
        if self.sensor is not None:
            centre = s.position_neu + np.array([0.0, 0.0, self.cfg.radius_m])
            self.sensor.sample(self.sim_time_s, centre, s.yaw_rad, s.position_neu)
        if self.targets is not None:
            self.targets.step(self.sim_time_s, s.position_neu)
            for msg in self.targets.messages(self.sim_time_s, s.position_neu, self.origin_neu, self.local_scale):
                self.send(None, msg)
        home_up = self.home_neu[2] if self.home_neu is not None else self.boot_neu[2]
        self.recorder.update(dt_s, s.position_neu, self.armed, self.airborne, home_up)

    def _crash(self, hit: Collision | None, why: str) -> None:
        s = self.quad.state
        if hit is not None:
            entry = self.recorder.add_collision(hit)
            text = (f"COLLISION with box {hit.box_index} at N {hit.north_m:.1f} E {hit.east_m:.1f} "
                    f"alt {hit.up_m:.1f} ({entry['lat_deg']:.7f},{entry['lon_deg']:.7f})")
        else:
            text = f"CRASH: {why}"
        self.crashed = True
        self.statustext(M.MAV_SEVERITY_CRITICAL, text)
        self.emit("collision" if hit is not None else "crash", text)
        s.position_neu[2] = self._ground_fn(s.position_neu[0], s.position_neu[1], s.position_neu[2])
        s.on_ground = True
        s.velocity_neu[:] = 0.0
        s.accel_neu[:] = 0.0
        self.set_armed(False, why)

    # ------------------------------------------------------------------ telemetry
    def system_status(self) -> int:
        """HEARTBEAT system_status. PX4 reports UNINIT while disarmed and not armable (measured: during boot, and
        in a mode it cannot arm in), STANDBY once it could arm; ArduCopter STANDBY on the ground, ACTIVE in flight."""
        if self.crashed:
            return M.MAV_STATE_EMERGENCY
        if not self.armed:
            if self.is_px4 and arm_refusal(self, force=False) is not None:
                return M.MAV_STATE_UNINIT
            return M.MAV_STATE_STANDBY
        if self.is_px4:
            return M.MAV_STATE_ACTIVE
        return M.MAV_STATE_STANDBY if self.ground.landed else M.MAV_STATE_ACTIVE  # ArduCopter: ACTIVE in flight

    def snapshot(self) -> tm.TelemetrySnapshot:
        s = self.quad.state
        pos = self.position_neu  # the estimate (a new array)
        home = self.home_neu if self.home_neu is not None else self.boot_neu
        lat, lon, alt = self.city.map_to_geodetic(*pos)
        hlat, hlon, halt = self.city.map_to_geodetic(*home)
        olat, olon, oalt = self.city.map_to_geodetic(*self.boot_neu)
        local = (pos - self.origin_neu) * self.local_scale
        home_local = (home - self.origin_neu) * self.local_scale
        roll, pitch, yaw = self.quad.attitude()
        base = self.personality.base_mode(self.mode, self.armed, self.airborne)
        v = s.velocity_neu
        has_fix = self.sim_time_s >= self.boot.gps_fix_s
        if self.is_px4:
            fix_type = M.GPS_FIX_TYPE_3D_FIX if has_fix else M.GPS_FIX_TYPE_NO_FIX
        else:  # ArduPilot SITL's simulated u-blox reports RTK fixed
            fix_type = M.GPS_FIX_TYPE_RTK_FIXED if has_fix else M.GPS_FIX_TYPE_NO_GPS
        if self.gps_lost_since is not None:  # a receiver that lost its fix (both SITLs: NO_FIX)
            fix_type = M.GPS_FIX_TYPE_NO_FIX
        armable = not self.crashed and self.sim_time_s >= self.boot.armable_s and self.home_neu is not None
        return tm.TelemetrySnapshot(
            int(self.sim_time_s * 1000), lat, lon, alt, alt - home[2],
            float(local[0]), float(local[1]), float(-local[2]) + 0.0, float(v[0]), float(v[1]), float(-v[2]),
            roll, pitch, yaw, s.yaw_rate_rad_s, hlat, hlon, halt,
            float(home_local[0]), float(home_local[1]), float(-home_local[2]) + 0.0,
            self.personality.autopilot, base, self.mode.custom_mode, self.system_status(), self.landed_state(),
            armable, 50 if self.armed and self.airborne else 0,
            fix_type, has_fix, olat, olon, oalt, not self.is_px4, self.sensor is not None,
            *self.gps_accuracy(),
        )

    def _drift_gps(self, dt_s: float) -> None:
        """Move the estimate's error on by ``dt_s``: a first-order Gauss-Markov drift (``gps_correlation_s``), seen
        through the estimator's smoothing (a first-order lag of ``GPS_SMOOTHING_S``, the drift's spread scaled so
        the error's own is ``--gps-noise``). Unsmoothed, the error jumped ~0.13 m per 20 ms step at 2 m: a hovering
        vehicle's reported position shook by 0.6 m, which no EKF fusing an IMU reports."""
        tau = self.cfg.gps_correlation_s
        k = dt_s / tau
        spread = self.cfg.gps_noise_m * math.sqrt((tau + GPS_SMOOTHING_S) / tau)
        for i in (0, 1):
            self.gps_drift[i] += -k * self.gps_drift[i] + spread * math.sqrt(2 * k) * self.rng.gauss(0, 1)
        self.gps_noise[:2] += (dt_s / GPS_SMOOTHING_S) * (self.gps_drift - self.gps_noise[:2])

    def gps_accuracy(self) -> tuple[int, int, int, int]:
        """GPS_RAW_INT's HDOP, VDOP (x 100) and horizontal and vertical accuracy (mm): what the real SITLs report
        (PX4 1.15 SIH: 70, 110, 900, 900; ArduCopter 4.7: 121, 200, 300, 300), the accuracies grown by the
        simulated ``--gps-noise`` (its standard deviation, added in quadrature), as a receiver's estimate would."""
        eph, epv, h_m, v_m = (70, 110, 0.9, 0.9) if self.is_px4 else (121, 200, 0.3, 0.3)
        noise = self.cfg.gps_noise_m
        return eph, epv, int(round(1000 * math.hypot(h_m, noise))), int(round(1000 * math.hypot(v_m, noise)))

    def truth(self) -> dict:
        """Current true state (map frame) for tests and the report."""
        s = self.quad.state
        return {
            "sim_time_s": round(self.sim_time_s, 3),
            "position": self.recorder.place(*s.position_neu),
            "velocity_neu_m_s": [float(v) for v in s.velocity_neu],
            "yaw_deg": math.degrees(s.yaw_rad),
            "armed": self.armed,
            "on_ground": s.on_ground,
            "crashed": self.crashed,
            "mode": self.mode.name,
            "task": self.task.kind.value,
            "landed_state": M.enums["MAV_LANDED_STATE"][self.landed_state()].name,
            "ready": not readiness_reason(self),
        }
