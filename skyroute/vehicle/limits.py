"""The autopilot's limits and failsafes, from its parameters, in SI units.

Read before flight (:data:`PARAMETERS`), so the mission flies within the autopilot's speed and acceleration
limits, knows how far the last setpoint can carry the vehicle if our commands stop (a crashed client or a cut
link), and can say what the autopilot does when the link is lost. Missing parameters (an autopilot that does not
have them, e.g. our sim) take the real autopilot's default, and the description says so. Part of the ``vehicle``
package.

Measured on the SITL binaries in ../shared/sitl (ArduCopter V4.7.0-dev, PX4 v1.15.4):

- ArduCopter GUIDED moves a position + velocity target on along its velocity for GUID_TIMEOUT (3 s) after the
  last one, then holds there: 5 m/s ended 20.5 m past the last target (5 x 3 s plus braking at WPNAV_ACCEL),
  settling back to 14 m. With FS_GCS_ENABLE = 0 (the default) it stays GUIDED and hovers there.
- PX4 OFFBOARD holds the last position setpoint with its velocity feed-forward until COM_OF_LOSS_T (1 s), then
  takes COM_OBL_RC_ACT: 5 m/s ended 6-7 m past the last target. With the default (0, position mode) and no RC,
  PX4 then descends at 0.6-1.15 m/s (run to run) and lands where it is ("Landing detected", "Disarmed by landing").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .telemetry import Autopilot

ARDUPILOT_PARAMETERS = ("FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "GUID_TIMEOUT", "WPNAV_SPEED", "WPNAV_ACCEL",
                        "MAV_GCS_SYSID", "SYSID_MYGCS")
PX4_PARAMETERS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT", "COM_DL_LOSS_T", "MPC_XY_VEL_MAX",
                  "MPC_ACC_HOR", "MPC_XY_P")
PARAMETERS = {Autopilot.ARDUPILOT: ARDUPILOT_PARAMETERS, Autopilot.PX4: PX4_PARAMETERS,
              Autopilot.GENERIC: PX4_PARAMETERS}

#: The real autopilots' defaults, for parameters an autopilot does not report.
DEFAULTS = {
    "FS_GCS_ENABLE": 0.0, "FS_GCS_TIMEOUT": 5.0, "GUID_TIMEOUT": 3.0, "WPNAV_SPEED": 1000.0, "WPNAV_ACCEL": 250.0,
    "MAV_GCS_SYSID": 255.0,
    "COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0.0, "NAV_DLL_ACT": 0.0, "COM_DL_LOSS_T": 10.0,
    "MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MPC_XY_P": 0.95,
}

_FS_GCS_ACTIONS = {1: "RTL", 2: "RTL (or continue an AUTO mission)", 3: "SmartRTL or RTL", 4: "SmartRTL or LAND",
                   5: "LAND", 6: "DO_LAND_START or RTL", 7: "BRAKE then LAND"}
_PX4_OFFBOARD_LOSS = {0: "position mode", 1: "altitude mode", 2: "manual mode", 3: "Return", 4: "Land",
                      5: "Hold", 6: "terminate", 7: "disarm"}
_PX4_DATALINK_LOSS = {0: "nothing", 1: "Hold", 2: "Return", 3: "Land", 5: "terminate", 6: "disarm"}
_PX4_HOVERS = {5}  # Hold keeps the vehicle hovering where it is
#: The manual modes need RC; without it PX4 descends and lands (measured for position mode on PX4 1.15 SITL).
_PX4_MANUAL = {0, 1, 2}


@dataclass(frozen=True)
class FlightLimits:
    """Limits (SI) the mission must respect, and what the autopilot does once our commands stop.

    ``cruise_mps`` and ``accel_mps2``: the most the autopilot will fly or accelerate horizontally (``inf`` when
    unknown); ``lateral_accel_mps2`` the most to plan its corners with, leaving the rest of ``accel_mps2`` to its
    position loop (ArduCopter GUIDED shapes its target with a jerk limit: 0.6 x WPNAV_ACCEL; PX4 0.9 x). After our
    last setpoint the autopilot keeps acting on it for ``hold_last_s`` (moving a velocity target on, or
    overshooting a position target by the feed-forward), then brakes at ``brake_mps2``: see
    :meth:`coast_m`. ``link_loss`` says in words what happens when our link is lost; ``leaves_flying`` is True
    when that leaves the vehicle in the air (hovering) until its battery runs out. ``response_s``: how long its
    velocity lags a new feed-forward (measured on SITL: PX4 ~0.6 s braking from 9 m/s; ArduCopter ~1 s, its GUIDED
    shapes the target with WPNAV_ACCEL and a jerk limit; NaN when unknown).
    """

    cruise_mps: float = math.inf
    accel_mps2: float = math.inf
    lateral_accel_mps2: float = math.inf
    hold_last_s: float = 1.0
    brake_mps2: float = 2.5
    link_loss: str = "unknown: the autopilot's failsafe parameters were not read"
    leaves_flying: bool = False
    response_s: float = math.nan
    params: dict[str, float] = field(default_factory=dict)

    def coast_m(self, speed_mps: float) -> float:
        """How far (m) past its last setpoint a vehicle commanded at ``speed_mps`` can go once commands stop.

        >>> round(FlightLimits(hold_last_s=3.0, brake_mps2=2.5).coast_m(5.0), 2)  # ArduCopter: 15 m + 5 m braking
        20.0
        """
        speed = max(float(speed_mps), 0.0)
        return speed * self.hold_last_s + speed**2 / (2.0 * self.brake_mps2)

    def speed_for_clearance_mps(self, clear_m: float) -> float:
        """The highest speed whose :meth:`coast_m` fits in ``clear_m`` metres (the inverse of ``coast_m``).

        >>> round(FlightLimits(hold_last_s=3.0, brake_mps2=2.5).speed_for_clearance_mps(20.0), 6)
        5.0
        """
        if not clear_m > 0:
            return 0.0
        a, t = self.brake_mps2, self.hold_last_s
        return a * (-t + math.sqrt(t * t + 2.0 * clear_m / a))


def flight_limits(autopilot: Autopilot, params: dict[str, float], our_system: int) -> FlightLimits:
    """:class:`FlightLimits` from the parameters read (names as in :data:`PARAMETERS`).

    >>> lim = flight_limits(Autopilot.ARDUPILOT, {"WPNAV_ACCEL": 250.0, "FS_GCS_ENABLE": 0.0}, our_system=255)
    >>> lim.accel_mps2, lim.hold_last_s, lim.leaves_flying
    (2.5, 3.0, True)
    """
    def get(name: str) -> float:
        return float(params[name]) if name in params else DEFAULTS[name]

    def assumed(*names: str) -> str:
        missing = [n for n in names if n not in params]
        return f" ({', '.join(missing)} not reported: default assumed)" if missing else ""

    if autopilot is Autopilot.ARDUPILOT:
        accel = get("WPNAV_ACCEL") / 100.0
        action = int(get("FS_GCS_ENABLE"))
        gcs_sysid = int(params.get("MAV_GCS_SYSID", params.get("SYSID_MYGCS", DEFAULTS["MAV_GCS_SYSID"])))
        hovers = "a lost link leaves the vehicle hovering in GUIDED at its last target"
        if action == 0:
            link_loss, flying = f"ArduCopter's GCS failsafe is off (FS_GCS_ENABLE=0): {hovers}", True
        elif gcs_sysid != our_system:
            link_loss = (f"ArduCopter's GCS failsafe watches system {gcs_sysid} (MAV_GCS_SYSID), not ours "
                         f"({our_system}): {hovers}")
            flying = True
        else:
            link_loss = (f"after {get('FS_GCS_TIMEOUT'):g} s without our heartbeat ArduCopter's GCS failsafe does "
                         f"{_FS_GCS_ACTIONS.get(action, f'action {action}')} (FS_GCS_ENABLE={action})")
            flying = False
        return FlightLimits(
            cruise_mps=get("WPNAV_SPEED") / 100.0, accel_mps2=accel, lateral_accel_mps2=0.6 * accel,
            hold_last_s=get("GUID_TIMEOUT"),
            brake_mps2=accel, link_loss=link_loss + assumed("FS_GCS_ENABLE", "GUID_TIMEOUT"), leaves_flying=flying,
            response_s=1.0, params=dict(params))
    offboard = int(get("COM_OBL_RC_ACT"))
    datalink = int(get("NAV_DLL_ACT"))
    link_loss = (f"after {get('COM_OF_LOSS_T'):g} s without setpoints PX4 switches to "
                 f"{_PX4_OFFBOARD_LOSS.get(offboard, f'action {offboard}')} (COM_OBL_RC_ACT={offboard}); "
                 f"after {get('COM_DL_LOSS_T'):g} s without a ground station it does "
                 f"{_PX4_DATALINK_LOSS.get(datalink, f'action {datalink}')} (NAV_DLL_ACT={datalink})")
    flying = offboard in _PX4_HOVERS and datalink in (0, 1)
    if flying:
        link_loss += ": a lost link leaves the vehicle hovering"
    elif offboard in _PX4_MANUAL:
        link_loss += ": without RC a lost link lands the vehicle where it is"
    accel = get("MPC_ACC_HOR")
    return FlightLimits(
        cruise_mps=get("MPC_XY_VEL_MAX"), accel_mps2=accel, lateral_accel_mps2=0.9 * accel,
        hold_last_s=max(get("COM_OF_LOSS_T"), 1.0 / max(get("MPC_XY_P"), 0.1)), brake_mps2=accel,
        link_loss=link_loss + assumed("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT"), leaves_flying=flying,
        response_s=0.6 if autopilot is Autopilot.PX4 else math.nan, params=dict(params))
