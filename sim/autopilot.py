"""The autopilot: modes, commands, setpoints, flight tasks and the physics step.

Owned by the simulation thread; nothing here is thread-safe on its own (the :class:`Simulator`
holds a lock around every call).

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

from . import telemetry as tm
from .commands import CommandHandlers, LinkState
from .config import SimConfig
from .dynamics import ControlTarget, Limits, PointMassQuad
from .faults import CommandFaults
from .modes import ArduCopter, Behaviour, Mode, Task, make_personality
from .report import Collision, FlightRecorder
from .setpoints import global_int_target, local_ned_target
from .world import CityMap

log = logging.getLogger(__name__)
M = mavlink
NAN = math.nan


class Autopilot(CommandHandlers):
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
        table = tm.PX4_PARAMS if self.is_px4 else tm.ARDUPILOT_PARAMS
        self.param_types = {k: v[1] for k, v in table.items()}
        self.params = {k: v[0] for k, v in table.items()}
        self.command_faults = CommandFaults(config.faults)
        self.rng = random.Random(config.seed)
        self.sim_time_s = 0.0
        self.wall_s = 0.0
        self.home_neu = np.zeros(3)
        if config.start is not None:
            n, e, _ = city.geodetic_to_map(config.start[0], config.start[1], 0.0)
        else:
            n, e = 0.0, 0.0
        up = city.ground_up_m(n, e, math.inf, config.radius_m)
        self.boot_neu = np.array([n, e, up])
        self.quad = PointMassQuad(Limits(), self.boot_neu)
        self._apply_params()
        self.armed = False
        self.crashed = False
        self.mode: Mode = self.personality.boot_mode
        self.task = Task(Behaviour.HOLD, self.boot_neu.copy())
        self.setpoint: ControlTarget | None = None
        self.setpoint_wall_s = -math.inf
        self.following = False
        self.touchdown_s: float | None = None
        self.speed_limit_m_s = NAN
        self.gps_noise = np.zeros(3)
        self.gust = np.zeros(3)
        self._commands = {
            M.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm,
            M.MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            M.MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff,
            M.MAV_CMD_NAV_LAND: self._cmd_land,
            M.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._cmd_rtl,
            M.MAV_CMD_DO_SET_HOME: self._cmd_set_home,
            M.MAV_CMD_DO_REPOSITION: self._cmd_reposition,
            M.MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
            M.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_message_interval,
            M.MAV_CMD_REQUEST_MESSAGE: self._cmd_request_message,
            M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._cmd_capabilities,
            M.MAV_CMD_GET_HOME_POSITION: self._cmd_get_home,
        }
        self._after_ack: list[tuple[object, object]] = []

    # ------------------------------------------------------------------ frames and state
    @property
    def origin_neu(self) -> np.ndarray:
        """Local NED origin in the map frame."""
        return self.home_neu if self.cfg.origin == "home" else self.boot_neu

    @property
    def position_neu(self) -> np.ndarray:
        return self.quad.state.position_neu

    @property
    def airborne(self) -> bool:
        return not self.quad.state.on_ground

    def param(self, name: str) -> float:
        return self.params[name]

    def _apply_params(self) -> None:
        lim = self.quad.limits
        if self.is_px4:
            lim.max_horizontal_speed_m_s = self.params["MPC_XY_VEL_MAX"]
            lim.max_climb_m_s = self.params["MPC_Z_VEL_MAX_UP"]
            lim.max_descent_m_s = self.params["MPC_Z_VEL_MAX_DN"]
        else:
            lim.max_horizontal_speed_m_s = self.params["WPNAV_SPEED"] / 100.0
            lim.max_climb_m_s = self.params["WPNAV_SPEED_UP"] / 100.0
            lim.max_descent_m_s = self.params["WPNAV_SPEED_DN"] / 100.0

    def _land_speed(self) -> float:
        return self.params["MPC_LAND_SPEED"] if self.is_px4 else self.params["LAND_SPEED"] / 100.0

    def _ground_fn(self, north_m: float, east_m: float, below_up_m: float) -> float:
        return self.city.ground_up_m(north_m, east_m, below_up_m, self.cfg.radius_m)

    def landed_state(self) -> int:
        if not self.airborne:
            return M.MAV_LANDED_STATE_ON_GROUND
        if self.task.kind == Behaviour.TAKEOFF:
            return M.MAV_LANDED_STATE_TAKEOFF
        if self.task.kind == Behaviour.LAND or (self.task.kind == Behaviour.RTL and self.task.phase == 2):
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    def statustext(self, severity: int, text: str, link=None) -> None:
        for msg in tm.statustext(severity, text):
            self.send(link, msg)

    # ------------------------------------------------------------------ modes and tasks
    def _enter_mode(self, mode: Mode, task: Task | None = None) -> None:
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
            self.following = self.wall_s - self.setpoint_wall_s <= self.param_offboard_timeout()
        changed = mode != self.mode
        self.mode, self.task = mode, task
        if changed:
            self.emit("mode", f"mode {mode.name}")

    def _default_takeoff_height(self) -> float:
        if self.is_px4:
            return self.params["MIS_TAKEOFF_ALT"]
        return max(1.0, self.params["PILOT_TKOFF_ALT"] / 100.0)

    def param_offboard_timeout(self) -> float:
        return self.params.get("COM_OF_LOSS_T", 0.5)

    def _hold(self, reason: str = "") -> None:
        self._enter_mode(self.personality.mode_for(Behaviour.HOLD))
        if reason:
            self.statustext(M.MAV_SEVERITY_WARNING, reason)

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
        elif kind == "PING" and msg.target_system == 0:
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
        self.setpoint_wall_s = self.wall_s
        link.sent_setpoint = True
        if self.mode.behaviour == Behaviour.OFFBOARD:
            if self.task.kind != Behaviour.OFFBOARD:
                self.task = Task(Behaviour.OFFBOARD, self.position_neu.copy())
            self.following = True

    def _on_param(self, link: LinkState, msg) -> None:
        if msg.target_system not in (0, tm.SYSTEM_ID):
            return
        names = list(self.params)
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            selected = names
        elif kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:
                selected = names[msg.param_index : msg.param_index + 1]
            else:
                selected = [msg.param_id] if msg.param_id in self.params else []
        else:
            if msg.param_id not in self.params:
                self.statustext(M.MAV_SEVERITY_WARNING, f"unknown parameter {msg.param_id}", link)
                return
            value = float(msg.param_value)
            if self.param_types[msg.param_id] != tm.REAL32:
                value = float(int(round(value)))
            self.params[msg.param_id] = value
            self._apply_params()
            self.emit("param", f"{msg.param_id} = {value:g}")
            selected = [msg.param_id]
        for name in selected:
            index = names.index(name)
            out = tm.param_value(name, self.params[name], self.param_types[name], len(names), index)
            self.send(None if kind == "PARAM_SET" else link, out)

    # ------------------------------------------------------------------ physics step
    def control_target(self) -> ControlTarget:
        """Controller target for the current task (map frame)."""
        task, pos = self.task, self.position_neu
        speed = self.speed_limit_m_s
        if task.kind == Behaviour.OFFBOARD:
            if self.following and self.setpoint is not None and (self.is_px4 or self.airborne):
                sp = self.setpoint
                if math.isfinite(speed):
                    sp = ControlTarget(sp.position_neu, sp.velocity_neu, sp.yaw_rad, sp.yaw_rate_rad_s, speed,
                                       sp.max_descent_m_s)
                return sp
            return ControlTarget(tuple(task.position_neu), max_horizontal_speed_m_s=speed)
        if task.kind in (Behaviour.HOLD, Behaviour.TAKEOFF):
            return ControlTarget(tuple(task.position_neu), max_horizontal_speed_m_s=speed)
        land = self._land_speed()
        if task.kind == Behaviour.LAND:
            n, e = task.position_neu[:2]
            return ControlTarget((n, e, NAN), (NAN, NAN, -land), max_horizontal_speed_m_s=speed,
                                 max_descent_m_s=land)
        # RTL
        home = self.home_neu
        rtl_height = self.params["RTL_RETURN_ALT"] if self.is_px4 else self.params["RTL_ALT"] / 100.0
        rtl_up = max(home[2] + rtl_height, task.position_neu[2])
        if task.phase == 0:
            if not self.airborne:
                return ControlTarget(tuple(pos))
            return ControlTarget((task.position_neu[0], task.position_neu[1], rtl_up))
        if task.phase == 1:
            return ControlTarget((home[0], home[1], rtl_up), max_horizontal_speed_m_s=speed)
        return ControlTarget((home[0], home[1], NAN), (NAN, NAN, -land), max_descent_m_s=land)

    def step(self, dt_s: float) -> None:
        """Advance the vehicle by one physics step (``self.wall_s`` must be current)."""
        if (self.cfg.strict and self.is_px4 and self.mode.behaviour == Behaviour.OFFBOARD
                and self.wall_s - self.setpoint_wall_s > self.param_offboard_timeout()):
            self._hold("offboard setpoints lost: holding position")
            self.emit("failsafe", "offboard setpoints lost -> hold")
        s = self.quad.state
        wind = None
        if self.cfg.wind_m_s != (0.0, 0.0) or self.cfg.gust_m_s > 0:
            if self.cfg.gust_m_s > 0:
                k = dt_s / 3.0
                for i in (0, 1):
                    kick = self.cfg.gust_m_s * math.sqrt(2 * k) * self.rng.gauss(0, 1)
                    self.gust[i] += -k * self.gust[i] + kick
            wind = np.array([self.cfg.wind_m_s[0], self.cfg.wind_m_s[1], 0.0]) + self.gust
        motors = self.armed and not self.crashed
        touched = self.quad.step(dt_s, self.control_target(), motors, self._ground_fn, wind)
        self.sim_time_s += dt_s
        if self.cfg.gps_noise_m > 0:
            k = dt_s / 10.0
            for i in range(3):
                kick = self.cfg.gps_noise_m * math.sqrt(2 * k) * self.rng.gauss(0, 1)
                self.gps_noise[i] += -k * self.gps_noise[i] + kick
        speed = float(np.linalg.norm(s.velocity_neu))
        hit = self.recorder.truth.check(s.position_neu, self.airborne, self.sim_time_s, speed)
        if hit is not None:
            self._crash(hit, "collision")
        if touched and not self.crashed:
            entry = self.recorder.add_landing(self.sim_time_s, s.position_neu)
            self.touchdown_s = self.sim_time_s
            self.emit("landed", f"touchdown at N {entry['north_m']:.2f} E {entry['east_m']:.2f} "
                                f"alt {entry['up_m']:.2f} ({entry['lat_deg']:.7f},{entry['lon_deg']:.7f})")
        if self.airborne:
            self.touchdown_s = None
        self._advance_task()
        delay = self.params["COM_DISARM_LAND"] if self.is_px4 else self.params["DISARM_DELAY"]
        if self.armed and self.touchdown_s is not None and self.sim_time_s - self.touchdown_s >= delay:
            self._set_armed(False, "auto-disarm after landing")
        self.recorder.update(dt_s, s.position_neu, self.armed, self.airborne, self.home_neu[2])

    def _advance_task(self) -> None:
        task, pos = self.task, self.position_neu
        if task.kind == Behaviour.TAKEOFF and self.airborne and abs(pos[2] - task.position_neu[2]) < 0.1:
            self.emit("takeoff", f"takeoff complete at {pos[2] - self.home_neu[2]:.1f} m above home")
            if self.is_px4:
                hold = Task(Behaviour.HOLD, task.position_neu)
                self._enter_mode(self.personality.mode_for(Behaviour.HOLD), hold)
            else:
                self.task = Task(Behaviour.OFFBOARD, task.position_neu.copy())
                self.following = False
        elif task.kind == Behaviour.RTL and self.airborne:
            rtl_target = self.control_target().position_neu
            if task.phase == 0 and pos[2] >= rtl_target[2] - 0.3:
                task.phase = 1
            elif task.phase == 1 and math.hypot(*(pos[:2] - self.home_neu[:2])) < 0.5:
                task.phase = 2

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
        self._set_armed(False, why)

    # ------------------------------------------------------------------ telemetry
    def snapshot(self) -> tm.TelemetrySnapshot:
        s = self.quad.state
        pos = s.position_neu.copy()
        if self.cfg.gps_noise_m > 0:
            pos[:2] += self.gps_noise[:2]
            if self.airborne:
                pos[2] += self.gps_noise[2]
        lat, lon, alt = self.city.map_to_geodetic(*pos)
        hlat, hlon, halt = self.city.map_to_geodetic(*self.home_neu)
        local = pos - self.origin_neu
        home_local = self.home_neu - self.origin_neu
        roll, pitch, yaw = self.quad.attitude()
        base = self.mode.base_flags | (M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        status = M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY
        if self.crashed:
            status = M.MAV_STATE_EMERGENCY
        v = s.velocity_neu
        return tm.TelemetrySnapshot(
            int(self.sim_time_s * 1000), lat, lon, alt, alt - self.home_neu[2],
            float(local[0]), float(local[1]), float(-local[2]) + 0.0, float(v[0]), float(v[1]), float(-v[2]),
            roll, pitch, yaw, s.yaw_rate_rad_s, hlat, hlon, halt,
            float(home_local[0]), float(home_local[1]), float(-home_local[2]) + 0.0,
            self.personality.autopilot, base, self.mode.custom_mode, status, self.landed_state(),
            not self.crashed, 50 if self.armed and self.airborne else 0,
        )

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
        }
