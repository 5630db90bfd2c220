"""What the vehicle flies in each mode: the controller target of a task, and when a task moves on.

Mixed into :class:`sim.autopilot.Autopilot` (relies on its attributes). Targets are in the map frame.

* OFFBOARD (PX4 OFFBOARD, ArduCopter GUIDED): the last setpoint. PX4 holds the setpoint's position with its
  velocity as feed-forward; ArduCopter moves the position target along the velocity for GUID_TIMEOUT after the
  setpoint arrived, then stops it (measured on SITL: 10 m ahead at 2 m/s ended 16 m out).
* HOLD / TAKEOFF: a fixed position. TAKEOFF ends within 0.1 m of its altitude: PX4 switches to Hold, ArduCopter
  stays in its mode (GUIDED then waits for setpoints).
* LAND / DESCEND: hold north/east, sink at the land speed (DESCEND: PX4's manual modes without RC).
* RTL: climb to the return altitude, fly home, land.
"""

from __future__ import annotations

import math

from .dynamics import ControlTarget
from .modes import Behaviour, Task

NAN = math.nan


class TaskControl:
    """Controller targets of the flight tasks; relies on the attributes of :class:`Autopilot`."""

    def _guided_target(self) -> ControlTarget:
        """ArduCopter GUIDED: a velocity (feed-forward) moves the target along for GUID_TIMEOUT, then it stops."""
        sp = self.setpoint
        age = self.sim_time_s - self.setpoint_s
        horizon = max(0.0, self.params["GUID_TIMEOUT"])
        moving = age < horizon
        pos, vel = list(sp.position_neu), list(sp.velocity_neu)
        for axis in range(3):
            if math.isfinite(vel[axis]):
                if math.isfinite(pos[axis]):
                    pos[axis] += vel[axis] * min(age, horizon)
                vel[axis] = vel[axis] if moving else 0.0
        return ControlTarget(tuple(pos), tuple(vel), sp.yaw_rad, sp.yaw_rate_rad_s, sp.max_horizontal_speed_m_s,
                             sp.max_descent_m_s)

    def control_target(self) -> ControlTarget:
        """Controller target for the current task (map frame)."""
        task, pos = self.task, self.position_neu
        speed = self.speed_limit_m_s
        if task.kind == Behaviour.OFFBOARD:
            if self.following and self.setpoint is not None and (self.is_px4 or self.airborne):
                sp = self.setpoint if self.is_px4 else self._guided_target()
                if math.isfinite(speed):
                    sp = ControlTarget(sp.position_neu, sp.velocity_neu, sp.yaw_rad, sp.yaw_rate_rad_s, speed,
                                       sp.max_descent_m_s, sp.accel_neu)
                return sp
            return ControlTarget(tuple(task.position_neu), max_horizontal_speed_m_s=speed)
        if task.kind in (Behaviour.HOLD, Behaviour.TAKEOFF):
            return ControlTarget(tuple(task.position_neu), max_horizontal_speed_m_s=speed)
        land = self._land_speed()
        if task.kind in (Behaviour.LAND, Behaviour.DESCEND):
            n, e = task.position_neu[:2]
            if not self.airborne and task.kind == Behaviour.DESCEND:
                return ControlTarget(tuple(pos))
            return ControlTarget((n, e, NAN), (NAN, NAN, -land), max_horizontal_speed_m_s=speed,
                                 max_descent_m_s=land)
        # RTL
        home = self.home_neu if self.home_neu is not None else self.boot_neu
        rtl_height = self.params["RTL_RETURN_ALT"] if self.is_px4 else self.params["RTL_ALT"] / 100.0
        rtl_up = max(home[2] + rtl_height, task.position_neu[2])
        if task.phase == 0:
            if not self.airborne:
                return ControlTarget(tuple(pos))
            return ControlTarget((task.position_neu[0], task.position_neu[1], rtl_up))
        if task.phase == 1:
            return ControlTarget((home[0], home[1], rtl_up), max_horizontal_speed_m_s=speed)
        return ControlTarget((home[0], home[1], NAN), (NAN, NAN, -land), max_descent_m_s=land)

    def _advance_task(self) -> None:
        task, pos = self.task, self.position_neu
        if task.kind == Behaviour.TAKEOFF and self.airborne and abs(pos[2] - task.position_neu[2]) < 0.1:
            home_up = self.home_neu[2] if self.home_neu is not None else 0.0
            self.emit("takeoff", f"takeoff complete at {pos[2] - home_up:.1f} m above home")
            if self.is_px4:
                self.enter_mode(self.personality.mode_for(Behaviour.HOLD), Task(Behaviour.HOLD, task.position_neu))
            elif self.mode.behaviour == Behaviour.OFFBOARD:
                self.task = Task(Behaviour.OFFBOARD, task.position_neu.copy())
                self.following = False
            else:
                self.task = Task(Behaviour.HOLD, task.position_neu.copy())
        elif task.kind == Behaviour.RTL and self.airborne:
            rtl_target = self.control_target().position_neu
            if task.phase == 0 and pos[2] >= rtl_target[2] - 0.3:
                task.phase = 1
            elif task.phase == 1 and math.hypot(*(pos[:2] - self.control_target().position_neu[:2])) < 0.5:
                task.phase = 2
