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
from .recovery import _Abort
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
                    return (f"could not land ({exc}) nor hold ({hold_exc}); "
                            "the autopilot's failsafe owns the vehicle")
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
