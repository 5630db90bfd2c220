"""The MAVLink command protocol: COMMAND_LONG out, its own COMMAND_ACK back.

An ack counts only if it answers this command (``command``), is addressed to us (``target_system`` and
``target_component`` ours, or 0 from autopilots that do not fill them) and comes from the autopilot we sent it
to, so a ground station's acks on the same link cannot satisfy ours. One command of a kind is in flight at a
time (five back-to-back SET_MESSAGE_INTERVALs could not be told apart otherwise). IN_PROGRESS means wait for
the final ack, never resend; no ack means resend with ``confirmation`` incremented, unless the caller can see the
command's effect in the telemetry (``done``: the heartbeat's mode, its armed flag) and sees it: then the command
was taken and its ack lost, as on a lossy radio link, and resending or failing would be wrong. TEMPORARILY_REJECTED
is retried when the caller asks (PX4 accepts OFFBOARD only once setpoints stream). Part of the ``vehicle`` package.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .errors import CommandRejected, CommandTimeout, LinkLost, command_name, result_name
from .health import LinkHealth

log = logging.getLogger(__name__)


@dataclass
class _Pending:
    command: int
    target: tuple[int, int]
    acks: list = field(default_factory=list)


def ack_matches(ack, command: int, target: tuple[int, int], us: tuple[int, int], source: tuple[int, int]) -> bool:
    """True if COMMAND_ACK ``ack`` from ``source`` answers ``command`` sent by ``us`` to ``target``.

    >>> from types import SimpleNamespace as Ack
    >>> ack = Ack(command=400, target_system=255, target_component=191)
    >>> ack_matches(ack, 400, (1, 1), (255, 191), (1, 1)), ack_matches(ack, 400, (1, 1), (255, 190), (1, 1))
    (True, False)
    """
    if ack.command != command or source != target:
        return False
    return (getattr(ack, "target_system", 0) in (0, us[0])
            and getattr(ack, "target_component", 0) in (0, us[1]))


class Commander:
    """Sends COMMAND_LONGs and waits for their acks; the reader thread feeds acks to :meth:`on_ack`.

    Parameters
    ----------
    send : callable ``(message) -> bool``
        Sends a pymavlink message (False if the link is down).
    us : (int, int)
        Our system and component ids.
    health : LinkHealth
        Gets a round-trip sample from each ack that answers a single send; says whether the link is alive.
    reason : callable ``(command, since_s, until_s) -> str | None``
        The autopilot's text about a refusal received in that window (after a short grace for trailing texts).
    """

    def __init__(self, send: Callable[[object], bool], us: tuple[int, int], health: LinkHealth,
                 reason: Callable[[int, float, float], str | None], clock: Callable[[], float] = time.monotonic):
        self.send, self.us, self.health, self.reason, self.clock = send, us, health, reason, clock
        self._cond = threading.Condition()
        self._pending: dict[int, _Pending] = {}
        self._locks: dict[int, threading.Lock] = collections.defaultdict(threading.Lock)
        self._locks_lock = threading.Lock()
        self._closed = False

    def close(self) -> None:
        """Wake every waiting command: they fail with :class:`LinkLost` (the link is being closed)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def on_ack(self, ack, source: tuple[int, int]) -> None:
        with self._cond:
            pending = self._pending.get(ack.command)
            if pending is not None and ack_matches(ack, pending.command, pending.target, self.us, source):
                pending.acks.append(ack)
                self._cond.notify_all()

    def _lock(self, command: int) -> threading.Lock:
        with self._locks_lock:
            return self._locks[command]

    def run(self, target: tuple[int, int], command: int, *params: float, timeout_s: float = 1.5,
            retries: int = 3, in_progress_timeout_s: float = 30.0, retry_temporary_s: float = 0.0,
            done: Callable[[], bool] | None = None):
        """Send ``command`` to ``target`` and return its ACCEPTED ack; None when an attempt went unanswered but
        ``done()`` (the command's effect, seen in the telemetry) is true: the command was taken, its ack lost.

        Raises
        ------
        CommandRejected
            A final result other than ACCEPTED (TEMPORARILY_REJECTED only after ``retry_temporary_s``), with the
            autopilot's text about it.
        CommandTimeout
            No final ack after ``1 + retries`` sends (or IN_PROGRESS for longer than ``in_progress_timeout_s``).
        LinkLost
            The link was silent before sending, or when the retries ran out.
        """
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self._check_link()
        give_up_temporary = self.clock() + retry_temporary_s
        with self._lock(command):
            while True:
                started = self.clock()
                ack = self._exchange(target, command, p, timeout_s, retries, in_progress_timeout_s, done)
                if ack is None:
                    return None
                if ack.result == mavlink.MAV_RESULT_ACCEPTED:
                    return ack
                if ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED and self.clock() < give_up_temporary:
                    log.debug("%s temporarily rejected; retrying", command_name(command))
                    time.sleep(min(0.3, max(give_up_temporary - self.clock(), 0.0)))
                    continue
                raise CommandRejected(command, ack.result, self.reason(command, started - 0.2, self.clock()))

    def _exchange(self, target, command, p, timeout_s, retries, in_progress_timeout_s, done=None):
        """One command until its final ack (resending on silence); returns the ack, or None once an unanswered
        attempt's effect is seen (``done``)."""
        attempt_timeout_s = max(timeout_s, 2.0 * self.health.rtt_s + 0.3)
        with self._cond:
            self._pending[command] = _Pending(command, target)
        try:
            for confirmation in range(retries + 1):
                sent_s = self.clock()
                self.send(mavlink.MAVLink_command_long_message(target[0], target[1], command, confirmation, *p))
                ack = self._wait_final(command, attempt_timeout_s, in_progress_timeout_s)
                if ack is None:
                    log.debug("no ack for %s (attempt %d)", command_name(command), confirmation + 1)
                    if done is not None and done():
                        log.info("no ack for %s, but the telemetry shows it taken: the ack was lost",
                                 command_name(command))
                        return None
                    if not self.health.ok():
                        break
                    continue
                if confirmation == 0:
                    self.health.round_trip(self.clock() - sent_s)
                return ack
        finally:
            with self._cond:
                self._pending.pop(command, None)
        self._check_link()
        raise CommandTimeout(command, retries + 1, attempt_timeout_s)

    def _wait_final(self, command: int, timeout_s: float, in_progress_timeout_s: float):
        deadline = self.clock() + timeout_s
        in_progress_until = None
        with self._cond:
            while True:
                pending = self._pending[command]
                while pending.acks:
                    ack = pending.acks.pop(0)
                    if ack.result != mavlink.MAV_RESULT_IN_PROGRESS:
                        return ack
                    if in_progress_until is None:
                        in_progress_until = self.clock() + in_progress_timeout_s
                        log.debug("%s in progress (%s %%)", command_name(command), getattr(ack, "progress", "?"))
                    deadline = min(in_progress_until, self.clock() + max(timeout_s, 5.0))
                remaining = deadline - self.clock()
                if self._closed:
                    raise LinkLost(0.0)
                if remaining <= 0:
                    if in_progress_until is not None:
                        raise CommandTimeout(command, 1, in_progress_timeout_s,
                                             f"still {result_name(mavlink.MAV_RESULT_IN_PROGRESS)}")
                    return None
                self._cond.wait(timeout=min(remaining, 0.5))

    def _check_link(self) -> None:
        if not self.health.ok():
            raise LinkLost(self.health.silent_s(), self.health.timeout_s)
