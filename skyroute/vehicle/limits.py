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
  A held position target does not move, so the feed-forward settles the vehicle about ``v / MPC_XY_P`` past it
  however long COM_OF_LOSS_T is: with COM_OF_LOSS_T = 5 s, 5 m/s went 6.6 m past the last target in 3 s and settled
  back towards 5.3 m until the failsafe (6.9 m with the drag's lean, 1 m/s^2 per m/s, held as an acceleration too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .telemetry import Autopilot

ARDUPILOT_PARAMETERS = ("FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "GUID_TIMEOUT", "WPNAV_SPEED", "WPNAV_ACCEL", "ANGLE_MAX",
                        "MAV_GCS_SYSID", "SYSID_MYGCS", "FENCE_ENABLE", "FENCE_TYPE", "FENCE_ACTION", "FENCE_RADIUS",
                        "FENCE_ALT_MAX", "FENCE_MARGIN", "RTL_ALT")
PX4_PARAMETERS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT", "COM_DL_LOSS_T", "MPC_XY_VEL_MAX",
                  "MPC_ACC_HOR", "MPC_XY_P", "MPC_TILTMAX_AIR", "GF_ACTION", "GF_MAX_HOR_DIST", "GF_MAX_VER_DIST",
                  "RTL_RETURN_ALT")
PARAMETERS = {Autopilot.ARDUPILOT: ARDUPILOT_PARAMETERS, Autopilot.PX4: PX4_PARAMETERS,
              Autopilot.GENERIC: PX4_PARAMETERS}

#: The real autopilots' defaults, for parameters an autopilot does not report.
DEFAULTS = {
    "FS_GCS_ENABLE": 0.0, "FS_GCS_TIMEOUT": 5.0, "GUID_TIMEOUT": 3.0, "WPNAV_SPEED": 1000.0, "WPNAV_ACCEL": 250.0,
    "MAV_GCS_SYSID": 255.0,
    "COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0.0, "NAV_DLL_ACT": 0.0, "COM_DL_LOSS_T": 10.0,
    "MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MPC_XY_P": 0.95, "MPC_TILTMAX_AIR": 45.0, "ANGLE_MAX": 3000.0,
    "FENCE_ENABLE": 0.0, "FENCE_TYPE": 7.0, "FENCE_ACTION": 1.0, "FENCE_RADIUS": 300.0, "FENCE_ALT_MAX": 100.0,
    "FENCE_MARGIN": 2.0, "GF_ACTION": 2.0, "GF_MAX_HOR_DIST": 0.0, "GF_MAX_VER_DIST": 0.0,
    "RTL_ALT": 1500.0, "RTL_RETURN_ALT": 60.0,
}

_FS_GCS_ACTIONS = {1: "RTL", 2: "RTL (or continue an AUTO mission)", 3: "SmartRTL or RTL", 4: "SmartRTL or LAND",
                   5: "LAND", 6: "DO_LAND_START or RTL", 7: "BRAKE then LAND"}
_PX4_OFFBOARD_LOSS = {0: "position mode", 1: "altitude mode", 2: "manual mode", 3: "Return", 4: "Land",
                      5: "Hold", 6: "terminate", 7: "disarm"}
_PX4_DATALINK_LOSS = {0: "nothing", 1: "Hold", 2: "Return", 3: "Land", 5: "terminate", 6: "disarm"}
_FENCE_ACTIONS = {1: "RTL or LAND", 2: "LAND", 3: "SmartRTL, RTL or LAND", 4: "BRAKE or LAND",
                  5: "SmartRTL or LAND"}
_GF_ACTIONS = {2: "Hold", 3: "Return", 4: "terminate", 5: "Land"}
_PX4_HOVERS = {5}  # Hold keeps the vehicle hovering where it is
#: The manual modes need RC; without it PX4 descends and lands (measured for position mode on PX4 1.15 SITL).
_PX4_MANUAL = {0, 1, 2}


@dataclass(frozen=True)
class Geofence:
    """The autopilot's own fence round home: ``radius_m`` horizontally, ``height_m`` above home (``inf`` where it
    has none), each less the autopilot's margin; ``described`` says which parameters and what it does on a breach."""

    radius_m: float
    height_m: float
    described: str


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
    shapes the target with WPNAV_ACCEL and a jerk limit; NaN when unknown). ``fence``: the autopilot's geofence
    round home when it has one that acts (:func:`geofence`), else None. ``return_altitude_m``: the height above
    home at which the autopilot's return (RTL) flies home in a straight line, climbing to it first when lower
    (ArduCopter RTL_ALT, PX4 RTL_RETURN_ALT; NaN unknown), named with its parameter in ``return_described``.
    ``acceleration_feedforward``: the autopilot adds a setpoint's acceleration to its velocity loop's output and
    holds it as it is (PX4 OFFBOARD), so the mission may send the drag's lean as one; False where that is not known
    (ArduCopter GUIDED integrates a target acceleration into the target's velocity: after our last setpoint it would
    speed the target up for GUID_TIMEOUT). ``max_tilt_deg``: the most the autopilot leans in flight (ArduCopter
    ANGLE_MAX, PX4 MPC_TILTMAX_AIR; ``inf`` unknown): with the drag it bounds how fast the vehicle can fly against
    and across a wind and still hold its track (:mod:`skyroute.flight.tilt`).
    """

    cruise_mps: float = math.inf
    accel_mps2: float = math.inf
    lateral_accel_mps2: float = math.inf
    hold_last_s: float = 1.0
    brake_mps2: float = 2.5
    link_loss: str = "unknown: the autopilot's failsafe parameters were not read"
    leaves_flying: bool = False
    response_s: float = math.nan
    fence: Geofence | None = None
    return_altitude_m: float = math.nan
    return_described: str = ""
    params: dict[str, float] = field(default_factory=dict)
    acceleration_feedforward: bool = False
    max_tilt_deg: float = math.inf

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


def geofence(autopilot: Autopilot, params: dict[str, float]) -> Geofence | None:
    """The autopilot's geofence round home, from its parameters; None when it has none that does more than warn.

    ArduCopter: FENCE_ENABLE, FENCE_TYPE bits 1 (max altitude, FENCE_ALT_MAX) and 2 (circle, FENCE_RADIUS), less
    FENCE_MARGIN, FENCE_ACTION 0 = report only (measured on SITL: radius 150 m, action 1: "Circle fence breached",
    RTL). PX4: GF_MAX_HOR_DIST and GF_MAX_VER_DIST (0 = none), GF_ACTION 0 none, 1 warning. Polygon fences (a fence
    mission) are not read.

    >>> geofence(Autopilot.ARDUPILOT, {"FENCE_ENABLE": 1, "FENCE_TYPE": 2, "FENCE_RADIUS": 150}).radius_m
    148.0
    >>> geofence(Autopilot.PX4, {"GF_MAX_HOR_DIST": 0, "GF_MAX_VER_DIST": 0}) is None
    True
    """
    def get(name: str) -> float:
        return float(params[name]) if name in params else DEFAULTS[name]

    if autopilot is Autopilot.ARDUPILOT:
        kinds, action = int(get("FENCE_TYPE")), int(get("FENCE_ACTION"))
        if not get("FENCE_ENABLE") or action == 0 or not kinds & 3:
            return None
        margin = max(get("FENCE_MARGIN"), 0.0)
        radius = get("FENCE_RADIUS") - margin if kinds & 2 else math.inf
        height = get("FENCE_ALT_MAX") - margin if kinds & 1 else math.inf
        names = [n for n, bit in (("FENCE_RADIUS", 2), ("FENCE_ALT_MAX", 1)) if kinds & bit]
        return Geofence(radius, height, f"{' and '.join(f'{n}={get(n):g} m' for n in names)}, FENCE_MARGIN="
                                        f"{margin:g} m; a breach does {_FENCE_ACTIONS.get(action, f'action {action}')}")
    action = int(get("GF_ACTION"))
    radius, height = get("GF_MAX_HOR_DIST"), get("GF_MAX_VER_DIST")
    if action in (0, 1) or not (radius > 0 or height > 0):
        return None
    names = [f"{n}={v:g} m" for n, v in (("GF_MAX_HOR_DIST", radius), ("GF_MAX_VER_DIST", height)) if v > 0]
    return Geofence(radius if radius > 0 else math.inf, height if height > 0 else math.inf,
                    f"{' and '.join(names)}; a breach does {_GF_ACTIONS.get(action, f'action {action}')} "
                    f"(GF_ACTION={action})")


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
            response_s=1.0, fence=geofence(autopilot, params), return_altitude_m=get("RTL_ALT") / 100.0,
            return_described=f"RTL_ALT={get('RTL_ALT'):g} cm" + assumed("RTL_ALT"), params=dict(params),
            max_tilt_deg=get("ANGLE_MAX") / 100.0)
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
        # our setpoints always carry a position: PX4 holds it, so COM_OF_LOSS_T does not lengthen the coast
        hold_last_s=1.0 / max(get("MPC_XY_P"), 0.1), brake_mps2=accel,
        link_loss=link_loss + assumed("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT"), leaves_flying=flying,
        response_s=0.6 if autopilot is Autopilot.PX4 else math.nan, fence=geofence(autopilot, params),
        return_altitude_m=get("RTL_RETURN_ALT"),
        return_described=f"RTL_RETURN_ALT={get('RTL_RETURN_ALT'):g} m" + assumed("RTL_RETURN_ALT"),
        params=dict(params), acceleration_feedforward=autopilot is Autopilot.PX4,
        max_tilt_deg=get("MPC_TILTMAX_AIR"))
