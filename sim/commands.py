"""COMMAND_LONG / COMMAND_INT / SET_MODE handling, mixed into :class:`sim.autopilot.Autopilot`.

Every command addressed to system 1 / component 1 (or broadcast) gets exactly one COMMAND_ACK whose
target_system/component are the sender's, with the result code the real autopilot gives (measured on
ArduCopter SITL V4.7.0-dev and PX4 v1.15.4 SITL):

=================================================  ==========================  ==========================
request                                            ArduCopter                  PX4
=================================================  ==========================  ==========================
NAV_TAKEOFF while disarmed                         FAILED                      ACCEPTED (mode TAKEOFF;
                                                                               arming then takes off)
NAV_TAKEOFF when already flying                    FAILED                      ACCEPTED
DO_SET_MODE with param1 = 0 (no custom mode)       DENIED                      ACCEPTED (no change)
DO_SET_MODE to a mode the sim has not got          FAILED                      DENIED
OFFBOARD without setpoints (``--strict``)          --                          ACCEPTED disarmed,
                                                                               TEMPORARILY_REJECTED armed
arm refused (not ready, mode, ...)                 FAILED + "Arm: ..."         TEMPORARILY_REJECTED +
                                                                               "Arming denied: ..."
REQUEST_MESSAGE GPS_GLOBAL_ORIGIN (49)             ACCEPTED, then the message  the message, then ACCEPTED
REQUEST_MESSAGE of a message it cannot send        FAILED                      DENIED
SET_MESSAGE_INTERVAL of a message it cannot send   DENIED                      FAILED
GET_HOME_POSITION before home is set               FAILED                      FAILED
DO_SET_HOME with lat = lon = 0                     home = current position     home = 0,0 (as asked)
DO_REPOSITION as COMMAND_LONG                      UNSUPPORTED                 UNSUPPORTED when disarmed
SET_MODE message                                   no COMMAND_ACK              COMMAND_ACK for DO_SET_MODE
unknown command                                    UNSUPPORTED                 UNSUPPORTED
=================================================  ==========================  ==========================

Refusals carry a STATUSTEXT only where the real autopilot sends one (arming; PX4's mode switch refusals);
every command and its reason are recorded in the report. Fault injection (``--deny-*``) always explains itself
in a STATUSTEXT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from . import streams
from . import telemetry as tm
from .arming import arm_refusal
from .faults import command_name
from .modes import ArduCopter, Behaviour, Mode, Task

M = mavlink
NAN = math.nan
FORCE_MAGIC = 21196.0
ACCEPTED = M.MAV_RESULT_ACCEPTED


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
    #: A ground station's HEARTBEAT (type GCS) has arrived on this link.
    gcs_seen: bool = False


class CommandHandlers:
    """Command handlers; relies on the attributes and helpers of :class:`Autopilot`."""

    def command_table(self) -> dict:
        return {
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
        self._before_ack: list = []
        self._after_ack = []
        self._in_command = True
        try:
            if self.command_faults.deny_command(cmd.command):
                result, reason = M.MAV_RESULT_DENIED, "fault injection: command denied"
                self.statustext(M.MAV_SEVERITY_WARNING, reason)
            else:
                handler = self._commands.get(cmd.command)
                if handler is None:
                    result, reason = M.MAV_RESULT_UNSUPPORTED, ""
                else:
                    result, reason = handler(cmd, link)
        finally:
            self._in_command = False
        for target, out in self._before_ack:
            self.send(target, out)
        self.send(link, M.MAVLink_command_ack_message(cmd.command, result, 0, 0, cmd.src_system,
                                                      cmd.src_component))
        for target, out in self._after_ack:
            self.send(target, out)
        self._before_ack, self._after_ack = [], []
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

    def _refuse(self, result: int, text: str) -> tuple[int, str]:
        """A refusal the real autopilot announces in a STATUSTEXT."""
        self.statustext(M.MAV_SEVERITY_CRITICAL, text)
        return result, text.rstrip("\t")

    # ------------------------------------------------------------------ arming
    def _cmd_arm(self, cmd: CommandIn, link):
        force = abs(cmd.p(2) - FORCE_MAGIC) < 0.5
        if cmd.p(1) >= 0.5:
            if self.armed:
                return ACCEPTED, ""
            if self.command_faults.deny_arm():
                n, total = self.command_faults.arms_denied, self.cfg.faults.deny_arm_count
                text = f"fault injection: arming denied ({n}/{total})"
                self.statustext(M.MAV_SEVERITY_WARNING, text)
                return M.MAV_RESULT_TEMPORARILY_REJECTED, text
            refusal = arm_refusal(self, force)
            if refusal is not None:
                return self._refuse(*refusal)
            self.set_armed(True)
            self.statustext(M.MAV_SEVERITY_INFO, "Armed by external command\t" if self.is_px4 else "Arming motors")
            if self.is_px4 and self.mode.behaviour == Behaviour.TAKEOFF:
                self._announce_px4_takeoff()
            return ACCEPTED, ""
        if not self.armed:
            return ACCEPTED, ""
        if self.airborne and not force:
            return (M.MAV_RESULT_DENIED if self.is_px4 else M.MAV_RESULT_FAILED), "disarm refused: in air"
        if self.airborne:
            self._crash(None, "forced disarm in flight")
            return ACCEPTED, ""
        self.statustext(M.MAV_SEVERITY_INFO, "Disarmed by external command\t" if self.is_px4 else "Disarming motors")
        self.set_armed(False)
        return ACCEPTED, ""

    # ------------------------------------------------------------------ modes
    def _cmd_set_mode(self, cmd: CommandIn, link):
        if not int(cmd.p(1)) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            if self.is_px4:
                return ACCEPTED, "no custom mode: nothing to change"
            return M.MAV_RESULT_DENIED, "DO_SET_MODE without MAV_MODE_FLAG_CUSTOM_MODE_ENABLED"
        mode, reason = self.personality.decode_set_mode(int(cmd.p(1)), cmd.p(2), cmd.p(3))
        if mode is None:
            return (M.MAV_RESULT_DENIED if self.is_px4 else M.MAV_RESULT_FAILED), reason
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
        if self.is_px4:  # PX4 acks it as the DO_SET_MODE it turns it into; ArduCopter 4.7 does not ack it
            self.send(link, M.MAVLink_command_ack_message(M.MAV_CMD_DO_SET_MODE, result, 0, 0,
                                                          cmd.src_system, cmd.src_component))
        self._record(cmd, result, reason)

    def _needs_position(self, mode: Mode) -> bool:
        """Whether ``mode`` needs a horizontal position estimate: both autopilots refuse such a mode without one
        (PX4's Land too; ArduCopter's LAND comes down without one, drifting)."""
        b = mode.behaviour
        return b in (Behaviour.HOLD, Behaviour.TAKEOFF, Behaviour.OFFBOARD, Behaviour.RTL) or (
            self.is_px4 and b == Behaviour.LAND)

    def _position_refusal(self, mode: Mode) -> tuple[int, str] | None:
        """The refusal of ``mode`` while the estimator has no position (``--gps-loss``), else None. PX4 (measured,
        1.15 SITL): TEMPORARILY_REJECTED, "Switching to Land is currently not available" (it lets a disarmed
        vehicle select any mode); ArduCopter: FAILED, "Mode change to GUIDED failed: requires position"."""
        if self.position_valid or not self._needs_position(mode):
            return None
        if self.is_px4:
            if not self.armed:
                return None
            return self._refuse(M.MAV_RESULT_TEMPORARILY_REJECTED,
                                f"Switching to {mode.label} is currently not available\t")
        text = f"Mode change to {mode.name} failed: requires position"
        self.statustext(M.MAV_SEVERITY_WARNING, text)
        return M.MAV_RESULT_FAILED, text

    def _request_mode(self, mode: Mode, link):
        if (refusal := self._position_refusal(mode)) is not None:
            return refusal
        if self.is_px4:
            if mode.behaviour == Behaviour.OFFBOARD and not self.cfg.strict:
                if not link.sent_setpoint and not link.classic:
                    link.classic = True
                    self.emit("dialect", f"link {link.link_id}: OFFBOARD before any setpoint -> classic dialect")
            elif self.armed and not self._px4_can_run(mode):
                return self._refuse(M.MAV_RESULT_TEMPORARILY_REJECTED,
                                    f"Switching to {mode.label} is currently not available\t")
        if mode == self.mode and mode.behaviour == self.task.kind:
            return ACCEPTED, ""
        self.enter_mode(mode)
        return ACCEPTED, ""

    def _px4_can_run(self, mode: Mode) -> bool:
        """PX4 lets an armed vehicle switch only to a mode that can run (always while disarmed)."""
        if mode.needs_rc or mode.name == "MISSION":
            return False
        return mode.behaviour != Behaviour.OFFBOARD or self.setpoint_fresh()

    # ------------------------------------------------------------------ takeoff, land, RTL, home
    def _target_up(self, cmd: CommandIn, value: float, relative_default: bool) -> float:
        """Map up (m) of an altitude param, honouring COMMAND_INT frames."""
        frame = cmd.frame
        home_up = self.home_neu[2] if self.home_neu is not None else self.boot_neu[2]
        if frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            return home_up + value
        if frame in (M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT):
            p = self.position_neu
            return self._ground_fn(p[0], p[1], p[2] + 0.05) + value
        if frame is None and relative_default:
            return home_up + value
        return value  # AMSL == map up

    def _cmd_takeoff(self, cmd: CommandIn, link):
        if (refusal := self._position_refusal(self.personality.mode_for(Behaviour.TAKEOFF))) is not None:
            return refusal
        pos = self.position_neu
        ground = self._ground_fn(pos[0], pos[1], pos[2] + 0.05)
        alt = cmd.p(7)
        target_up = ground + self._default_takeoff_height() if not math.isfinite(alt) else \
            self._target_up(cmd, alt, relative_default=not self.is_px4)
        if not self.is_px4:
            if not self.armed:
                return M.MAV_RESULT_FAILED, "takeoff refused: not armed"
            if self.mode.name not in ArduCopter.TAKEOFF_MODES:
                return M.MAV_RESULT_FAILED, f"takeoff refused: {self.mode.name} has no user takeoff"
            if self.airborne:
                return M.MAV_RESULT_FAILED, "takeoff refused: already flying"
            if target_up <= pos[2]:
                return M.MAV_RESULT_FAILED, f"takeoff refused: altitude {alt:.1f} not above the vehicle"
            self.task = Task(Behaviour.TAKEOFF, np.array([pos[0], pos[1], target_up]))
            self.following = False
            self.emit("takeoff", f"takeoff to {target_up - ground:.1f} m above ground")
            return ACCEPTED, ""
        target = np.array([pos[0], pos[1], max(target_up, pos[2])])
        self.enter_mode(self.personality.mode_for(Behaviour.TAKEOFF), Task(Behaviour.TAKEOFF, target))
        self._takeoff_default_alt = not math.isfinite(alt)
        if self.armed:
            self._announce_px4_takeoff()
        self.emit("takeoff", f"takeoff to {target[2] - ground:.1f} m above ground")
        return ACCEPTED, ""

    _takeoff_default_alt = False

    def _announce_px4_takeoff(self) -> None:
        if self._takeoff_default_alt:
            self.statustext(M.MAV_SEVERITY_INFO,
                            f"Using default takeoff altitude: {self.params['MIS_TAKEOFF_ALT']:.1f} m\t")

    def _latlon_target(self, cmd: CommandIn) -> np.ndarray:
        pos = self.position_neu.copy()
        lat, lon = cmd.p(5), cmd.p(6)
        if math.isfinite(lat) and math.isfinite(lon) and not (lat == 0 and lon == 0):
            pos[0], pos[1], _ = self.city.geodetic_to_map(lat, lon, 0.0)
        return pos

    def _cmd_land(self, cmd: CommandIn, link):
        if (refusal := self._position_refusal(self.personality.mode_for(Behaviour.LAND))) is not None:
            return refusal
        task = Task(Behaviour.LAND, self._latlon_target(cmd))
        self.enter_mode(self.personality.mode_for(Behaviour.LAND), task)
        if self.is_px4 and self.armed:
            self.statustext(M.MAV_SEVERITY_INFO, "Landing at current position\t")
        return ACCEPTED, ""

    def _cmd_rtl(self, cmd: CommandIn, link):
        if (refusal := self._position_refusal(self.personality.mode_for(Behaviour.RTL))) is not None:
            return refusal
        self.enter_mode(self.personality.mode_for(Behaviour.RTL))
        return ACCEPTED, ""

    def _cmd_set_home(self, cmd: CommandIn, link):
        lat, lon, alt = cmd.p(5), cmd.p(6), cmd.p(7)
        use_current = cmd.p(1) >= 0.5 or (not self.is_px4 and lat == 0 and lon == 0)
        if use_current:
            self.set_home(self.position_neu.copy(), "DO_SET_HOME current")
            return ACCEPTED, ""
        if not all(math.isfinite(v) for v in (lat, lon, alt)) or abs(lat) > 90 or abs(lon) > 180:
            return (M.MAV_RESULT_DENIED if self.is_px4 else M.MAV_RESULT_FAILED), "home refused: invalid position"
        self.set_home(np.array(self.city.geodetic_to_map(lat, lon, alt)), "DO_SET_HOME")
        return ACCEPTED, ""

    def _cmd_reposition(self, cmd: CommandIn, link):
        if not self.is_px4 and cmd.frame is None:
            return M.MAV_RESULT_UNSUPPORTED, "ArduPilot takes DO_REPOSITION as COMMAND_INT only"
        if not self.armed or not self.airborne:
            return (M.MAV_RESULT_UNSUPPORTED if self.is_px4 else M.MAV_RESULT_FAILED), "reposition: not flying"
        target = self._latlon_target(cmd)
        if math.isfinite(cmd.p(7)):
            target[2] = self._target_up(cmd, cmd.p(7), relative_default=not self.is_px4)
        if math.isfinite(cmd.p(1)) and cmd.p(1) > 0:
            self.speed_limit_m_s = cmd.p(1)
        mode = self.personality.mode_for(Behaviour.HOLD if self.is_px4 else Behaviour.OFFBOARD)
        if (refusal := self._position_refusal(mode)) is not None:
            return refusal
        self.enter_mode(mode, Task(Behaviour.HOLD, target))
        return ACCEPTED, ""

    def _cmd_change_speed(self, cmd: CommandIn, link):
        if int(cmd.p(1)) in (0, 1):
            speed = cmd.p(2)
            self.speed_limit_m_s = speed if math.isfinite(speed) and speed > 0 else NAN
        return ACCEPTED, ""

    # ------------------------------------------------------------------ messages
    def _cmd_message_interval(self, cmd: CommandIn, link):
        msg_id, interval_us = int(cmd.p(1)), cmd.p(2)
        if not self.streamable(msg_id):
            return (M.MAV_RESULT_FAILED if self.is_px4 else M.MAV_RESULT_DENIED), f"message {msg_id} not streamed"
        if msg_id == M.MAVLINK_MSG_ID_HEARTBEAT:
            return ACCEPTED, ""  # heartbeat stays at 1 Hz
        sched = self.scheduler
        if interval_us == -1:
            sched.set_rate(link, msg_id, None, self.sim_time_s)
        elif interval_us == 0 or not math.isfinite(interval_us):
            sched.set_rate(link, msg_id, sched.default_hz(msg_id), self.sim_time_s)
        else:
            sched.set_rate(link, msg_id, 1e6 / max(interval_us, 1.0), self.sim_time_s)
        return ACCEPTED, ""

    def _on_request_data_stream(self, link, msg) -> None:
        if self.is_px4 or msg.target_system not in (0, tm.SYSTEM_ID):
            return  # PX4 does not implement the deprecated REQUEST_DATA_STREAM
        streams.request_data_stream(self.scheduler, link, msg.req_stream_id, float(msg.req_message_rate),
                                    bool(msg.start_stop), self.sim_time_s)

    def _cmd_request_message(self, cmd: CommandIn, link):
        msg_id = int(cmd.p(1))
        if not self.streamable(msg_id):
            return (M.MAV_RESULT_DENIED if self.is_px4 else M.MAV_RESULT_FAILED), f"message {msg_id} not available"
        if streams.available(self, msg_id):
            queue = self._before_ack if self.is_px4 else self._after_ack
            queue.extend((link, msg) for msg in self.build_messages(msg_id, link, self.snapshot))
        return ACCEPTED, ""

    def _cmd_capabilities(self, cmd: CommandIn, link):
        self._after_ack.append((link, tm.autopilot_version(self.snapshot())))
        return ACCEPTED, ""

    def _cmd_get_home(self, cmd: CommandIn, link):
        if self.home_neu is None:
            return M.MAV_RESULT_FAILED, "home not set yet"
        self._before_ack.append((link, tm.home_position(self.snapshot())))
        return ACCEPTED, ""
