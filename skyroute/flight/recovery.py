"""Riding through a lost link or a lost flight mode in the air (a mixin of :class:`~.mission.Mission`).

While the link is down the autopilot's failsafe owns the vehicle (PX4 holds or lands after COM_OF_LOSS_T,
ArduCopter's GCS failsafe if enabled; the sender keeps re-sending our last setpoint without its feed-forward).
When the link comes back within ``link_lost_timeout_s`` the mission reads the vehicle's real state: landed and
disarmed -> say so and stop (never take off again on our own); after a failsafe the autopilot names as its own
(ArduCopter's "Battery Failsafe", a geofence, the estimator), in a return or landing nothing on our side explains,
or in a pilot's mode (manual, position, altitude) that no failsafe explains -> hand over; otherwise take our flight
mode back (bounded retries) and fly on from where the vehicle is, replanning if it is more than
``resume_off_path_m`` off the path. The same judgement applies to a mode change while the link is up.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from .errors import ControlTakenOver, LandedMeanwhile, LinkLostInFlight
from .path import leg_headings, smooth_path
from .states import MissionEvent as E
from .states import MissionState as S

log = logging.getLogger(__name__)

#: After an outage, wait up to this long (s) for a heartbeat sent after the link came back (autopilots send 1 Hz).
FRESH_HEARTBEAT_WAIT_S = 1.5


class _Abort(Exception):
    """Internal: a timeout or refusal during flight that must end in a landing."""


class _Resumed(Exception):
    """Internal: control was taken back after an outage or a lost mode: fly on from where the vehicle is."""


class RecoveryMixin:
    """The mission's RECOVERING state; uses the mission's vehicle, clock, sleep, progress and settings."""

    def _link_lost(self) -> None:
        if self.state is S.LANDING:
            self._fire(E.LINK_LOST)
            self._wait_for_link("the link was lost while landing")
            return
        if self.state in (S.TAKEOFF, S.WAYPOINT, S.REPLANNING):
            self._recover("the link was lost", link_lost=True)  # raises _Resumed unless landing over the goal
            return
        self._wait_for_link(f"the link was lost in state {self.state.name}")

    def _wait_for_link(self, why: str) -> None:
        """Wait up to ``link_lost_timeout_s`` for the link (the autopilot's failsafe owns the vehicle meanwhile)."""
        self._say(f"{why}: the autopilot's failsafe has the vehicle; waiting up to {self.link_lost_timeout_s:g} s "
                  "for the link")
        deadline = self.clock() + self.link_lost_timeout_s
        while not self.vehicle.link_ok:
            if self.clock() >= deadline:
                state = self.state
                self._fire(E.LINK_TIMEOUT if state in (S.RECOVERING, S.LANDING) else E.LINK_LOST)
                raise LinkLostInFlight(f"{why} (state {state.name}) and stayed lost for {self.link_lost_timeout_s:g} "
                                       "s; the autopilot's failsafe now owns the vehicle")
            self.sleep(self.poll_s)
        self._say("the link is back")
        back_s = self.clock()
        if self.state is S.RECOVERING:
            self._hold_where_seen(back_s)
        self.sleep(max(self.poll_s, 0.3))  # let a position in after the outage
        # the mode and the armed state come with heartbeats (1 Hz): judge them from one sent after the outage
        while (getattr(self.vehicle.telemetry, "last_heartbeat_s", math.inf) < back_s
               and self.clock() < back_s + FRESH_HEARTBEAT_WAIT_S):
            self.sleep(self.poll_s)

    def _recover(self, why: str, *, link_lost: bool, retake: bool = False) -> None:
        """RECOVERING: wait for the link, read the vehicle's real state, take control back; raises _Resumed. A
        landing the autopilot began over the goal while the link was down (coming down there, a failsafe's LAND)
        is the landing: back to WAYPOINT without taking control, the descent's loop hands over to it."""
        self._fire(E.LINK_LOST if link_lost else E.CONTROL_LOST)
        self.result.recoveries += 1
        log.warning("%s in flight; recovering", why)
        if link_lost:
            self._wait_for_link(why)
        else:
            self._say(why)
        self._unless_landed_meanwhile(why)
        if self._landing_over_goal():  # its failsafe landed it where we were bringing it down: the landing
            self._fire(E.RESUMED)
            self._say(f"{why}: meanwhile the autopilot began landing over the goal by itself; that is the landing")
            return
        kind = getattr(self.vehicle.mode_kind(), "value", "other")
        if kind != "ours":
            self._hand_over_unless_ours(kind, link_lost)
        if self.result.recoveries > self.max_recoveries:
            self._fire(E.ABORT)
            raise _Abort(f"{why}: control lost {self.result.recoveries} times, giving up")
        if not self.vehicle.in_control or retake:
            self._take_control(why)
        self._fire(E.RESUMED)
        self._say("control taken back: flying on from where the vehicle is")
        raise _Resumed()

    def _hold_where_seen(self, back_s: float) -> None:
        """The link back (at ``back_s``, our clock): as soon as a position from after the outage is in, re-send a
        hold there, at the flight altitude, in place of the last setpoint. That setpoint was reckoned from telemetry
        the outage had already frozen, and the link re-sends it: it pulled an ArduPilot vehicle 8 m back to where
        it was last seen until the mission flew on, and the turn onto the route from there passed a building's
        corner at 2.7 m (a fault campaign's 3 s outage, a 5 m margin). The stream itself goes on through the
        outage: PX4 returns to OFFBOARD the moment setpoints come back."""
        vehicle = self.vehicle
        if not getattr(vehicle, "streaming", True) or not vehicle.telemetry.armed:
            return
        deadline = back_s + 1.0
        while getattr(vehicle.telemetry, "local_rx_s", math.inf) < back_s and self.clock() < deadline:
            self.sleep(0.02)
        p = self._map_position()
        # at the flight altitude, or where it is on the way down over the goal (the descent goes on from there)
        altitude_m = p.altitude_m if self._coming_down else max(p.altitude_m, self.altitude_m)
        target = self._to_local(p.north_m, p.east_m, altitude_m)
        heading = float(getattr(vehicle.telemetry, "heading_rad", 0.0) or 0.0)
        try:
            vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading, velocity_ned=None)
        except self.vehicle_errors as exc:
            log.warning("holding where the vehicle is after the outage failed: %s", exc)

    def _hand_over_unless_ours(self, kind: str, link_lost: bool) -> None:
        """Raise ControlTakenOver (after releasing the vehicle) unless the mode the vehicle is in is ours to take
        back, i.e. a failsafe on our side put it there. Not ours: a failsafe the autopilot names as its own
        (battery, geofence, ...: it chose to return, land or hold; taking control back would fly on against it),
        a return or a landing nothing on our side explains (an operator's or the autopilot's choice; PX4 announces
        its geofence failsafe only as "Failsafe activated"), a pilot's mode nothing explains."""
        t = self.vehicle.telemetry
        own = self.vehicle.own_failsafe()
        if own is not None:
            reason = f"the autopilot's own failsafe put the vehicle in {t.mode} (it said {own!r})"
        elif link_lost:
            return  # our link was silent: its link-loss failsafe
        elif kind == "return" and self.vehicle.failsafe_hint(texts=False) is None:
            reason = (f"the vehicle went to {t.mode} and nothing on our side explains it (an operator or the "
                      "autopilot's own failsafe sent it home or down)")
        elif kind == "pilot" and (explained := self.vehicle.failsafe_hint()) is None:
            if self._back_by_itself():
                log.warning("the autopilot went back to our mode from %s by itself: a failsafe's fallback (its text "
                            "lost), not a pilot", t.mode)
                return
            reason = f"a pilot took over: the vehicle is in {t.mode}, a mode we never select"
        else:
            if kind == "pilot":
                log.warning("the autopilot is in %s after a failsafe (%s); taking control back", t.mode, explained)
            return
        self._fire(E.TAKEN_OVER)
        self._release()
        reason += "; handed over, not taking control back"
        if kind == "return":  # the autopilot brings it down: follow it there, so the log says how it ended
            self._say(f"{reason}: following it down")
            reason += f"; {self._follow_down()}"
        raise ControlTakenOver(reason)

    def _back_by_itself(self) -> bool:
        """Whether the vehicle returns to our mode within ``pilot_grace_s`` while our setpoints keep streaming.

        PX4 leaves its offboard-loss fallback (position, altitude, manual or hold mode) for OFFBOARD as soon as
        setpoints arrive again; when its "Failsafe activated" was lost (a short outage), that is the only sign the
        fallback was no pilot's. A pilot's mode stays. Its heartbeat says the mode once a second."""
        deadline = self.clock() + self.pilot_grace_s
        while self.clock() < deadline and self.vehicle.link_ok:
            if self.vehicle.in_control:
                return True
            self.sleep(self.poll_s)
            self._sample()
        return self.vehicle.in_control

    def _follow_down(self, disarm_wait_s: float = 15.0) -> str:
        """After handing the vehicle over to a return or landing of the autopilot's: record the track until it is
        on the ground and disarmed (the autopilot disarms after touchdown: ArduCopter at once, PX4 after
        COM_DISARM_LAND), the link is lost, or ``handover_watch_s`` has passed; say which."""
        deadline = self.clock() + self.handover_watch_s
        landed_s = math.inf
        while self.clock() < deadline:
            self.sleep(self.poll_s)
            if not self.vehicle.link_ok:
                return "then the link was lost (the autopilot has the vehicle)"
            self._sample()
            t = self.vehicle.telemetry
            if t.on_ground:
                landed_s = min(landed_s, self.clock())
                if not t.armed or self.clock() - landed_s >= disarm_wait_s:
                    self._sample(force=True)
                    p = self._map_position()
                    return (f"it landed at map ({p.north_m:.1f} N, {p.east_m:.1f} E)"
                            f"{' and disarmed' if not t.armed else ', still armed'}")
            else:
                landed_s = math.inf
        mode = self.vehicle.telemetry.mode
        return f"still in the air in {mode} after {self.handover_watch_s:g} s (the autopilot has it)"

    def _no_fix_hint(self) -> str:
        """Why an autopilot may refuse every mode we ask for: its GPS has no fix (GPS_RAW_INT below 3D), so its
        estimator has, or soon will have, no position; "" when it has one or never said."""
        fix = int(getattr(self.vehicle.telemetry, "gps_fix_type", -1))
        if 0 <= fix < 3:
            return (f" (the GPS reports no 3D fix, fix type {fix}: without a position the autopilot refuses the "
                    "modes that need one)")
        return ""

    def _unless_landed_meanwhile(self, why: str) -> None:
        """Raise LandedMeanwhile if the vehicle stands disarmed on the ground (a failsafe landed it), or
        VehicleDisarmedInFlight if it disarmed in the air."""
        t = self.vehicle.telemetry
        if t.armed:
            return
        if t.on_ground:
            self._fire(E.LANDED_MEANWHILE)
            self._release()
            p = self._map_position()
            raise LandedMeanwhile(f"{why}; meanwhile the vehicle landed and disarmed at map ({p.north_m:.1f} N, "
                                  f"{p.east_m:.1f} E): not taking off again on our own")
        self._check_armed(why)

    def _take_control(self, why: str) -> None:
        for attempt in range(1, self.control_retries + 1):
            if attempt > 1:  # a failsafe refusing our mode may be landing it meanwhile (PX4 without a position)
                self._sample()
                self._unless_landed_meanwhile(why)
            try:
                self.vehicle.take_control()
                self._sample()
                self._unless_landed_meanwhile(why)  # a disarmed PX4 takes OFFBOARD again: that is no control
                return
            except self.vehicle_errors as exc:
                log.warning("taking control back failed (attempt %d/%d): %s", attempt, self.control_retries, exc)
                if attempt == self.control_retries:
                    self._fire(E.ABORT)
                    raise _Abort(f"{why}; could not take control back: {exc}{self._no_fix_hint()}") from exc
                self.sleep(0.5)

    def _resume_path(self, waypoints: np.ndarray) -> np.ndarray:
        """The path to fly on with: the same one if the vehicle is near it, else a new plan from where it is."""
        p = self._map_position()
        s = self.speeds
        path = smooth_path(waypoints, corner_cut_m=self.corner_cut_m, cruise_mps=s.cruise_mps)
        s_now = path.project((p.north_m, p.east_m, p.altitude_m), self._progress_s)
        off_m = math.dist(path.point_at(s_now)[0], (p.north_m, p.east_m, p.altitude_m))
        if off_m <= self.resume_off_path_m:
            log.info("resuming on the path (%.1f m off it)", off_m)
            self._progress_s = s_now
            return waypoints
        self._say(f"the vehicle is {off_m:.1f} m off the path: replanning from where it is")
        try:
            new = np.array(self.plan_fn(p.north_m, p.east_m), dtype=float).reshape(-1, 4)
        except Exception as exc:  # a planner that cannot plan from here: land where we are
            raise _Abort(f"replanning from ({p.north_m:.1f} N, {p.east_m:.1f} E) failed: {exc}") from exc
        if len(new) == 0:
            raise _Abort("replanning returned no waypoints")
        new[np.isnan(new[:, 2]), 2] = self.altitude_m
        here = np.array([[p.north_m, p.east_m, p.altitude_m, 0.0]])
        if p.altitude_m < new[0, 2] - self.altitude_tolerance_m:  # below the flight altitude: climb first
            here = np.vstack([here, [p.north_m, p.east_m, new[0, 2], 0.0]])
        elif p.altitude_m > new[0, 2] + self.altitude_tolerance_m \
                and math.dist(new[0, :2], (p.north_m, p.east_m)) > 0.5:
            # Above it (an autopilot's return climbs to its RTL altitude, over roofs lower than that): the plan
            # starts at the nearest point free at the flight altitude; get over it at this height, then descend
            # straight down. Descending on the way there cut down into the roof the vehicle was over.
            here = np.vstack([here, [new[0, 0], new[0, 1], p.altitude_m, 0.0]])
        path_wps = np.vstack([here, new])
        path_wps[:, 3] = leg_headings(path_wps)
        self._progress_s = 0.0
        return path_wps

