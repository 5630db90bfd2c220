"""Boot readiness: what a freshly booted autopilot still lacks before a mission can plan and arm.

A fresh ArduCopter streams LOCAL_POSITION_NED only once its EKF uses GPS (~40 s of simulated time after boot),
and a stock PX4 has a global position only ~35 s after boot; both refuse to arm until then. :func:`readiness`
names what is missing from one telemetry snapshot, so the mission can wait with progress lines instead of
failing. Part of the ``vehicle`` package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .statustext import StatusText
from .telemetry import Telemetry

#: A position older than this (s, our clock) does not count: the stream stopped.
FRESH_S = 2.0
#: Texts worth quoting while waiting (besides warnings): the autopilot's own reasons for not being ready.
_REASON_WORDS = ("prearm", "pre-arm", "preflight", "arming denied", "not ready", "unstable")


@dataclass(frozen=True)
class Readiness:
    """``missing``: what the mission still needs, in words; ``reasons``: the autopilot's latest texts about it."""

    missing: tuple[str, ...]
    reasons: tuple[str, ...] = ()

    @property
    def ready(self) -> bool:
        return not self.missing

    def describe(self) -> str:
        """One line: what is missing, then what the autopilot says.

        >>> Readiness(("a GPS fix", "a home position"), ("PreArm: Need Position Estimate",)).describe()
        'waiting for a GPS fix, a home position (autopilot: PreArm: Need Position Estimate)'
        """
        if self.ready:
            return "ready"
        text = "waiting for " + ", ".join(self.missing)
        return f"{text} (autopilot: {'; '.join(self.reasons)})" if self.reasons else text


def readiness(t: Telemetry, now_s: float, *, recent_s: float = 15.0) -> Readiness:
    """What ``t`` lacks for a mission, and the autopilot's texts of the last ``recent_s`` about it.

    Needed: a 3D GPS fix (when the autopilot reports GPS_RAW_INT), a global position estimate, a home position,
    a local position estimate (the EKF origin is set once both positions stream; GPS_GLOBAL_ORIGIN is recorded
    when the autopilot sends it, not required: PX4 sends it only on request), both positions fresh, the landed
    state (whether it stands on the ground), and the pre-arm checks passing when SYS_STATUS reports them.

    >>> readiness(Telemetry(), now_s=0.0).missing[:4]
    ('a heartbeat', 'a global position estimate', 'a home position', 'a local position estimate')
    """
    missing = []
    if math.isnan(t.last_heartbeat_s):
        missing.append("a heartbeat")
    if 0 <= t.gps_fix_type < mavlink.GPS_FIX_TYPE_3D_FIX:
        missing.append("a 3D GPS fix" + (f" ({t.satellites} satellites)" if t.satellites >= 0 else ""))
    if not t.has_global:
        missing.append("a global position estimate")
    elif not now_s - t.global_rx_s <= FRESH_S:
        missing.append("a fresh global position (the stream stopped)")
    if t.home is None:
        missing.append("a home position")
    if not t.has_local:
        missing.append("a local position estimate")
    elif not now_s - t.local_rx_s <= FRESH_S:
        missing.append("a fresh local position (the stream stopped)")
    if math.isnan(t.landed_rx_s):
        missing.append("a landed state (EXTENDED_SYS_STATE)")
    if t.prearm_ok is False:
        missing.append("the autopilot's pre-arm checks")
    return Readiness(tuple(missing), recent_reasons(t.statustexts, now_s - recent_s) if missing else ())


def recent_reasons(texts: tuple[StatusText, ...], since_s: float, keep: int = 2) -> tuple[str, ...]:
    """The latest ``keep`` distinct texts since ``since_s`` that say why the autopilot is not ready: warnings and
    worse, and texts such as "PreArm: ..." or "Preflight Fail: ..." whatever their severity."""
    out: list[str] = []
    for s in reversed(texts):
        if s.time_s < since_s:
            break
        worth = s.severity <= mavlink.MAV_SEVERITY_WARNING or any(w in s.text.lower() for w in _REASON_WORDS)
        if worth and s.text not in out:
            out.append(s.text)
        if len(out) >= keep:
            break
    return tuple(reversed(out))
