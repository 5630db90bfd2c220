"""Parameters: PARAM_VALUE decoded with the autopilot's own encoding.

PARAM_VALUE carries every value in a float field. ArduPilot (and our sim) converts integers to that float
("C cast": INT32 5 is sent as 5.0). PX4 copies the integer's bytes into the float ("bytewise": INT32 5 is the
float whose bits are 0x00000005) and says so with MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE in
AUTOPILOT_VERSION. Part of the ``vehicle`` package.
"""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .telemetry import Autopilot

#: MAV_PARAM_TYPE -> struct format of the integer held in the float's four bytes (little endian).
_BYTEWISE_FORMATS = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B3x",
    mavlink.MAV_PARAM_TYPE_INT8: "<b3x",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H2x",
    mavlink.MAV_PARAM_TYPE_INT16: "<h2x",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}
_FLOAT_TYPES = (mavlink.MAV_PARAM_TYPE_REAL32, mavlink.MAV_PARAM_TYPE_REAL64)


def bytewise_encoding(autopilot: Autopilot, capabilities: int | None) -> bool:
    """True if integer parameters come bytewise: AUTOPILOT_VERSION says so, or (no answer yet) it is PX4.

    >>> bytewise_encoding(Autopilot.PX4, None), bytewise_encoding(Autopilot.PX4, 0)
    (True, False)
    """
    if capabilities is not None:
        return bool(capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    return autopilot is Autopilot.PX4


def decode_param_value(value: float, param_type: int, bytewise: bool) -> float:
    """The parameter's value from PARAM_VALUE's ``param_value`` and ``param_type``.

    >>> decode_param_value(5.0, mavlink.MAV_PARAM_TYPE_INT32, bytewise=False)
    5.0
    >>> bits = struct.unpack("<f", struct.pack("<i", 5))[0]  # how PX4 sends INT32 5
    >>> decode_param_value(bits, mavlink.MAV_PARAM_TYPE_INT32, bytewise=True)
    5.0
    """
    if param_type in _FLOAT_TYPES or not bytewise:
        return float(value)
    fmt = _BYTEWISE_FORMATS.get(param_type)
    if fmt is None:  # 64-bit integers do not fit the float field; take it as sent
        return float(value)
    return float(struct.unpack(fmt, struct.pack("<f", value))[0])


def param_name(raw: bytes | str) -> str:
    """PARAM_VALUE's ``param_id`` as text (NUL-padded to 16 bytes on the wire)."""
    text = raw.decode("ascii", errors="replace") if isinstance(raw, bytes | bytearray) else str(raw)
    return text.split("\x00", 1)[0]
