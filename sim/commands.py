"""COMMAND_LONG / COMMAND_INT / SET_MODE handling, mixed into :class:`sim.autopilot.Autopilot`.

Every command addressed to system 1 / component 1 (or broadcast) gets exactly one COMMAND_ACK:
ACCEPTED, DENIED / TEMPORARILY_REJECTED / FAILED (with the reason also sent as a STATUSTEXT
warning), or UNSUPPORTED for commands the sim does not implement. Every command is recorded in the
report with its result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from . import telemetry as tm
from .faults import command_name
from .modes import Behaviour, Mode, Task

M = mavlink
NAN = math.nan
FORCE_MAGIC = 21196.0

@dataclass
class CommandIn:
    """A COMMAND_LONG/COMMAND_INT normalised to seven float params (lat/lon in degrees for INT)."""

    command: int
    params: list[float]
    frame: int | None
    src_system: int
    src_component: int
    link_id: int

    def p(self, n: int) -> float:
        return self.params[n - 1]



@dataclass
class LinkState:
    """Per-link protocol state the autopilot cares about (the transport owns the rest)."""

    link_id: int
    classic: bool = False
    sent_setpoint: bool = False
    intervals: dict = field(default_factory=dict)
    next_due: dict = field(default_factory=dict)
    warned: set = field(default_factory=set)


class CommandHandlers:
    """Command handlers; relies on the attributes and helpers of :class:`Autopilot`."""

    def _on_command(self, link: LinkState, msg) -> None:
        is_int = msg.get_type() == "COMMAND_INT"
        params = [msg.param1, msg.param2, msg.param3, msg.param4]
        if is_int:
            x = NAN if msg.x == 0x7FFFFFFF else msg.x * 1e-7
            y = NAN if msg.y == 0x7FFFFFFF else msg.y * 1e-7
            params += [x, y, msg.z]
        else:
            params += [msg.param5, msg.param6, msg.param7]
        cmd = CommandIn(msg.command, [float(p) for p in params], msg.frame if is_int else None,
                        msg.get_srcSystem(), msg.get_srcComponent(), link.link_id)
        if msg.target_system not in (0, tm.SYSTEM_ID) or msg.target_component not in (0, tm.COMPONENT_ID):
            self._record(cmd, None, f"not addressed to {tm.SYSTEM_ID}/{tm.COMPONENT_ID}")
            return
        self._after_ack = []
        if self.command_faults.deny_command(cmd.command):
            result, reason = M.MAV_RESULT_DENIED, "fault injection: command denied"
        else:
            handler = self._commands.get(cmd.command)
            if handler is None:
                result, reason = M.MAV_RESULT_UNSUPPORTED, ""
            else:
                result, reason = handler(cmd, link)
        ack = M.MAVLink_command_ack_message(cmd.command, result, 0, 0, cmd.src_system, cmd.src_component)
        self.send(link, ack)
        if reason and result != M.MAV_RESULT_ACCEPTED:
            self.statustext(M.MAV_SEVERITY_WARNING, reason)
        for target, out in self._after_ack:
            self.send(target, out)
        self._after_ack = []
        self._record(cmd, result, reason)

    def _record(self, cmd: CommandIn, result: int | None, reason: str) -> None:
        name = command_name(cmd.command) if cmd.command >= 0 else "SET_MODE"
        result_name = M.enums["MAV_RESULT"][result].name if result is not None else None
        self.recorder.commands.append({
            "sim_time_s": round(self.sim_time_s, 3), "link": cmd.link_id,
            "source": f"{cmd.src_system}/{cmd.src_component}", "command": cmd.command, "name": name,
            "params": [None if not math.isfinite(p) else p for p in cmd.params],
            "frame": cmd.frame, "result": result, "result_name": result_name, "reason": reason,
        })
        if cmd.command not in (M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_CMD_REQUEST_MESSAGE):
            self.emit("command", f"{name} -> {result_name}" + (f" ({reason})" if reason else ""))

    def _cmd_arm(self, cmd: CommandIn, link):
        force = abs(cmd.p(2) - FORCE_MAGIC) < 0.5
        if cmd.p(1) >= 0.5:
            if self.armed:
                return M.MAV_RESULT_ACCEPTED, ""
            if self.command_faults.deny_arm():
                n, total = self.command_faults.arms_denied, self.cfg.faults.deny_arm_count
                return M.MAV_RESULT_TEMPORARILY_REJECTED, f"fault injection: arming denied ({n}/{total})"
            if self.crashed:
                return M.MAV_RESULT_DENIED, "arming denied: vehicle crashed"
            if self.airborne:
                return M.MAV_RESULT_DENIED, "arming denied: in air"
            if self.home_neu is None:
                return M.MAV_RESULT_DENIED, "arming denied: no home position"
            if not self.mode.armable and not force:
                return M.MAV_RESULT_DENIED, f"arming denied: not in {self.mode.name}"
            if (self.cfg.strict and self.mode.behaviour == Behaviour.OFFBOARD
                    and self.wall_s - self.setpoint_wall_s > self.param_offboard_timeout()):
                return M.MAV_RESULT_DENIED, "arming denied: offboard without setpoints"
            self._set_armed(True)
            return M.MAV_RESULT_ACCEPTED, ""
        if not self.armed:
            return M.MAV_RESULT_ACCEPTED, ""
        if self.airborne and not force:
            return M.MAV_RESULT_DENIED, "disarm denied: in air (force with param2=21196)"
        if self.airborne:
            self._crash(None, "forced disarm in flight")
            return M.MAV_RESULT_ACCEPTED, ""
        self._set_armed(False)
        return M.MAV_RESULT_ACCEPTED, ""

    def _set_armed(self, armed: bool, why: str = "") -> None:
        self.armed = armed
        self.touchdown_s = None
        if armed and self.task.kind in (Behaviour.HOLD, Behaviour.OFFBOARD):
            self.task.position_neu = self.position_neu.copy()
        text = ("ARMED" if armed else "DISARMED") + (f" ({why})" if why else "")
        self.emit("armed" if armed else "disarmed", text)

    def _cmd_set_mode(self, cmd: CommandIn, link):
        mode, reason = self.personality.decode_set_mode(int(cmd.p(1)), cmd.p(2), cmd.p(3))
        if mode is None:
            return M.MAV_RESULT_DENIED, reason
        return self._request_mode(mode, link)

    def _on_set_mode_msg(self, link, msg) -> None:
        if msg.target_system not in (0, tm.SYSTEM_ID):
            return
        cmd = CommandIn(-1, [float(msg.base_mode), float(msg.custom_mode)] + [NAN] * 5, None,
                        msg.get_srcSystem(), msg.get_srcComponent(), link.link_id)
        mode = self.personality.decode_custom_mode(msg.custom_mode)
        if mode is None:
            result, reason = M.MAV_RESULT_DENIED, f"SET_MODE custom_mode {msg.custom_mode} not supported"
        else:
            result, reason = self._request_mode(mode, link)
        if not self.is_px4:  # ArduPilot acks SET_MODE with command = message id 11
            self.send(link, M.MAVLink_command_ack_message(M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0,
                                                          cmd.src_system, cmd.src_component))
        if reason:
            self.statustext(M.MAV_SEVERITY_WARNING, reason)
        self._record(cmd, result, reason)

    def _request_mode(self, mode: Mode, link):
        if mode.behaviour == Behaviour.OFFBOARD and self.is_px4:
            fresh = self.wall_s - self.setpoint_wall_s <= self.param_offboard_timeout()
            if self.cfg.strict and not fresh:
                return M.MAV_RESULT_DENIED, "offboard denied: no setpoint stream"
            if not self.cfg.strict and not link.sent_setpoint and not link.classic:
                link.classic = True
                self.emit("dialect", f"link {link.link_id}: OFFBOARD before any setpoint -> classic dialect")
        if mode == self.mode and mode.behaviour == self.task.kind:
            return M.MAV_RESULT_ACCEPTED, ""
        self._enter_mode(mode)
        return M.MAV_RESULT_ACCEPTED, ""

    def _target_up(self, cmd: CommandIn, value: float, relative_default: bool) -> float:
        """Map up (m) of an altitude param, honouring COMMAND_INT frames."""
        frame = cmd.frame
        if frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            return self.home_neu[2] + value
        if frame in (M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT):
            p = self.position_neu
            return self._ground_fn(p[0], p[1], p[2] + 0.05) + value
        if frame is None and relative_default:
            return self.home_neu[2] + value
        return value  # AMSL == map up

    def _cmd_takeoff(self, cmd: CommandIn, link):
        if not self.armed:
            return M.MAV_RESULT_DENIED, "takeoff denied: not armed"
        if not self.is_px4 and self.mode.name != "GUIDED":
            return M.MAV_RESULT_DENIED, "takeoff denied: needs GUIDED"
        pos = self.position_neu
        ground = self._ground_fn(pos[0], pos[1], pos[2] + 0.05)
        alt = cmd.p(7)
        target_up = ground + self._default_takeoff_height() if not math.isfinite(alt) else \
            self._target_up(cmd, alt, relative_default=not self.is_px4)
        if target_up < ground + 0.5:
            return M.MAV_RESULT_DENIED, f"takeoff denied: altitude {alt:.1f} below ground"
        if self.airborne and not self.is_px4:
            return M.MAV_RESULT_FAILED, "takeoff failed: already flying"
        target = np.array([pos[0], pos[1], max(target_up, pos[2])])
        self._enter_mode(self.personality.mode_for(Behaviour.TAKEOFF), Task(Behaviour.TAKEOFF, target))
        self.emit("takeoff", f"takeoff to {target[2] - ground:.1f} m above ground")
        return M.MAV_RESULT_ACCEPTED, ""

    def _latlon_target(self, cmd: CommandIn) -> np.ndarray:
        pos = self.position_neu.copy()
        lat, lon = cmd.p(5), cmd.p(6)
        if math.isfinite(lat) and math.isfinite(lon) and not (lat == 0 and lon == 0):
            pos[0], pos[1], _ = self.city.geodetic_to_map(lat, lon, 0.0)
        return pos

    def _cmd_land(self, cmd: CommandIn, link):
        task = Task(Behaviour.LAND, self._latlon_target(cmd))
        self._enter_mode(self.personality.mode_for(Behaviour.LAND), task)
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_rtl(self, cmd: CommandIn, link):
        self._enter_mode(self.personality.mode_for(Behaviour.RTL))
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_set_home(self, cmd: CommandIn, link):
        if cmd.p(1) >= 0.5:
            lat, lon, alt = self.city.map_to_geodetic(*self.position_neu)
        else:
            lat, lon, alt = cmd.p(5), cmd.p(6), cmd.p(7)
        if not all(math.isfinite(v) for v in (lat, lon, alt)) or abs(lat) > 90 or abs(lon) > 180:
            return M.MAV_RESULT_DENIED, "home denied: invalid coordinates"
        if lat == 0 and lon == 0:
            return M.MAV_RESULT_DENIED, "home denied: lat/lon 0,0"
        self.home_neu = np.array(self.city.geodetic_to_map(lat, lon, alt))
        self.recorder.home = self.recorder.place(*self.home_neu)
        self.emit("home", f"home set to {lat:.7f},{lon:.7f},{alt:.2f}")
        self._after_ack.append((None, tm.home_position(self.snapshot())))
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_reposition(self, cmd: CommandIn, link):
        if not self.armed or not self.airborne:
            return M.MAV_RESULT_DENIED, "reposition denied: not flying"
        target = self._latlon_target(cmd)
        if math.isfinite(cmd.p(7)):
            target[2] = self._target_up(cmd, cmd.p(7), relative_default=not self.is_px4)
        if math.isfinite(cmd.p(1)) and cmd.p(1) > 0:
            self.speed_limit_m_s = cmd.p(1)
        mode = self.personality.mode_for(Behaviour.HOLD if self.is_px4 else Behaviour.OFFBOARD)
        self._enter_mode(mode, Task(Behaviour.HOLD, target))
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_change_speed(self, cmd: CommandIn, link):
        if int(cmd.p(1)) in (0, 1):
            speed = cmd.p(2)
            self.speed_limit_m_s = speed if math.isfinite(speed) and speed > 0 else NAN
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_message_interval(self, cmd: CommandIn, link):
        msg_id, interval_us = int(cmd.p(1)), cmd.p(2)
        if msg_id not in tm.BUILDERS:
            return M.MAV_RESULT_UNSUPPORTED, f"message {msg_id} not streamed"
        if msg_id == M.MAVLINK_MSG_ID_HEARTBEAT:
            return M.MAV_RESULT_ACCEPTED, ""  # heartbeat stays at 1 Hz
        if interval_us == -1:
            link.intervals[msg_id] = None
        elif interval_us == 0 or not math.isfinite(interval_us):
            link.intervals[msg_id] = tm.default_intervals(self.cfg.speedup)[msg_id]
        else:
            link.intervals[msg_id] = max(1.0 / tm.MAX_RATE_HZ, interval_us / 1e6)
        link.next_due[msg_id] = self.wall_s
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_request_message(self, cmd: CommandIn, link):
        msg_id = int(cmd.p(1))
        if msg_id not in tm.BUILDERS:
            return M.MAV_RESULT_UNSUPPORTED, f"message {msg_id} not available"
        self._after_ack.append((link, tm.BUILDERS[msg_id](self.snapshot())))
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_capabilities(self, cmd: CommandIn, link):
        self._after_ack.append((link, tm.autopilot_version(self.snapshot())))
        return M.MAV_RESULT_ACCEPTED, ""

    def _cmd_get_home(self, cmd: CommandIn, link):
        self._after_ack.append((link, tm.home_position(self.snapshot())))
        return M.MAV_RESULT_ACCEPTED, ""

