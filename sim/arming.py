"""Who may arm when, the land detector, and when the vehicle disarms itself.

Everything is in simulated seconds and was measured on the real autopilots (ArduCopter SITL V4.7.0-dev, PX4
v1.15.4 SIH):

Arming refusals
    ArduCopter answers FAILED with one "Arm: <reason>" STATUSTEXT: "Arm: AHRS: waiting for home" before the EKF
    origin, "Arm: Need Position Estimate" until the EKF uses GPS, then the mode's refusal ("Arm: LAND mode not
    armable"). While not ready it also broadcasts "PreArm: <reason>" every 30 s. PX4 answers
    TEMPORARILY_REJECTED with "Arming denied: Resolve system health failures first" (two 50-byte STATUSTEXT
    chunks; its detailed reasons are EVENT messages, which the sim does not send).
Land detector
    After touchdown the landed state turns ON_GROUND once the detector is sure: ArduCopter ~1.7 s, PX4 ~1 s.
Auto-disarm
    ArduCopter: in LAND (and RTL's landing) it disarms as soon as it has landed ("Disarming motors", ~0.4 s after
    ON_GROUND); otherwise, armed on the ground (never took off, or landed) for DISARM_DELAY (10 s). PX4: armed
    without taking off for COM_DISARM_PRFLT (10 s): "Disarmed by auto preflight disarming"; landed for
    COM_DISARM_LAND (2 s): "Disarmed by landing". After a disarm PX4 returns to the last mode the user selected
    that does not prevent arming (after a mission flown in OFFBOARD and a NAV_LAND: OFFBOARD again).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from .modes import PX4_ARMING_DENIED, Behaviour

M = mavlink
#: Touchdown to landed state ON_GROUND (simulated s).
LAND_DETECT_S = {"ardupilot": 1.7, "px4": 1.0}
#: ArduCopter LAND mode: ON_GROUND to the disarm.
ARDUPILOT_LAND_DISARM_S = 0.4
#: ArduCopter repeats its failing pre-arm check this often while disarmed and not ready (simulated s).
PREARM_REPORT_PERIOD_S = 30.0


def readiness_reason(ap) -> str:
    """Why the vehicle is not ready to arm, in the autopilot's words; "" when it is."""
    t = ap.sim_time_s
    if t >= ap.boot.armable_s and ap.home_neu is not None and ap.gps_lost_since is None:
        return ""
    if ap.is_px4:
        return PX4_ARMING_DENIED
    if ap.home_neu is None:
        return "AHRS: waiting for home"
    return "Need Position Estimate"


def arm_refusal(ap, force: bool) -> tuple[int, str] | None:
    """``(MAV_RESULT, text)`` if an arm request must be refused now, else None.

    ``force`` (param2 = 21196) skips the pre-arm and mode checks, as on both autopilots.
    """
    if ap.crashed:
        return M.MAV_RESULT_DENIED, "arming denied: vehicle crashed"
    if force:
        return None
    reason = readiness_reason(ap)
    if ap.is_px4:
        offboard_dry = (ap.mode.behaviour == Behaviour.OFFBOARD and ap.cfg.strict
                        and not ap.setpoint_fresh())
        if reason or not ap.mode.armable or offboard_dry:
            return M.MAV_RESULT_TEMPORARILY_REJECTED, PX4_ARMING_DENIED
        return None
    if reason:
        return M.MAV_RESULT_FAILED, f"Arm: {reason}"
    if not ap.mode.armable:
        return M.MAV_RESULT_FAILED, ap.mode.arm_refusal
    return None


class GroundLogic:
    """Land detector and auto-disarm of one vehicle; :meth:`step` runs after every physics step."""

    def __init__(self, ap) -> None:
        self.ap = ap
        self.flew_since_arming = False
        self.armed_at_s = 0.0
        self.touchdown_s: float | None = None
        #: When the land detector declared the vehicle landed (None while flying or not yet sure).
        self.landed_at_s: float | None = 0.0
        self._next_prearm_report_s = PREARM_REPORT_PERIOD_S

    @property
    def landed(self) -> bool:
        """The land detector's verdict (what EXTENDED_SYS_STATE reports as ON_GROUND)."""
        return self.landed_at_s is not None

    def on_arm(self) -> None:
        self.flew_since_arming = False
        self.armed_at_s = self.ap.sim_time_s

    def on_touchdown(self) -> None:
        self.touchdown_s = self.ap.sim_time_s

    def step(self) -> None:
        ap = self.ap
        t = ap.sim_time_s
        if ap.airborne:
            self.flew_since_arming = self.flew_since_arming or ap.armed
            self.touchdown_s = None
            self.landed_at_s = None
        elif self.landed_at_s is None:
            if self.touchdown_s is None:
                self.touchdown_s = t
            if t - self.touchdown_s >= LAND_DETECT_S[ap.personality.name] - 1e-9:
                self.landed_at_s = t
                if ap.is_px4:
                    ap.statustext(M.MAV_SEVERITY_INFO, "Landing detected\t")
        if ap.armed:
            self._auto_disarm(t)
        else:
            self._report_prearm(t)

    def _auto_disarm(self, t: float) -> None:
        ap = self.ap
        if not self.landed:
            return
        p = ap.params
        if ap.is_px4:
            if not self.flew_since_arming:
                delay = p["COM_DISARM_PRFLT"]
                if delay > 0 and t - self.armed_at_s >= delay - 1e-9:
                    ap.disarm("auto preflight disarm", "Disarmed by auto preflight disarming\t")
            else:
                delay = p["COM_DISARM_LAND"]
                if delay >= 0 and t - self.landed_at_s >= delay - 1e-9:
                    ap.disarm("landed", "Disarmed by landing\t")
            return
        landing_mode = ap.task.kind == Behaviour.LAND or (ap.task.kind == Behaviour.RTL and ap.task.phase == 2)
        if landing_mode:
            if t - self.landed_at_s >= ARDUPILOT_LAND_DISARM_S - 1e-9:
                ap.disarm("landed", "Disarming motors")
            return
        delay = p["DISARM_DELAY"]
        since = max(self.armed_at_s, self.landed_at_s)
        if delay > 0 and t - since >= delay - 1e-9:
            ap.disarm("DISARM_DELAY", "Disarming motors")

    def _report_prearm(self, t: float) -> None:
        ap = self.ap
        if ap.is_px4 or t < self._next_prearm_report_s:
            return
        self._next_prearm_report_s = t + PREARM_REPORT_PERIOD_S
        reason = readiness_reason(ap)
        if reason:
            ap.statustext(M.MAV_SEVERITY_CRITICAL, f"PreArm: {reason}")
