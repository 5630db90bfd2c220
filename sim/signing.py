"""MAVLink 2 message signing with pymavlink's own support (``MAVLink.signing``).

``--signing-key KEY``: 64 hexadecimal characters are the 32-byte secret key itself; any other text is a passphrase
whose SHA-256 is the key, as MAVProxy's ``signing setup`` derives it (the project's client uses the same rule).
With a key the sim signs everything it sends and drops every frame that is unsigned, signed with another key or
replayed (an old timestamp), counting them per link (report ``signing``).
"""

from __future__ import annotations

import hashlib
import re
import time

#: MAVLink signing timestamps count 10 microsecond units since 2015-01-01 00:00 UTC.
SIGNING_EPOCH_UNIX_S = 1420070400
_HEX_KEY = re.compile(r"[0-9a-fA-F]{64}")


def secret_key(text: str) -> bytes:
    """The 32-byte secret key for ``--signing-key`` text.

    Raises
    ------
    ValueError
        For an empty key.

    >>> secret_key("00" * 32) == bytes(32)
    True
    >>> secret_key("hello").hex()[:16]
    '2cf24dba5fb0a30e'
    """
    if not text:
        raise ValueError("signing key must not be empty")
    if _HEX_KEY.fullmatch(text):
        return bytes.fromhex(text)
    return hashlib.sha256(text.encode("utf-8")).digest()


def enable(mav, key: bytes, link_id: int) -> None:
    """Sign what ``mav`` packs and make its ``decode`` refuse unsigned or badly signed frames.

    The unsigned-frame callback refuses everything, so that pymavlink counts refusals in
    ``mav.signing.reject_count``.
    """
    s = mav.signing
    s.secret_key = key
    s.sign_outgoing = True
    s.link_id = link_id & 0xFF
    s.timestamp = int((max(time.time(), SIGNING_EPOCH_UNIX_S) - SIGNING_EPOCH_UNIX_S) * 100_000)
    s.allow_unsigned_callback = _refuse_unsigned


def _refuse_unsigned(_mav, _msg_id: int) -> bool:
    return False


def rejected(mav) -> int:
    """Frames ``mav`` has refused for their signature so far."""
    return mav.signing.reject_count
