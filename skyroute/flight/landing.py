"""Landing, disarming, and making the vehicle safe after a failure (a mixin of :class:`~.mission.Mission`).

Any failure after the takeoff command lands the vehicle where it is (or holds it, if landing cannot be
commanded); on the ground an armed vehicle is disarmed. A vehicle that disarmed in the air is not commanded any
more, and a lost link that stays lost leaves it to the autopilot's failsafe; both are reported, never called a
landing.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from .errors import LinkLostInFlight, MissionError, VehicleDisarmedInFlight
from .path import path_length_m
from .recovery import _Abort, _Resumed
from .states import MissionEvent as E
from .states import MissionState as S

log = logging.getLogger(__name__)


class LandingMixin:
    """The mission's LANDING and DISARMING states; uses the mission's vehicle, clock, sleep and result."""

    def _land(self) -> None:
        """Land here, wait for touchdown, disarm, release control (LANDING -> DISARMING -> MANUAL)."""
        self.vehicle.land()
        self._land_commanded = True
        self._await_touchdown()

    def _come_down(self, north_m: float, east_m: float) -> None:
        """Descend over the map point to ``handover_m`` above the map's surface there under our own setpoints,
        holding the point with the hover trim (:meth:`~.mission.Mission._trim`), so that the autopilot's landing
        that follows has little left to fly. The end of the last leg (WAYPOINT): a link or a mode lost on the way
        down is recovered as anywhere in flight.

        An autopilot's landing holds the position it had when told to land, less tightly than its position loop
        holds a setpoint: PX4 SIH wandered 0.5 m off its landing point over a 5 m descent and touched down up to
        1.2 m from the goal it had been brought to within 0.3 m of (measured). From 1.5 m its landing is a short
        descent. The setpoint comes down at ``vertical_mps``, at most 1 m/s: a firm touchdown at worst, should the
        altitude estimate read high (a booting PX4's drifted 2.6 m over one flight, measured, though the other way).

        The hand-over comes once the vehicle is at that height (within 0.3 m) and over the point
        (:meth:`~.mission.Mission._at_goal`); at once if it is on the ground or has stopped coming down while told
        to for a second and the link's round trip (something below, or an estimate that reads high); at the latest
        after the descent's time plus twice ``settle_s`` (autopilot seconds), wherever the vehicle is. A LAND the
        autopilot switches to by itself on the way down (a failsafe's) is the landing (:meth:`_landing_over_goal`).
        """
        surface = 0.0 if self.surface_fn is None else float(self.surface_fn(north_m, east_m))
        floor = surface + self.handover_m
        start = self._map_position().altitude_m
        if self.handover_m <= 0 or start - floor < 0.5:
            return
        speed = min(self.speeds.vertical_mps, 1.0)
        rate = self._autopilot_rate()
        limit_s = (start - floor) / speed + 2.0 * self.settle_s
        # a vehicle told to come down starts to only after the link's round trip (autopilot seconds)
        stall_s = 1.0 + rate * float(getattr(self.vehicle, "round_trip_s", 0.0) or 0.0)
        heading = self._heading_rad
        if not math.isfinite(heading):  # no leg flown yet: the heading it has, north if it reports none
            heading = float(getattr(self.vehicle.telemetry, "heading_rad", math.nan))
            heading = heading if math.isfinite(heading) else 0.0
        self._near_goal_since = stalled_at = math.nan
        log.info("coming down over (%.1f N, %.1f E) to %.1f m before landing", north_m, east_m, floor)
        began = trim_at = self.clock()
        self._coming_down, self._descent_point = True, (north_m, east_m)
        interrupted = False
        try:
            while True:
                now = self.clock()
                elapsed = rate * (now - began)
                carrot_m = max(floor, start - speed * elapsed)
                t = self.vehicle.telemetry
                # heights as flown (the keep-off's lift is not sent: coming down is the point), the horizontal
                # relative to the route as the keep-off shifted it
                self._sense_coming_down(self._map_position())  # may move the fix's correction: read p after
                p = self._map_position()
                q = self._unshifted(p)
                off_m = math.hypot(q.north_m - north_m, q.east_m - east_m)
                if carrot_m == floor and abs(p.altitude_m - floor) <= 0.3 \
                        and self._at_goal(np.array([north_m, east_m, floor + q.altitude_m - p.altitude_m])):
                    return
                if p.altitude_m - carrot_m < 0.5 or t.local_v_down_mps > 0.1:  # where told, or coming down
                    stalled_at = math.nan
                elif math.isnan(stalled_at):
                    stalled_at = elapsed
                why = ("the autopilot is landing by itself" if self._landing_over_goal() else
                       "it is on the ground" if t.on_ground else
                       "it stopped coming down" if elapsed - stalled_at >= stall_s else
                       "not settled in time" if elapsed > limit_s else "")
                if why:
                    log.info("%s %.1f s into the descent, %.2f m off the landing point, %.1f m above the map's "
                             "surface: landing from there", why, elapsed, off_m, p.altitude_m - surface)
                    return
                position = self._trim(np.array([north_m, east_m, carrot_m]), q, t, rate * (now - trim_at))
                trim_at = now
                if self.keep_off is not None:
                    position[:2] += self.keep_off.shift_ne
                target = self._to_local(*position)
                self.vehicle.goto_local(target.north_m, target.east_m, target.down_m, heading)
                self._tick()
        except _Resumed:
            interrupted = True  # control taken back on the way down: :meth:`_finish_descent` goes on from there
            raise
        finally:
            self._coming_down = False
            if not interrupted:
                self._descent_point = None

    def _descent_resumable(self) -> bool:
        """After control was taken back (a lost link or mode, :class:`~.recovery._Resumed`): whether a descent over
        the goal was interrupted and the vehicle is still within ``resume_off_path_m`` of its point, so that
        :meth:`_finish_descent` comes on down from where it is. Otherwise the interrupted descent is forgotten and
        the path is flown again (:meth:`~.recovery.RecoveryMixin._resume_path`), which from below the flight
        altitude climbs back to it before coming down once more."""
        point = self._descent_point
        if point is None:
            return False
        q = self._unshifted(self._map_position())
        off_m = math.hypot(q.north_m - point[0], q.east_m - point[1])
        if off_m > self.resume_off_path_m:
            log.info("%.1f m off the landing point after control was taken back: flying the path again", off_m)
            self._descent_point = None
            return False
        log.info("coming on down over the landing point from %.1f m (%.1f m off it)", q.altitude_m, off_m)
        return True

    def _finish_descent(self) -> None:
        """Come on down over the interrupted descent's point (:meth:`_descent_resumable`); the goal is reached."""
        self._come_down(*self._descent_point)
        self._fire(E.GOAL_REACHED)

    def _landing_over_goal(self) -> bool:
        """The autopilot switched to its own landing (a failsafe's: a low battery, a lost link) while we were
        coming down over the goal (:meth:`_come_down`): that is the landing, not a mode to take back or hand over."""
        return self._coming_down and self.vehicle.telemetry.mode == "LAND"

    def _await_touchdown(self) -> None:
        deadline = self.clock() + self.landing_timeout_s
        self._check_armed()
        while not self.vehicle.telemetry.on_ground:  # an autopilot that auto-disarms on touchdown says so too
            if self.clock() > deadline:
                raise _Abort(f"no touchdown within {self.landing_timeout_s:g} s of the land command")
            self._tick()
        self._sample(force=True)
        r = self.result
        now_autopilot = self._autopilot_time_s()
        r.flight_time_s = now_autopilot - self._takeoff_autopilot_s
        r.airborne_s = now_autopilot - self._liftoff_autopilot_s
        if not math.isfinite(r.flight_time_s):  # no autopilot clock: our own
            r.flight_time_s = r.airborne_s = self.clock() - self._takeoff_s
        elif not math.isfinite(r.airborne_s):  # liftoff unseen (it came while a lost takeoff ACK was retried)
            r.airborne_s = r.flight_time_s
        r.flown_length_m = path_length_m(np.array(self._track)[:, 1:])
        p = self._map_position()
        goal = self.goal_ne if self.goal_ne is not None else (tuple(r.waypoints[-1, :2]) if len(r.waypoints) else None)
        if goal is not None:
            r.landing_error_m = math.hypot(p.north_m - goal[0], p.east_m - goal[1])
        log.info("landed; %s", r.summary())
        self._fire(E.LANDED)
        self._disarm()
        self.vehicle.release_control()
        self._fire(E.DISARMED)

    def _make_safe(self, why: str) -> str:
        """After a failure or Ctrl-C: land if flying (hold if landing fails), disarm if armed on the ground.

        Returns what was done, for the error message. Raises only MissionErrors that say the vehicle is not safe
        (LinkLostInFlight, VehicleDisarmedInFlight), with ``why`` in the message.
        """
        if self.state is S.MANUAL:
            return "nothing to undo: the vehicle is disarmed and not under our control"
        if self.state is S.HANDED_OVER:
            return "the vehicle was handed over (to its pilot, or the autopilot's own failsafe)"
        if self.state is S.FAILED:
            return ("the mission had already failed (link lost, landing or disarming failed, or the vehicle disarmed "
                    "in flight): it may still be in the air, the autopilot's failsafe owns it")
        if self.state in (S.PREFLIGHT, S.PLANNING):
            self._release()
            self._fire(E.ABORT)
            return "the vehicle is on the ground, never armed"
        if self.state in (S.ARMING, S.DISARMING):
            self._release()
            if self.state is S.ARMING:
                self._fire(E.ABORT)
            try:
                self._disarm()
                self._fire(E.DISARMED)
            except (MissionError, *self.vehicle_errors) as exc:
                return f"could not disarm: {exc}"
            return "disarmed on the ground" if math.isnan(self._takeoff_s) else "landed and disarmed"
        self._check_armed(why)  # a disarmed vehicle cannot be landed
        if self.state is not S.LANDING:
            self._fire(E.ABORT)
        log.warning("%s: landing where we are", why)
        if not self._land_commanded:
            try:
                self.vehicle.land()
                self._land_commanded = True
            except self.vehicle_errors as exc:
                log.error("could not land (%s); holding", exc)
                self._fire(E.LAND_FAILED)
                try:
                    self.vehicle.hold()
                except self.vehicle_errors as hold_exc:
                    # Refused both: the autopilot's failsafe flies it (PX4 without a position lands blind in
                    # ALTCTL and refuses every mode that needs one). Watch it down, so we can say how it ended.
                    said = (f"could not land ({exc}) nor hold ({hold_exc}); "
                            "the autopilot's failsafe owns the vehicle")
                    self._say(f"{said}: following it down")
                    return f"{said}; {self._follow_down()}"
                return f"could not land ({exc}); holding position"
        try:
            self._await_touchdown()
        except _Abort as exc:
            self._fire(E.LAND_FAILED)
            return f"landing commanded but not confirmed ({exc}); the autopilot is landing"
        except LinkLostInFlight as exc:  # not landed: the autopilot's failsafe has it
            raise LinkLostInFlight(f"{why}; landing commanded, then {exc}") from exc
        except VehicleDisarmedInFlight as exc:
            raise VehicleDisarmedInFlight(exc.state, exc.position, exc.on_ground, f"{why}; landing") from exc
        except (MissionError, *self.vehicle_errors) as exc:  # touchdown confirmed: disarm or release failed
            return f"landed, then {exc}"
        p = self._map_position()
        return f"landed at ({p.north_m:.1f} N, {p.east_m:.1f} E) and disarmed"
