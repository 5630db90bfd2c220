"""Link health: alive while any message of the target autopilot arrives; timeout sized from the round trip.

Heartbeats come once a second, positions 10-50 times: counting only heartbeats, 5 % loss and 100 ms of latency
tripped a 3 s timeout by 22 ms. :class:`LinkHealth` counts every message from the target, measures the round
trip (TIMESYNC answers and COMMAND_ACKs), and calls the link lost after ``max(floor_s, rtt_factor x round
trip)`` of silence. Pure and thread-safe; the clock is injected. Part of the ``vehicle`` package.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable


class LinkHealth:
    """Liveness and round-trip time of one link.

    Parameters
    ----------
    floor_s : float
        Shortest silence (s) that counts as a lost link, whatever the round trip.
    rtt_factor : float
        The timeout is at least this many round trips (the largest of the last ``window`` samples).
    clock : callable
        Monotonic seconds.

    >>> now = [0.0]
    >>> h = LinkHealth(floor_s=2.0, clock=lambda: now[0])
    >>> h.heard(); now[0] = 1.9; h.ok()
    True
    >>> h.round_trip(0.8); h.timeout_s  # 4 x 0.8 s: a slow link gets a longer timeout
    3.2
    """

    def __init__(self, *, floor_s: float = 2.0, rtt_factor: float = 4.0, window: int = 20,
                 clock: Callable[[], float] = time.monotonic):
        self.floor_s, self.rtt_factor = floor_s, rtt_factor
        self.clock = clock
        self._lock = threading.Lock()
        self._last_heard_s = math.nan
        self._samples: deque[float] = deque(maxlen=window)
        self._smoothed_s = math.nan
        self._gaps: deque[tuple[float, float]] = deque(maxlen=10)  # (when it ended, s) of silences >= GAP_S

    #: A silence this long (s) is remembered: the autopilots stream at 10-50 Hz, so it is the link, not a lull.
    GAP_S = 0.5

    def heard(self, now_s: float | None = None) -> None:
        """A message from the target arrived."""
        now_s = self.clock() if now_s is None else now_s
        with self._lock:
            gap = now_s - self._last_heard_s
            if gap >= self.GAP_S:  # False while NaN
                self._gaps.append((now_s, gap))
            self._last_heard_s = now_s

    def longest_gap_s(self, window_s: float, now_s: float | None = None) -> float:
        """The longest silence (s, at least :attr:`GAP_S`) that ended in the last ``window_s``; 0 if none.

        A silence shorter than :attr:`timeout_s` is not a lost link, but an autopilot that heard nothing from us
        for as long may have failed safe meanwhile (PX4 leaves OFFBOARD after COM_OF_LOSS_T, 1 s).

        >>> h = LinkHealth(clock=lambda: 0.0)
        >>> for t in (0.0, 0.1, 1.6, 1.7): h.heard(t)
        >>> h.longest_gap_s(5.0, now_s=2.0), h.longest_gap_s(0.2, now_s=2.0)
        (1.5, 0.0)
        """
        now_s = self.clock() if now_s is None else now_s
        with self._lock:
            return max((gap for when, gap in self._gaps if now_s - when <= window_s), default=0.0)

    def round_trip(self, rtt_s: float) -> None:
        """One round-trip sample (s); ignored unless 0 <= rtt_s < 30."""
        if not 0.0 <= rtt_s < 30.0:
            return
        with self._lock:
            self._samples.append(rtt_s)
            self._smoothed_s = rtt_s if math.isnan(self._smoothed_s) else 0.8 * self._smoothed_s + 0.2 * rtt_s

    @property
    def rtt_s(self) -> float:
        """Smoothed round trip (s); 0 before the first sample."""
        with self._lock:
            return 0.0 if math.isnan(self._smoothed_s) else self._smoothed_s

    @property
    def timeout_s(self) -> float:
        """Silence (s) after which the link counts as lost."""
        with self._lock:
            worst = max(self._samples, default=0.0)
        return max(self.floor_s, self.rtt_factor * worst)

    def silent_s(self, now_s: float | None = None) -> float:
        """Seconds since the last message from the target (inf before the first)."""
        now_s = self.clock() if now_s is None else now_s
        with self._lock:
            last = self._last_heard_s
        return math.inf if math.isnan(last) else max(0.0, now_s - last)

    def ok(self, now_s: float | None = None) -> bool:
        return self.silent_s(now_s) <= self.timeout_s


class AutopilotClock:
    """How fast the autopilot's clock runs against ours: a SITL or simulator sped up N times runs its timeouts
    (COM_OF_LOSS_T, FS_GCS_TIMEOUT) N times faster on our clock. From the autopilot's message times
    (``time_boot_ms``) and our receive times, over the whole run since its clock last started; 1 until ``min_s``
    of our time has passed. Thread-safe.

    >>> c = AutopilotClock()
    >>> for k in range(40): c.note(10.0 + 0.5 * k, 100.0 + 0.1 * k)  # 5 s of its time every second of ours
    >>> round(c.rate(), 3)
    5.0
    >>> c.note(29.45, 104.0); round(c.rate(), 3)  # a message stamped just before the last one changes nothing
    5.0
    """

    def __init__(self, min_s: float = 0.5):
        self.min_s = min_s
        self._lock = threading.Lock()
        self._first: tuple[float, float] | None = None
        self._last: tuple[float, float] | None = None

    def note(self, autopilot_s: float, our_s: float) -> None:
        """One message stamped ``autopilot_s`` (its time since boot) arrived at ``our_s`` (monotonic)."""
        if not math.isfinite(autopilot_s):
            return
        with self._lock:
            if self._last is not None and autopilot_s < self._last[0]:
                if autopilot_s > self._last[0] - 1.0:
                    return  # stamped a little earlier than the last one (another message kind): no news
                self._first = None  # it rebooted: start again
            if self._first is None:
                self._first = (autopilot_s, our_s)
            self._last = (autopilot_s, our_s)

    def rate(self) -> float:
        """Autopilot seconds per second of ours (1.0 while unknown), within [0.1, 1000]."""
        with self._lock:
            if self._first is None or self._last is None or self._last[1] - self._first[1] < self.min_s:
                return 1.0
            rate = (self._last[0] - self._first[0]) / (self._last[1] - self._first[1])
        return min(max(rate, 0.1), 1000.0)
