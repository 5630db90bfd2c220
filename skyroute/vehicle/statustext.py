"""STATUSTEXT: chunks reassembled into whole texts, and the text that belongs to a refusal.

MAVLink 2 splits a text longer than 50 bytes into chunks that share a non-zero ``id`` and count ``chunk_seq``
from 0; a chunk shorter than 50 bytes is the last one. PX4 sends its longer refusals that way ("Arming denied:
Resolve system health failures firs" + "t"), and ends texts it also reports as an EVENT with a tab, which is
not part of the text. ArduPilot sends single texts (``id`` 0).

PX4's EVENT messages (MAVLink id 410) are not decoded: pymavlink's dialects do not define them, and their
text lives in PX4's event metadata, not in the message. PX4 sends the same refusals as STATUSTEXT to a ground
station (our heartbeat says MAV_TYPE_GCS), which is what we quote.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

CHUNK_BYTES = 50


@dataclass(frozen=True)
class StatusText:
    """One whole STATUSTEXT: MAV_SEVERITY (0 emergency .. 7 debug), text, our monotonic receive time in s."""

    severity: int
    text: str
    time_s: float


def clean_text(raw: bytes | str) -> str:
    """Decode a STATUSTEXT field: UTF-8, cut at the first NUL (pymavlink may leave them)."""
    text = raw.decode("utf-8", errors="replace") if isinstance(raw, bytes | bytearray) else str(raw)
    return text.split("\x00", 1)[0]


class StatusTextAssembler:
    """Turns STATUSTEXT messages into whole :class:`StatusText`; one instance per link.

    >>> a = StatusTextAssembler()
    >>> a.add(2, "Arming denied: Resolve system health failures firs", 7, 0, 1.0)
    []
    >>> [s.text for s in a.add(2, "t\\t", 7, 1, 1.01)]
    ['Arming denied: Resolve system health failures first']
    """

    def __init__(self, stale_s: float = 2.0):
        self.stale_s = stale_s
        self._pending: dict[int, tuple[int, list[str], float, int]] = {}  # id -> (severity, chunks, t0, next seq)

    def add(self, severity: int, raw_text: bytes | str, ident: int, chunk_seq: int, now_s: float) -> list[StatusText]:
        """Feed one message; returns the texts it completes (stale partial texts first, as they are)."""
        text = clean_text(raw_text)
        out = self._flush_stale(now_s)
        if not ident:
            out.append(_finished(severity, text, now_s))
            return out
        severity0, chunks, t0, expected = self._pending.get(ident, (severity, [], now_s, 0))
        if chunk_seq != expected:  # a chunk was lost: keep what we have, mark the gap
            chunks.append("…")
        chunks.append(text)
        if len(text.encode("utf-8")) < CHUNK_BYTES:
            self._pending.pop(ident, None)
            out.append(_finished(min(severity0, severity), "".join(chunks), now_s))
        else:
            self._pending[ident] = (min(severity0, severity), chunks, t0, chunk_seq + 1)
        return out

    def _flush_stale(self, now_s: float) -> list[StatusText]:
        stale = [k for k, (_, _, t0, _) in self._pending.items() if now_s - t0 > self.stale_s]
        out = []
        for ident in stale:
            severity, chunks, _, _ = self._pending.pop(ident)
            out.append(_finished(severity, "".join(chunks) + "…", now_s))
        return out


def _finished(severity: int, text: str, now_s: float) -> StatusText:
    return StatusText(int(severity), text.rstrip("\t\r\n "), now_s)


#: Words that tie a text to a command's refusal, by the command's subject.
_SUBJECTS = {
    "arm": re.compile(r"arm|pre-?flight|prearm|pre-arm|not ready|health|calibrat|gps|ekf|position", re.I),
    "mode": re.compile(r"mode|offboard|guided|not available|denied|switch", re.I),
    "takeoff": re.compile(r"take-?off|altitude|not armed|arm", re.I),
}


def refusal_reason(texts: Iterable[StatusText], since_s: float, until_s: float, subject: str | None = None,
                   warning_severity: int = 4) -> str | None:
    """The autopilot's own words for a refusal: the texts received between ``since_s`` and ``until_s``.

    Keeps warnings and worse (MAV_SEVERITY <= ``warning_severity``); prefers those about ``subject``
    ("arm", "mode", "takeoff"); joins at most two distinct texts with "; ", the earliest first.

    >>> ts = [StatusText(6, "Arming motors", 1.0), StatusText(2, "PreArm: Need Position Estimate", 1.1),
    ...       StatusText(4, "Battery 1 is low", 1.2)]
    >>> refusal_reason(ts, 0.9, 1.5, "arm")
    'PreArm: Need Position Estimate'
    """
    window = [s for s in texts if since_s <= s.time_s <= until_s and s.severity <= warning_severity]
    pattern = _SUBJECTS.get(subject or "")
    if pattern is not None and any(pattern.search(s.text) for s in window):
        window = [s for s in window if pattern.search(s.text)]
    distinct: list[str] = []
    for s in window:
        if s.text and s.text not in distinct:
            distinct.append(s.text)
    return "; ".join(distinct[:2]) or None


#: What an autopilot names when a failsafe of its own fires (measured on ArduCopter SITL: "Battery 1 is low 10.00V
#: used 177 mAh", "Battery Failsafe", "Circle fence breached"; by their names, ArduCopter's radio, EKF and
#: GPS-glitch failsafes and PX4's battery, position-loss and wind warnings) ...
_OWN_CAUSE = re.compile(r"batt|fence|ekf|estimat|gps|radio|\brc\b|throttle|terminat|crash|vibration|compass|baro"
                        r"|motor|parachute|dead.?reckon|flight time|wind", re.I)
#: ... and what it names when the failsafe is about us: our setpoint stream or our link (ArduCopter "GCS Failsafe",
#: PX4 "Connection to ground station lost", "No offboard signal").
_OUR_CAUSE = re.compile(r"gcs|ground station|offboard|data ?link|telemetry|mavlink|\blink\b", re.I)
#: Arming checks name the same sensors but are no failsafe (PX4 sends "Preflight Fail: height estimate not stable"
#: around takeoff and landing, measured on PX4 1.15 SITL).
_ARMING_CHECK = re.compile(r"pre-?flight|pre-?arm|\barm(ing)?\b", re.I)


def names_our_link(text: str) -> bool:
    """Whether a text is about our link or setpoint stream (ArduCopter "GCS Failsafe", PX4 "Connection to ground
    station lost").

    >>> names_our_link("GCS Failsafe"), names_our_link("Failsafe activated")
    (True, False)
    """
    return bool(_OUR_CAUSE.search(text))


def names_own_failsafe(s: StatusText, notice_severity: int = 5) -> bool:
    """Whether a notice or worse names a failsafe of the autopilot's own (see :func:`own_failsafe_text`)."""
    return (s.severity <= notice_severity and bool(_OWN_CAUSE.search(s.text)) and not _OUR_CAUSE.search(s.text)
            and not _ARMING_CHECK.search(s.text))


def own_failsafe_text(texts: Iterable[StatusText], since_s: float, notice_severity: int = 5) -> str | None:
    """The latest notice or worse (MAV_SEVERITY <= ``notice_severity``: ArduCopter says "Circle fence breached" as
    a NOTICE) received since ``since_s`` in which the autopilot names a failsafe of its own (battery, geofence,
    estimator, GPS, radio, ...), not one about our link; None if there is none. A generic "Failsafe activated"
    names no cause and does not count.

    >>> ts = [StatusText(4, "Battery 1 is low 10.00V used 177 mAh", 1.0), StatusText(4, "Battery Failsafe", 1.0),
    ...       StatusText(4, "GCS Failsafe", 2.0), StatusText(6, "EKF3 IMU0 MAG0 in-flight yaw alignment complete", 2.1),
    ...       StatusText(4, "Preflight Fail: height estimate not stable", 2.2)]
    >>> own_failsafe_text(ts, 0.5), own_failsafe_text(ts, 1.5)
    ('Battery Failsafe', None)
    """
    for s in reversed(list(texts)):
        if s.time_s < since_s:
            break
        if names_own_failsafe(s, notice_severity):
            return s.text
    return None
