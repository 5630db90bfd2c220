"""Incoming byte stream to MAVLink messages, resynchronising after bytes that are not MAVLink.

pymavlink's own parser (``robust_parsing``) takes any 0xFD/0xFE byte as the start of a frame, waits
for the length that byte's "header" announces, and when that would-be frame fails its CRC throws all
of it away -- including the start of the genuine packet that followed the junk. Classic course code
writes raw bytes into the MAVLink TCP stream: FCND ``motion_planning.py`` ``send_waypoints()`` does
``connection._master.write(msgpack.dumps(waypoints))`` (the Unity simulator drew them), and msgpack
encodes -3 / -2 as 0xFD / 0xFE, so a waypoint list ending ``[n, -3, 5, 0]`` ate the next command.

:class:`FrameScanner` accepts a candidate frame only if it decodes (a message id this dialect knows,
CRC with its CRC_EXTRA correct); otherwise it skips one byte and looks for the next start marker.
While a candidate is still incomplete, a complete valid frame starting later in the buffer proves the
candidate was junk, so a stray marker with a large length byte cannot hold real packets back.
Skipped bytes are counted (``junk_bytes``) so the caller can report them; they are never an error.

With signing enabled on the decoder (:mod:`sim.signing`), a frame that is well formed but unsigned or
wrongly signed is dropped whole and counted in ``rejected_frames``.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

_V1, _V2 = mavlink.PROTOCOL_MARKER_V1, mavlink.PROTOCOL_MARKER_V2
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED


_REJECTED = object()


class FrameScanner:
    """Feed bytes, get decoded messages; see the module docstring.

    Parameters
    ----------
    mav : pymavlink MAVLink
        Used only for :meth:`decode` (signing state, if any); not for sending.
    """

    def __init__(self, mav: mavlink.MAVLink) -> None:
        self.mav = mav
        self.buf = bytearray()
        self.junk_bytes = 0  # total skipped on this stream
        self.rejected_frames = 0  # well-formed frames refused for their signature

    def feed(self, data: bytes) -> tuple[list, int]:
        """Add ``data``; return (messages now complete, bytes skipped as not MAVLink by this call)."""
        self.buf += data
        buf = self.buf
        out: list = []
        junk = 0
        i = 0
        while True:
            start = self._next_marker(i)
            if start < 0:
                junk += len(buf) - i
                i = len(buf)
                break
            junk += start - i
            i = start
            length = self._frame_length(i)
            if length == 0:  # impossible header: not a frame
                junk += 1
                i += 1
                continue
            if length is None or i + length > len(buf):  # incomplete
                later = self._later_valid_frame(i + 1)
                if later is None:
                    break  # wait for more bytes
                junk += later - i
                i = later
                continue
            msg = self._decode(i, length)
            if msg is _REJECTED:
                self.rejected_frames += 1
                i += length
                continue
            if msg is None:
                junk += 1
                i += 1
                continue
            out.append(msg)
            i += length
        del buf[:i]
        self.junk_bytes += junk
        return out, junk

    # ------------------------------------------------------------------ internals
    def _next_marker(self, i: int) -> int:
        a, b = self.buf.find(_V2, i), self.buf.find(_V1, i)
        if a < 0 or b < 0:
            return max(a, b)
        return min(a, b)

    def _frame_length(self, i: int) -> int | None:
        """Whole frame length at ``i``; None if the header is not all here yet; 0 if impossible."""
        buf = self.buf
        if buf[i] == _V1:
            if i + 1 >= len(buf):
                return None
            return mavlink.HEADER_LEN_V1 + buf[i + 1] + 2
        if i + 2 >= len(buf):
            return None
        incompat = buf[i + 2]
        if incompat & ~_SIGNED:
            return 0
        sig = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if incompat & _SIGNED else 0
        return mavlink.HEADER_LEN_V2 + buf[i + 1] + 2 + sig

    def _decode(self, i: int, length: int):
        refused = self.mav.signing.reject_count
        try:
            msg = self.mav.decode(bytearray(self.buf[i:i + length]))
        except mavlink.MAVError:
            # pymavlink checks the CRC before the signature: a refusal means a whole, valid frame.
            return _REJECTED if self.mav.signing.reject_count > refused else None
        if isinstance(msg, mavlink.MAVLink_unknown):  # no CRC_EXTRA to check it against
            return None
        return msg

    def _later_valid_frame(self, i: int) -> int | None:
        while True:
            start = self._next_marker(i)
            if start < 0:
                return None
            length = self._frame_length(start)
            if length and start + length <= len(self.buf) and self._decode_peek(start, length):
                return start
            i = start + 1

    def _decode_peek(self, start: int, length: int) -> bool:
        """Whether a whole frame starts at ``start``, without counting or consuming it."""
        signing = self.mav.signing
        counters = (signing.reject_count, signing.badsig_count, signing.goodsig_count, signing.unsigned_count,
                    signing.sig_count, dict(signing.stream_timestamps), signing.timestamp)
        try:
            return self._decode(start, length) is not None
        finally:
            (signing.reject_count, signing.badsig_count, signing.goodsig_count, signing.unsigned_count,
             signing.sig_count, stream_timestamps, signing.timestamp) = counters
            signing.stream_timestamps = stream_timestamps
