"""TCP transport (several clients at once) and the tlog writer.

Everything here runs on the simulation thread: a non-blocking listening socket and client sockets
multiplexed with :mod:`selectors`. Each client gets its own pymavlink encoder (own sequence numbers
and, with a signing key, its own signing state), its own fault injector and its own stream rates.
Link faults (latency, loss, outage) are applied in simulated time (:mod:`sim.faults`).
"""

from __future__ import annotations

import collections
import logging
import selectors
import socket
import struct
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from . import signing
from .commands import LinkState
from .faults import FaultConfig, LinkFaults
from .framing import FrameScanner
from .telemetry import COMPONENT_ID, SYSTEM_ID

log = logging.getLogger(__name__)

#: Drop a client whose unsent output exceeds this (bytes): it has stopped reading.
MAX_BACKLOG_BYTES = 4 * 1024 * 1024


class TcpLink(LinkState):
    """One connected client."""

    def __init__(self, link_id: int, sock: socket.socket, peer: str, faults: LinkFaults,
                 signing_key: bytes | None = None) -> None:
        super().__init__(link_id)
        self.sock = sock
        self.peer = peer
        self.faults = faults
        self.mav = mavlink.MAVLink(None, SYSTEM_ID, COMPONENT_ID)
        if signing_key is not None:
            signing.enable(self.mav, signing_key, link_id)
        self.scanner = FrameScanner(self.mav)
        self.rejected_reported = 0
        self.junk_unreported = 0  # bytes skipped as not MAVLink, not yet reported by the simulator
        self.out_buf = bytearray()
        self.delayed_out: collections.deque = collections.deque()
        self.delayed_in: collections.deque = collections.deque()
        self.closed = False
        self.packets_in = 0
        self.packets_out = 0

    def queue(self, msg, sim_s: float) -> None:
        """Pack ``msg`` for this link (sequence number advances even if the packet is then lost)."""
        data = msg.pack(self.mav)
        self.packets_out += 1
        if self.faults.drop_out(sim_s):
            return
        delay = self.faults.delay_s
        if delay > 0:
            self.delayed_out.append((sim_s + delay, data))
        else:
            self.out_buf += data

    def stats(self) -> dict:
        """Packet counts of this link for the report."""
        return {
            "link": self.link_id, "peer": self.peer, "packets_in": self.packets_in, "packets_out": self.packets_out,
            "dropped_in": self.faults.dropped_in, "dropped_out": self.faults.dropped_out,
            "rejected_signature": self.scanner.rejected_frames, "junk_bytes": self.scanner.junk_bytes,
        }

    def receive(self, sim_s: float) -> list:
        """Read what the socket has; return messages whose (latency-delayed) arrival is due."""
        try:
            data = self.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            data = None
        except OSError:
            data = b""
        if data == b"":
            self.closed = True
        elif data:
            msgs, junk = self.scanner.feed(data)
            self.junk_unreported += junk
            for msg in msgs:
                self.packets_in += 1
                if self.faults.drop_in(sim_s):
                    continue
                self.delayed_in.append((sim_s + self.faults.delay_s, msg))
        return self.due_in(sim_s)

    def due_in(self, sim_s: float) -> list:
        out = []
        while self.delayed_in and self.delayed_in[0][0] <= sim_s + 1e-9:
            out.append(self.delayed_in.popleft()[1])
        return out

    def flush(self, sim_s: float) -> None:
        while self.delayed_out and self.delayed_out[0][0] <= sim_s + 1e-9:
            self.out_buf += self.delayed_out.popleft()[1]
        if not self.out_buf or self.closed:
            return
        try:
            sent = self.sock.send(self.out_buf)
            del self.out_buf[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self.closed = True
        if len(self.out_buf) > MAX_BACKLOG_BYTES:
            log.warning("link %d: client not reading, dropping it", self.link_id)
            self.closed = True

    def close(self) -> None:
        self.closed = True
        try:
            self.sock.close()
        except OSError:
            pass


class TlogLink(LinkState):
    """A pseudo-link that writes a MAVLink telemetry log.

    Format: for each packet an 8-byte big-endian Unix time in microseconds, then the raw packet, as
    written by MAVProxy and read by ``pymavlink.mavutil.mavlink_connection(path)``.
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__(link_id=0)
        self.path = Path(path)
        self.file = self.path.open("wb")
        self.mav = mavlink.MAVLink(None, SYSTEM_ID, COMPONENT_ID)

    def _write(self, data: bytes) -> None:
        if not self.file.closed:
            self.file.write(struct.pack(">Q", int(time.time() * 1e6)) + bytes(data))

    def queue(self, msg, sim_s: float) -> None:
        self._write(msg.pack(self.mav))

    def record_incoming(self, msg) -> None:
        self._write(msg.get_msgbuf())

    def flush(self, sim_s: float) -> None:
        pass

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()


class TcpServer:
    """Listening socket plus connected :class:`TcpLink` objects.

    Parameters
    ----------
    host, port : str, int
        Address to bind; port 0 = ephemeral.
    faults : FaultConfig
        Applied to every link.
    seed : int
        Seed for per-link packet loss.
    signing_key : bytes or None
        With a key every link signs what it sends and drops unsigned or wrongly signed frames.
    """

    def __init__(self, host: str, port: int, faults: FaultConfig, seed: int,
                 signing_key: bytes | None = None) -> None:
        self.faults = faults
        self.seed = seed
        self.signing_key = signing_key
        self.closed_stats: list[dict] = []
        self.selector = selectors.DefaultSelector()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((host, port))
        except OSError:
            self.listener.close()
            raise
        self.listener.listen(8)
        self.listener.setblocking(False)
        self.selector.register(self.listener, selectors.EVENT_READ, None)
        self.host, self.port = self.listener.getsockname()[:2]
        self.links: list[TcpLink] = []
        self._next_id = 1

    def poll(self, timeout_s: float, sim_s: float):
        """Wait up to ``timeout_s`` for I/O.

        Returns
        -------
        new_links : list of TcpLink
        messages : list of (TcpLink, message)
        closed : list of TcpLink
        """
        new_links, messages, closed = [], [], []
        for key, _events in self.selector.select(max(0.0, timeout_s)):
            if key.data is None:
                try:
                    sock, addr = self.listener.accept()
                except (BlockingIOError, InterruptedError):
                    continue
                sock.setblocking(False)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                link = TcpLink(self._next_id, sock, f"{addr[0]}:{addr[1]}",
                               LinkFaults(self.faults, self.seed, self._next_id), self.signing_key)
                self._next_id += 1
                self.selector.register(sock, selectors.EVENT_READ, link)
                self.links.append(link)
                new_links.append(link)
            else:
                link = key.data
                messages += [(link, m) for m in link.receive(sim_s)]
        for link in self.links:
            if link.delayed_in:
                messages += [(link, m) for m in link.due_in(sim_s)]
            if link.closed:
                closed.append(link)
        for link in closed:
            self._drop(link)
        return new_links, messages, closed

    def _drop(self, link: TcpLink) -> None:
        try:
            self.selector.unregister(link.sock)
        except (KeyError, ValueError):
            pass
        link.close()
        if link in self.links:
            self.links.remove(link)
            self.closed_stats.append(link.stats())

    def stats(self) -> list[dict]:
        """Packet counts of every link so far, closed ones first."""
        return self.closed_stats + [link.stats() for link in self.links]

    def close(self, sim_s: float) -> None:
        for link in list(self.links):
            link.flush(sim_s)
            self._drop(link)
        try:
            self.selector.unregister(self.listener)
        except (KeyError, ValueError):
            pass
        self.listener.close()
        self.selector.close()
