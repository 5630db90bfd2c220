"""Failsafes when the client goes quiet (PX4's offboard loss and both autopilots' GCS heartbeat loss), when the
battery runs low (``--battery-low``) and when the vehicle leaves its geofence round home.

All timers run in simulated seconds at the real parameter values (see ``scale_timeouts`` in sim/__init__.py).
Measured on the real autopilots:

PX4 offboard loss (``--strict``)
    Armed in OFFBOARD with no setpoint for COM_OF_LOSS_T (1.0 s): "Failsafe activated", then COM_OBL_RC_ACT:
    0 Position (default), 1 Altitude, 2 Manual -- without RC PX4 shows that mode and sinks at ~0.7 m/s
    (MPC_LAND_SPEED) to the ground, where it lands and disarms; 3 Return; 4 Land; 5 Hold; 6 Terminate and
    7 Disarm (the motors stop). For 0, 1, 2 and 5 the vehicle goes back to OFFBOARD by itself as soon as
    setpoints arrive again; Return and Land stay until the user selects a mode.
PX4 data link loss
    No heartbeat from a ground station (HEARTBEAT type GCS) for COM_DL_LOSS_T (10 s): "Connection to ground
    station lost", and "GCS connection regained" when one comes back; NAV_DLL_ACT (default 0: nothing) acts only
    while armed: 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Disarm.
ArduCopter GCS failsafe
    No heartbeat from system MAV_GCS_SYSID (255) for FS_GCS_TIMEOUT (5 s) while armed and flying: with the default
    FS_GCS_ENABLE = 0 nothing happens (SITL stayed GUIDED and armed at 10 m); otherwise "GCS Failsafe" and RTL
    (1, 2, 3, 6), SMART_RTL (4) or LAND (5, 7); "GCS Failsafe Cleared" when heartbeats return (the mode stays).

Low battery (the fault ``battery_low_s``)
    ArduCopter (SITL, BATT_FS_LOW_ACT 2, its battery made low in flight): "Battery 1 is low 10.00V used 177 mAh"
    and "Battery Failsafe" (both MAV_SEVERITY_WARNING), then RTL; BATT_FS_LOW_ACT 0 (the default) only warns.
    PX4 (SITL, COM_LOW_BAT_ACT 3, SIM_BAT_DRAIN 5 in OFFBOARD flight): "Low battery level" and "Failsafe
    activated" (its failsafe framework's warning; the cause goes in an EVENT), and it stayed in OFFBOARD and flew
    on: at the low level PX4 only warns, COM_LOW_BAT_ACT acts at the critical and emergency levels, which the sim
    does not reach.

Geofence round home
    ArduCopter (SITL, FENCE_ENABLE 1, FENCE_RADIUS 150, FENCE_ACTION 1, flying out in GUIDED): "Circle fence
    breached" (MAV_SEVERITY_NOTICE) and RTL at once; "Fence breach cleared" once back inside (the mode stays).
    The altitude fence (FENCE_TYPE bit 1, FENCE_ALT_MAX) is modelled the same way, "Altitude fence breached".
    PX4 (SITL, GF_MAX_HOR_DIST 60, GF_ACTION 3, flying out in OFFBOARD): "Failsafe activated" and nothing else:
    it stayed in OFFBOARD and flew on. In the other modes the sim takes GF_ACTION (PX4's documented behaviour).

ArduCopter GUIDED's own timeout (a velocity target lasts GUID_TIMEOUT) is part of the setpoint, see
:meth:`sim.autopilot.Autopilot.control_target`.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from .modes import Behaviour

M = mavlink
#: COM_OBL_RC_ACT -> (PX4 mode shown, goes back to OFFBOARD when setpoints return); None = motors stop.
OFFBOARD_LOSS_ACTIONS: dict[int, tuple[str, bool] | None] = {
    0: ("POSCTL", True), 1: ("ALTCTL", True), 2: ("MANUAL", True), 3: ("RTL", False), 4: ("LAND", False),
    5: ("LOITER", True), 6: None, 7: None,
}
#: NAV_DLL_ACT -> PX4 mode; None = motors stop.
PX4_DATALINK_ACTIONS: dict[int, str | None] = {1: "LOITER", 2: "RTL", 3: "LAND", 5: None, 6: None}
#: BATT_FS_LOW_ACT -> ArduCopter mode; None = motors stop.
ARDUPILOT_LOW_BATTERY_ACTIONS: dict[int, str | None] = {1: "LAND", 2: "RTL", 3: "SMART_RTL", 4: "SMART_RTL",
                                                        5: None}
#: FENCE_ACTION -> ArduCopter mode.
ARDUPILOT_FENCE_ACTIONS = {1: "RTL", 2: "LAND", 3: "SMART_RTL", 4: "BRAKE", 5: "SMART_RTL"}
#: GF_ACTION -> PX4 mode; None = motors stop.
PX4_FENCE_ACTIONS: dict[int, str | None] = {2: "LOITER", 3: "RTL", 4: None, 5: "LAND"}
#: FS_GCS_ENABLE -> ArduCopter mode.
ARDUPILOT_GCS_ACTIONS = {1: "RTL", 2: "RTL", 3: "RTL", 4: "SMART_RTL", 5: "LAND", 6: "RTL", 7: "LAND"}


class Failsafes:
    """Link-loss failsafes of one vehicle; :meth:`step` runs after every physics step."""

    def __init__(self, ap) -> None:
        self.ap = ap
        self.offboard_fallback: str | None = None  # the failsafe mode that gives way to OFFBOARD again
        self.gcs_heartbeat_s: float | None = None
        self.gcs_lost = False
        self.battery_low: str | None = None  # "low" from battery_low_s on, "acted" once its failsafe acted
        self.fence_breached = False
        self.position_lost = False  # the estimator's position-loss failsafe acted (until the position is back)

    # ------------------------------------------------------------------ inputs
    def on_heartbeat(self, msg) -> None:
        """Note a HEARTBEAT from a client if it counts as the ground station's."""
        ap = self.ap
        if ap.is_px4:
            counts = msg.type == M.MAV_TYPE_GCS
        else:
            counts = msg.get_srcSystem() == int(ap.params["MAV_GCS_SYSID"])
        if not counts:
            return
        self.gcs_heartbeat_s = ap.sim_time_s
        ap.recorder.last_gcs_heartbeat_sim_time_s = round(ap.sim_time_s, 3)
        if self.gcs_lost:
            self.gcs_lost = False
            text = "GCS connection regained\t" if ap.is_px4 else "GCS Failsafe Cleared"
            ap.statustext(M.MAV_SEVERITY_INFO if ap.is_px4 else M.MAV_SEVERITY_WARNING, text)
            ap.emit("failsafe", "ground station heartbeat back")

    def _failsafe_mode(self, name: str) -> None:
        """Enter a failsafe's mode; one the vehicle is already in goes on (ArduCopter's set_mode to the current
        mode changes nothing: a second GCS failsafe does not restart a return's climb)."""
        if self.ap.mode.name != name:
            self.ap.enter_mode(self.ap.personality.modes[name], user=False)

    # ------------------------------------------------------------------ per step
    def step(self) -> None:
        ap = self.ap
        if ap.is_px4 and ap.cfg.strict:
            self._offboard()
        self._gcs()
        self._battery()
        self._fence()
        self._position_loss()

    def _position_loss(self) -> None:
        """The estimator gave its position up (``--gps-loss``; see ``POSITION_LOSS_AFTER_S`` in sim/autopilot.py),
        once per loss, while flying. PX4 (measured, 1.15 SITL with no RC): "Failsafe activated", Altitude mode
        and a blind descent at MPC_LAND_SPEED, to touchdown and the landing disarm, OFFBOARD, Hold and Land refused
        meanwhile. ArduCopter (measured, 4.7 SITL): "EKF variance", "EKF Failsafe: changed to LAND Mode" ("EKF
        Failsafe" when landing already; both CRITICAL) and LAND (FS_EKF_ACTION's default), which comes down without
        a position, drifting with it."""
        ap = self.ap
        if ap.position_valid:
            self.position_lost = False
            return
        if self.position_lost or not (ap.armed and ap.airborne):
            return
        self.position_lost = True
        if ap.is_px4:
            ap.emit("failsafe", "no position estimate -> blind descent in ALTCTL")
            ap.statustext(M.MAV_SEVERITY_WARNING, "Failsafe activated\t")
            if ap.mode.behaviour != Behaviour.DESCEND:
                self._failsafe_mode("ALTCTL")
            return
        ap.emit("failsafe", "EKF variance (no GPS) -> LAND")
        ap.statustext(M.MAV_SEVERITY_CRITICAL, "EKF variance")
        landing = ap.mode.name == "LAND"
        ap.statustext(M.MAV_SEVERITY_CRITICAL, "EKF Failsafe" if landing else "EKF Failsafe: changed to LAND Mode")
        self._failsafe_mode("LAND")

    def _fence(self) -> None:
        ap = self.ap
        if ap.home_neu is None or not (ap.armed and ap.airborne):
            return
        offset = ap.position_neu - ap.home_neu
        horizontal, up = float(np.hypot(offset[0], offset[1])), float(offset[2])
        if ap.is_px4:
            radius, height = ap.params["GF_MAX_HOR_DIST"], ap.params["GF_MAX_VER_DIST"]
            which = ("horizontal" if 0 < radius < horizontal else "vertical" if 0 < height < up else None)
            action = int(ap.params["GF_ACTION"])
            on = action != 0
        else:
            kinds, action = int(ap.params["FENCE_TYPE"]), int(ap.params["FENCE_ACTION"])
            which = ("Circle" if kinds & 2 and horizontal > ap.params["FENCE_RADIUS"]
                     else "Altitude" if kinds & 1 and up > ap.params["FENCE_ALT_MAX"] else None)
            on = bool(ap.params["FENCE_ENABLE"])
        if not on:
            return
        if which is None:
            if self.fence_breached:
                self.fence_breached = False
                if not ap.is_px4:
                    ap.statustext(M.MAV_SEVERITY_NOTICE, "Fence breach cleared")
            return
        if self.fence_breached:
            return
        self.fence_breached = True
        if ap.is_px4:
            ap.emit("failsafe", f"geofence breached ({which}) -> GF_ACTION {action}")
            if action == 1:
                return
            ap.statustext(M.MAV_SEVERITY_WARNING, "Failsafe activated\t")
            if ap.mode.behaviour == Behaviour.OFFBOARD or action not in PX4_FENCE_ACTIONS:
                return  # measured: PX4 1.15 flew on in OFFBOARD
            mode_name = PX4_FENCE_ACTIONS[action]
            if mode_name is None:
                ap.cut_motors("geofence: GF_ACTION terminate")
                return
        else:
            ap.statustext(M.MAV_SEVERITY_NOTICE, f"{which} fence breached")
            ap.emit("failsafe", f"{which.lower()} fence breached -> FENCE_ACTION {action}")
            if action not in ARDUPILOT_FENCE_ACTIONS:
                return
            mode_name = ARDUPILOT_FENCE_ACTIONS[action]
        self._failsafe_mode(mode_name)

    def _battery(self) -> None:
        """From ``battery_low_s`` on the battery reads low: the autopilot warns at once, and its failsafe acts once,
        the first time the vehicle is armed and in the air (PX4's only warns at this level)."""
        ap = self.ap
        at = ap.cfg.faults.battery_low_s
        if self.battery_low == "acted" or at is None or ap.sim_time_s < at:
            return
        if not self.battery_low:
            self.battery_low = "low"
            ap.statustext(M.MAV_SEVERITY_WARNING,
                          "Low battery level\t" if ap.is_px4 else "Battery 1 is low 10.00V used 177 mAh")
        if not (ap.armed and ap.airborne):
            return
        self.battery_low = "acted"
        if ap.is_px4:
            ap.emit("failsafe", f"battery low -> warning (COM_LOW_BAT_ACT {int(ap.params['COM_LOW_BAT_ACT'])} acts "
                                "at the critical level)")
            ap.statustext(M.MAV_SEVERITY_WARNING, "Failsafe activated\t")
            return
        action = int(ap.params["BATT_FS_LOW_ACT"])
        ap.emit("failsafe", f"battery low -> BATT_FS_LOW_ACT {action}")
        if action not in ARDUPILOT_LOW_BATTERY_ACTIONS:
            return
        ap.statustext(M.MAV_SEVERITY_WARNING, "Battery Failsafe")
        mode_name = ARDUPILOT_LOW_BATTERY_ACTIONS[action]
        if mode_name is None:
            ap.cut_motors("low battery: BATT_FS_LOW_ACT terminate")
            return
        self._failsafe_mode(mode_name)

    def _offboard(self) -> None:
        ap = self.ap
        if self.offboard_fallback is not None:
            if ap.mode.name != self.offboard_fallback or not ap.armed:
                self.offboard_fallback = None
            elif ap.setpoint_fresh():
                self.offboard_fallback = None
                ap.enter_mode(ap.personality.modes["OFFBOARD"])
                ap.emit("failsafe", "offboard setpoints back -> OFFBOARD")
            return
        if not (ap.armed and ap.mode.behaviour == Behaviour.OFFBOARD) or ap.setpoint_fresh():
            return
        action = int(ap.params["COM_OBL_RC_ACT"])
        ap.statustext(M.MAV_SEVERITY_WARNING, "Failsafe activated\t")
        outcome = OFFBOARD_LOSS_ACTIONS.get(action, OFFBOARD_LOSS_ACTIONS[0])
        ap.emit("failsafe", f"offboard setpoints lost for COM_OF_LOSS_T -> COM_OBL_RC_ACT {action}")
        if outcome is None:
            ap.cut_motors("offboard loss: COM_OBL_RC_ACT terminate/disarm")
            return
        mode_name, restores = outcome
        self._failsafe_mode(mode_name)
        if restores:
            self.offboard_fallback = mode_name

    def _gcs(self) -> None:
        ap = self.ap
        if self.gcs_heartbeat_s is None or self.gcs_lost:
            return
        timeout = ap.params["COM_DL_LOSS_T"] if ap.is_px4 else ap.params["FS_GCS_TIMEOUT"]
        if ap.sim_time_s - self.gcs_heartbeat_s < timeout:
            return
        if ap.is_px4:
            self.gcs_lost = True
            ap.statustext(M.MAV_SEVERITY_CRITICAL, "Connection to ground station lost\t")
            ap.emit("failsafe", "no ground station heartbeat for COM_DL_LOSS_T")
            action = int(ap.params["NAV_DLL_ACT"])
            if ap.armed and action in PX4_DATALINK_ACTIONS:
                mode_name = PX4_DATALINK_ACTIONS[action]
                if mode_name is None:
                    ap.cut_motors("data link loss: NAV_DLL_ACT terminate/disarm")
                else:
                    self._failsafe_mode(mode_name)
            return
        action = int(ap.params["FS_GCS_ENABLE"])
        if action == 0 or not (ap.armed and ap.airborne):
            return
        self.gcs_lost = True
        ap.statustext(M.MAV_SEVERITY_WARNING, "GCS Failsafe")
        ap.emit("failsafe", f"no GCS heartbeat for FS_GCS_TIMEOUT -> FS_GCS_ENABLE {action}")
        self._failsafe_mode(ARDUPILOT_GCS_ACTIONS.get(action, "RTL"))
