"""The transport: one pymavlink connection, MAVLink 2 from the first packet, optional signing, TCP reconnects.

:class:`Transport` opens any pymavlink connection string (a string pymavlink cannot open is a
:class:`~skyroute.vehicle.errors.BadConnection`, never a traceback), encodes every packet with one MAVLink 2
encoder (one sequence counter and, with a key, one signing state for the whole session), and when a TCP peer
closes the connection it reconnects with backoff instead of parking the reader. Part of the ``vehicle`` package.

Signing follows MAVProxy's ``signing setup``: a key given as 64 hexadecimal digits is the 32-byte secret itself,
any other text is hashed with SHA-256 (:func:`signing_key`). With a key every packet we send is signed, and
unsigned or wrongly signed packets we receive are dropped.
"""

from __future__ import annotations

import errno
import hashlib
import logging
import re
import socket
import threading
import time
from collections.abc import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .errors import BadConnection, ConnectionTimeout

log = logging.getLogger(__name__)

#: The connection types pymavlink knows, by prefix; anything else with a ``scheme:`` or ``scheme://`` is refused
#: before pymavlink guesses (it would take ``bogus://x`` for a UDP host "bogus" and port "//x").
SCHEMES = ("tcp", "tcpin", "udp", "udpin", "udpout", "udpbcast", "uds", "unix", "mcast", "ws", "wss", "wsserver")
_HOST_PORT = re.compile(r"^(?P<host>[^:]*):(?P<port>\d{1,5})$")
#: Reconnect backoff (s): doubles from the first to the last value.
BACKOFF_S = (0.1, 2.0)


def signing_key(text: str) -> bytes:
    """The 32-byte MAVLink 2 signing secret for ``--signing-key``: 64 hex digits as is, else SHA-256 of the text.

    >>> signing_key("00" * 32) == bytes(32)
    True
    >>> signing_key("secret").hex()[:16]  # sha256(b"secret")
    '2bb80d537b1da3e3'
    """
    text = text.strip()
    if re.fullmatch(r"[0-9a-fA-F]{64}", text):
        return bytes.fromhex(text)
    if not text:
        raise ValueError("the signing key is empty")
    return hashlib.sha256(text.encode("utf-8")).digest()


def check_connection_string(connection: str) -> None:
    """Raise :class:`BadConnection` for a string pymavlink would misread or cannot open (checked offline).

    >>> check_connection_string("tcp:127.0.0.1:5760")
    >>> check_connection_string("bogus://x")
    Traceback (most recent call last):
    ...
    skyroute.vehicle.errors.BadConnection: cannot open connection 'bogus://x': unknown connection type 'bogus' \
(use tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or a serial device)
    """
    hint = "use tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or a serial device"
    if not connection.strip():
        raise BadConnection(connection, f"empty ({hint})")
    scheme, sep, rest = connection.partition(":")
    if not sep or "/" in scheme or "\\" in scheme:
        return  # a serial device path: pymavlink opens it or says why not
    if scheme.lower() not in SCHEMES:
        raise BadConnection(connection, f"unknown connection type {scheme!r} ({hint})")
    if scheme.lower() in ("tcp", "tcpin", "udp", "udpin", "udpout", "udpbcast", "mcast"):
        match = _HOST_PORT.match(rest)
        if match is None:
            raise BadConnection(connection, f"{scheme} needs HOST:PORT, got {rest!r}")
        if not 0 < int(match["port"]) <= 65535:
            raise BadConnection(connection, f"port {match['port']} is not in 1..65535")


class Transport:
    """One MAVLink connection: thread-safe :meth:`send`, :meth:`recv` for one reader thread, TCP reconnects.

    Parameters
    ----------
    connection : str
        A pymavlink connection string (``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:HOST:PORT``, a device).
    source_system, source_component : int
        Our MAVLink identity.
    key : bytes, optional
        32-byte MAVLink 2 signing secret (:func:`signing_key`).
    connect_timeout_s : float
        How long to keep trying when a TCP peer refuses the connection (it may still be starting).
    on_packet : callable ``(bytes) -> None``, optional
        Called with every packet sent (for the tlog), under the send lock.

    Raises
    ------
    BadConnection
        pymavlink cannot open the string (unknown type, bad port, no such host or device).
    ConnectionTimeout
        A TCP peer kept refusing for ``connect_timeout_s``.
    """

    def __init__(self, connection: str, *, source_system: int, source_component: int, key: bytes | None = None,
                 connect_timeout_s: float = 10.0, on_packet: Callable[[bytes], None] | None = None):
        check_connection_string(connection)
        self.connection = connection
        self.source_system, self.source_component = source_system, source_component
        self.key = key
        self.on_packet = on_packet
        self.reconnects = 0
        self._send_lock = threading.Lock()
        self._closed = threading.Event()
        self._down = False
        self._signing = None
        self._seq = 0
        self._conn = self._open(connect_timeout_s)

    # ------------------------------------------------------------------------------------------ opening
    def _open(self, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                conn = mavutil.mavlink_connection(self.connection, source_system=self.source_system,
                                                  source_component=self.source_component, retries=0,
                                                  autoreconnect=False)
            except ConnectionRefusedError as exc:  # the autopilot may still be starting
                if time.monotonic() >= deadline or self._closed.is_set():
                    raise ConnectionTimeout(self.connection, timeout_s, str(exc)) from None
                time.sleep(0.2)
                continue
            except (OSError, ValueError, OverflowError) as exc:  # bad host/port, no device (SerialException)
                raise BadConnection(self.connection, _describe(exc)) from None
            self._install_encoder(conn)
            return conn

    def _install_encoder(self, conn) -> None:
        """Speak MAVLink 2 from our first packet, keep one sequence and signing state across reconnects."""
        mav = mavlink.MAVLink(conn, srcSystem=self.source_system, srcComponent=self.source_component)
        mav.robust_parsing = True
        mav.seq = self._seq
        conn.mav = mav
        conn.WIRE_PROTOCOL_VERSION = "2.0"
        if self.key is not None:
            if self._signing is None:
                conn.setup_signing(self.key, sign_outgoing=True, allow_unsigned_callback=None)
                self._signing = mav.signing
            else:
                mav.signing = self._signing  # timestamps must keep increasing
        mav.set_send_callback(self._sent)
        if hasattr(conn, "handle_eof"):  # TCP: note the peer closing instead of printing in a loop
            conn.handle_eof = self._peer_closed
            conn.handle_disconnect = self._peer_closed

    def _sent(self, msg) -> None:  # called by the encoder under _send_lock
        if self.on_packet is not None:
            self.on_packet(bytes(msg.get_msgbuf()))

    def _peer_closed(self) -> None:
        if not self._down and not self._closed.is_set():
            log.warning("the autopilot closed the connection %s", self.connection)
        self._down = True

    @property
    def reconnectable(self) -> bool:
        return self.connection.lower().startswith("tcp:")

    @property
    def up(self) -> bool:
        """False while a TCP connection is closed and being re-opened."""
        return not self._down

    @property
    def signing(self) -> bool:
        return self.key is not None

    # ------------------------------------------------------------------------------------ send, receive
    def send(self, msg) -> bool:
        """Encode and send one message; False if the connection is down (the message is dropped)."""
        with self._send_lock:
            if self._down or self._closed.is_set():
                return False
            try:
                self._conn.mav.send(msg)
            except OSError as exc:
                log.debug("send failed: %s", exc)
                if self.reconnectable:
                    self._down = True
                return False
            self._seq = self._conn.mav.seq
            return True

    def recv(self, timeout_s: float = 0.05):
        """The next decoded message, or None after ``timeout_s``; reconnects a closed TCP link (with backoff)."""
        if self._down:
            self._reconnect()
            return None
        conn = self._conn
        try:
            msg = conn.recv_msg()
        except OSError as exc:
            if not self._closed.is_set():
                log.warning("link read failed: %s", _describe(exc))
                if self.reconnectable:
                    self._down = True
                else:
                    time.sleep(timeout_s)
            return None
        if msg is None:
            if not self._down:
                try:
                    conn.select(timeout_s)
                except (OSError, ValueError):
                    time.sleep(timeout_s)
            return None
        return msg

    def _reconnect(self) -> None:
        if not self.reconnectable:
            time.sleep(0.05)
            return
        delay = BACKOFF_S[0]
        with self._send_lock:
            try:
                self._conn.close()
            except OSError:
                pass
        while not self._closed.is_set():
            try:
                conn = mavutil.mavlink_connection(self.connection, source_system=self.source_system,
                                                  source_component=self.source_component, retries=0,
                                                  autoreconnect=False)
            except (OSError, ValueError) as exc:
                log.debug("reconnect to %s failed (%s); again in %.1f s", self.connection, exc, delay)
                self._closed.wait(delay)
                delay = min(delay * 2, BACKOFF_S[1])
                continue
            with self._send_lock:
                self._install_encoder(conn)
                self._conn, self._down = conn, False
            self.reconnects += 1
            log.warning("reconnected to %s", self.connection)
            return

    def close(self) -> None:
        self._closed.set()
        with self._send_lock:
            try:
                self._conn.close()
            except (OSError, AttributeError):
                pass


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno in (errno.ENOENT, errno.ENODEV) and exc.strerror:
        return exc.strerror
    if isinstance(exc, socket.gaierror):
        return f"unknown host ({exc.strerror or exc})"
    return str(exc) or type(exc).__name__
