"""Flying the vehicle: :class:`MavlinkVehicle`, the flight actions the mission calls, over :class:`MavlinkLink`.

Part of the ``vehicle`` package. The mission's order on a real autopilot: wait for :meth:`~MavlinkVehicle.readiness`,
plan, :meth:`~MavlinkVehicle.prepare_flight` (our flight mode, which the vehicle can be armed in: a vehicle left
in LAND by a previous mission cannot), :meth:`~MavlinkVehicle.arm`, :meth:`~MavlinkVehicle.takeoff` at once (an
idle armed vehicle disarms itself after ~10 s: ArduCopter DISARM_DELAY, PX4 COM_DISARM_PRFLT), then setpoints.
"""

from __future__ import annotations

import logging
import math
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute.frames import Geodetic, LocalNED

from . import limits as limits_mod
from .errors import CommandRejected, UnsupportedMode
from .link import MavlinkLink
from .modes import ModeKind, flight_mode, mode_kind, mode_numbers
from .readiness import Readiness, readiness
from .statustext import names_our_link, names_own_failsafe, own_failsafe_text
from .telemetry import Autopilot, Telemetry, map_offset

log = logging.getLogger(__name__)
_NAN = math.nan


class MavlinkVehicle(MavlinkLink):
    """A MAVLink autopilot (PX4, ArduPilot or generic) behind the SI-unit methods the mission needs.

    Takes :class:`~.link.MavlinkLink`'s parameters. Implements ``skyroute.flight.mission.Vehicle``.
    """

    #: The map ground's altitude above sea level (m) the mission tied the map frame to; None before.
    ground_amsl_m: float | None = None

    # ---------------------------------------------------------------------------------------------- state
    @property
    def in_control(self) -> bool:
        """True while the autopilot is in our flight mode (OFFBOARD on PX4, GUIDED on ArduPilot)."""
        return self.mode_kind() is ModeKind.OURS

    def mode_kind(self) -> ModeKind:
        """What the current mode means (ours, hold, return/land, a pilot's, another automatic one)."""
        t = self.telemetry
        return mode_kind(t.autopilot, t.mode)

    def readiness(self) -> Readiness:
        """What the vehicle still lacks for a mission (position estimates, home, pre-arm checks)."""
        return readiness(self.telemetry, time.monotonic())

    def map_offset(self, map_origin: Geodetic, ground_amsl_m: float | None = None, timeout_s: float = 10.0
                   ) -> LocalNED:
        """``map_ned - autopilot_local_ned`` (see :func:`~.telemetry.map_offset`) from fresh positions.

        ``ground_amsl_m`` (the map ground's altitude above sea level) is remembered for later calls without one
        (e.g. the live view's); until the mission has given one, the home position's altitude stands in.
        """
        if ground_amsl_m is None:
            ground_amsl_m = self.ground_amsl_m
            if ground_amsl_m is None:
                t = self.wait_for(lambda t: t.home is not None, timeout_s, "HOME_POSITION")
                ground_amsl_m = t.home.alt_m
        else:
            self.ground_amsl_m = float(ground_amsl_m)
        now = time.monotonic()
        t = self.wait_for(lambda t: t.has_global and t.has_local and t.global_rx_s > now and t.local_rx_s > now,
                          timeout_s, "GLOBAL_POSITION_INT and LOCAL_POSITION_NED")
        offset = map_offset(t, map_origin, ground_amsl_m)
        log.info("map frame = autopilot local frame + (%.2f, %.2f, %.2f) m (map ground %.2f m AMSL)", *offset,
                 ground_amsl_m)
        return offset

    def map_offset_now(self, map_origin: Geodetic, ground_amsl_m: float, fresh_s: float = 0.5) -> LocalNED | None:
        """The map offset from the latest samples, without waiting; None unless both positions are fresh."""
        t, now = self.telemetry, time.monotonic()
        if not (t.has_global and t.has_local) or now - t.global_rx_s > fresh_s or now - t.local_rx_s > fresh_s:
            return None
        return map_offset(t, map_origin, ground_amsl_m)

    def failsafe_hint(self, window_s: float = 5.0, pause_s: float = 0.5, *, texts: bool = True) -> str | None:
        """Why the autopilot may have left our mode on its own in the last ``window_s``, for a reason on our side:
        our setpoints paused for ``pause_s`` or more (PX4 leaves OFFBOARD after COM_OF_LOSS_T), our link was
        silent, nothing came from the autopilot for ``pause_s`` or more (a short outage: its failsafe text was lost
        with it), it announced a failsafe about our link ("GCS Failsafe"), or (``texts``) any failsafe that names
        no cause of its own ("Failsafe activated"; see :meth:`own_failsafe`). None if nothing explains it."""
        pause = self.setpoint_pause_s(window_s)
        if pause >= pause_s:
            return f"our setpoints paused for {pause:.1f} s"
        if self.link_silent_within(window_s):
            return "our link was silent"
        gap = self.health.longest_gap_s(window_s)
        # shorter than a lost link, long enough for its failsafe (its text lost with the link); its timeout runs on
        # its clock, which a sped-up SITL or simulator runs faster than ours
        if gap >= max(pause_s, 0.9 * self._failsafe_after_s() / self.autopilot_clock.rate()):
            return f"we heard nothing from the autopilot for {gap:.1f} s"
        now = time.monotonic()
        for s in reversed(self.telemetry.statustexts):
            if now - s.time_s > window_s:
                break
            failsafe = "failsafe" in s.text.lower().replace("-", "").replace(" ", "")
            if names_our_link(s.text) and s.severity <= mavlink.MAV_SEVERITY_WARNING or \
                    texts and failsafe and not names_own_failsafe(s):
                return f"the autopilot said {s.text!r}"
        return None

    def own_failsafe(self, window_s: float = 5.0) -> str | None:
        """The autopilot's words if, in the last ``window_s``, it announced a failsafe of its own (battery,
        geofence, estimator, GPS, radio: :func:`~.statustext.own_failsafe_text`), not one about our link."""
        return own_failsafe_text(self.telemetry.statustexts, time.monotonic() - window_s)

    def _failsafe_after_s(self) -> float:
        """How long the autopilot waits for us before its own failsafe (PX4 COM_OF_LOSS_T, ArduCopter
        FS_GCS_TIMEOUT), when its parameters were read; 0 if not known."""
        params = self._limits.params if self._limits is not None else {}
        return float(params.get("COM_OF_LOSS_T", params.get("FS_GCS_TIMEOUT", 0.0)))

    def flight_limits(self) -> limits_mod.FlightLimits:
        """The autopilot's speed/acceleration limits and link-loss behaviour, from its parameters (read once)."""
        if self._limits is None:
            params = self.read_params(limits_mod.PARAMETERS[self.autopilot])
            log.info("autopilot parameters: %s", ", ".join(f"{k}={v:g}" for k, v in params.items()) or "none")
            self._limits = limits_mod.flight_limits(self.autopilot, params, self.us[0])
        return self._limits

    # -------------------------------------------------------------------------------------------- actions
    def arm(self) -> None:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM 1). Returns as soon as the autopilot accepts (the ack says it is
        armed; the next heartbeat confirms it), so the takeoff can follow at once."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, done=lambda t: t.armed)
        self._assume(armed=True)
        log.info("armed")

    def disarm(self, *, force: bool = False) -> None:
        """Disarm; ``force`` sends the 21196 magic (disarm in the air), never used by the mission."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0, done=lambda t: not t.armed)
        self.wait_for(lambda t: not t.armed, 3.0, "heartbeat disarmed flag")
        log.info("disarmed")

    def set_mode(self, mode: str, *, retry_temporary_s: float = 0.0, confirm_s: float = 2.0) -> None:
        """DO_SET_MODE by name (pymavlink's PX4 or ArduPilot table); waits ``confirm_s`` for the heartbeat.
        A heartbeat in that mode also answers it when its ack is lost."""
        main_mode, sub_mode = mode_numbers(self.autopilot, mode, self._mav_type)

        def in_mode(t) -> bool:
            return t.mode == mode.upper()

        self.command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_mode,
                          sub_mode, retry_temporary_s=retry_temporary_s, done=in_mode)
        if confirm_s > 0:
            self.wait_for(in_mode, confirm_s, f"heartbeat mode {mode.upper()}")
        log.info("mode %s", mode.upper())

    def _hold_here(self) -> None:
        """Stream a position setpoint where the vehicle is (on the ground: where it stands)."""
        t = self.telemetry
        if not t.has_local:
            t = self.wait_for(lambda t: t.has_local, 5.0, "LOCAL_POSITION_NED")
        self.stream_setpoint(t.north_m, t.east_m, t.down_m, _heading_or_zero(t))

    def prepare_flight(self, warmup_s: float = 0.5) -> None:
        """Before arming: put the vehicle in our flight mode, which it can be armed in for this mission.

        A setpoint where the vehicle stands streams first: PX4 accepts OFFBOARD (and arming in it) only with a
        live stream (TEMPORARILY_REJECTED is retried meanwhile); real ArduCopter ignores it on the ground, and it
        stops before NAV_TAKEOFF. ArduPilot then GUIDED: a vehicle left in LAND after a mission cannot be armed.
        """
        self._hold_here()
        time.sleep(warmup_s)
        if not self.in_control:
            self.set_mode(flight_mode(self.autopilot), retry_temporary_s=3.0)

    def take_control(self) -> None:
        """Re-request our flight mode after the autopilot left it (the current setpoint keeps streaming)."""
        if not self.streaming:
            self._hold_here()
        self.set_mode(flight_mode(self.autopilot), retry_temporary_s=2.0)

    def takeoff(self, altitude_m: float) -> LocalNED:
        """Climb ``altitude_m`` above the current position; returns the local target. Does not wait.

        PX4/generic: a position setpoint straight above, in OFFBOARD. ArduPilot: MAV_CMD_NAV_TAKEOFF in GUIDED
        (its altitude is relative to home, which ArduCopter sets where it arms: here).
        """
        t = self.telemetry
        target = LocalNED(t.north_m, t.east_m, t.down_m - altitude_m)
        if self.autopilot is Autopilot.ARDUPILOT:
            self.stop_streaming()  # a position target would cut the takeoff short
            if t.mode != "GUIDED":
                self.set_mode("GUIDED")
            self.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, _NAN, 0, 0, altitude_m)
        else:
            self.stream_setpoint(*target, yaw_rad=_heading_or_zero(t))
            if not self.in_control:
                self.set_mode("OFFBOARD", retry_temporary_s=3.0)
        log.info("takeoff: %.1f m up", altitude_m)
        return target

    def goto_local(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
                   velocity_ned: tuple[float, float, float] | None = None,
                   accel_ned: tuple[float, float, float] | None = None) -> None:
        """Fly to a position in the autopilot's LOCAL_NED frame (m) with a heading (rad); re-sent until changed.

        ``velocity_ned`` (m/s, local NED) goes with the position as a feed-forward: the autopilot flies at that
        velocity plus its position loop's correction towards the position. Re-sends drop it after
        ``feedforward_timeout_s`` without a new call (position only: the vehicle brakes there). ``accel_ned``
        (m/s^2, local NED; only with a velocity, and dropped with it) is a feed-forward acceleration, for an
        autopilot that adds it to its velocity loop's output (``FlightLimits.acceleration_feedforward``).
        """
        self.stream_setpoint(north_m, east_m, down_m, yaw_rad, velocity_ned, accel_ned)

    def land(self) -> None:
        """Land where we are: ArduPilot LAND mode; PX4 MAV_CMD_NAV_LAND (falling back to its LAND mode).

        Setpoints keep streaming until the autopilot accepts, so a slow answer cannot drop PX4 out of OFFBOARD.
        """
        if self.autopilot is Autopilot.ARDUPILOT:
            self.set_mode("LAND", confirm_s=0.0)
        else:
            try:
                self.command_long(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, _NAN, _NAN, _NAN, _NAN,
                                  done=lambda t: t.mode == "LAND")
            except CommandRejected as exc:
                log.warning("%s; switching to LAND mode instead", exc)
                self.set_mode("LAND", confirm_s=0.0)
        self.stop_streaming()
        log.info("landing")

    def hold(self) -> None:
        """Hover in place: the autopilot's hold mode (PX4 Hold, ArduCopter BRAKE); if refused, a setpoint here."""
        if self.in_control:
            self._hold_here()
        mode = "BRAKE" if self.autopilot is Autopilot.ARDUPILOT else "LOITER"
        try:
            self.set_mode(mode, confirm_s=0.0)
        except (CommandRejected, UnsupportedMode) as exc:
            if not self.in_control:
                raise
            log.warning("%s; holding with a position setpoint instead", exc)
        else:
            self.stop_streaming()
        log.info("holding position")

    def release_control(self) -> None:
        """Stop streaming setpoints (the autopilot keeps its current mode)."""
        self.stop_streaming()


def _heading_or_zero(t: Telemetry) -> float:
    return 0.0 if math.isnan(t.heading_rad) else t.heading_rad
