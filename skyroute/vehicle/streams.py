"""Telemetry streams: what we ask the autopilot to send, and asking again when it does not arrive.

Real ArduCopter streams almost nothing until asked, and a SET_MESSAGE_INTERVAL lost on a radio would mean no
position ever. :class:`StreamKeeper` tracks, per message, when it last arrived and when we last asked; a stream
that has not arrived within a few of its periods (while the link itself is alive) is due to be asked for again,
with backoff. ArduPilot autopilots that refuse SET_MESSAGE_INTERVAL get REQUEST_DATA_STREAM for the stream group
instead (:data:`ARDUPILOT_GROUPS`). Pure: the clock is passed in. Part of the ``vehicle`` package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

#: REQUEST_DATA_STREAM groups that carry each message on ArduPilot (its GCS_MAVLINK stream tables).
ARDUPILOT_GROUPS = {
    "GLOBAL_POSITION_INT": (mavlink.MAV_DATA_STREAM_POSITION,),
    "LOCAL_POSITION_NED": (mavlink.MAV_DATA_STREAM_POSITION,),
    "ATTITUDE": (mavlink.MAV_DATA_STREAM_EXTRA1,),
    "SYS_STATUS": (mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,),
    "GPS_RAW_INT": (mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,),
    "EXTENDED_SYS_STATE": (mavlink.MAV_DATA_STREAM_EXTENDED_STATUS, mavlink.MAV_DATA_STREAM_EXTRA3),
    "DISTANCE_SENSOR": (mavlink.MAV_DATA_STREAM_EXTRA3,),
}


@dataclass
class _Stream:
    name: str
    msg_id: int
    rate_hz: float
    last_rx_s: float = math.nan
    asked_s: float = math.nan
    asks: int = 0
    refused: bool = False


class StreamKeeper:
    """Which streams to (re-)request now.

    >>> k = StreamKeeper({"LOCAL_POSITION_NED": 50.0})
    >>> [s.name for s in k.due(now_s=0.0)]  # never asked
    ['LOCAL_POSITION_NED']
    >>> k.asked("LOCAL_POSITION_NED", 0.0); k.due(now_s=1.0)  # asked, give it time
    []
    >>> [s.name for s in k.due(now_s=2.5)]  # still nothing: ask again
    ['LOCAL_POSITION_NED']
    >>> k.received("LOCAL_POSITION_NED", 2.6); k.due(now_s=3.0)
    []
    """

    def __init__(self, rates_hz: dict[str, float], *, patience_s: float = 2.0, max_backoff_s: float = 10.0):
        self.patience_s, self.max_backoff_s = patience_s, max_backoff_s
        self._streams = {
            name: _Stream(name, getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), float(hz)) for name, hz in rates_hz.items()
        }

    def add(self, name: str, rate_hz: float) -> None:
        """Keep ``name`` at ``rate_hz`` from now on (a stream worth asking for only once the autopilot shows it has
        the sensor behind it).

        >>> k = StreamKeeper({}); k.add("DISTANCE_SENSOR", 10.0); [s.name for s in k.due(now_s=0.0)]
        ['DISTANCE_SENSOR']
        """
        stream = _Stream(name, getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), float(rate_hz))
        self._streams = {**self._streams, name: stream}  # a new dict: other threads may be iterating the old one

    def __contains__(self, name: str) -> bool:
        return name in self._streams

    def received(self, name: str, now_s: float) -> None:
        stream = self._streams.get(name)
        if stream is not None:
            stream.last_rx_s = now_s
            stream.asks = 0

    def asked(self, name: str, now_s: float, refused: bool = False) -> None:
        stream = self._streams[name]
        stream.asked_s, stream.refused = now_s, refused
        stream.asks += 1

    def due(self, now_s: float) -> list[_Stream]:
        """Streams never asked for, or silent for ``max(patience_s, 5 periods)`` since we last heard or asked."""
        out = []
        for s in self._streams.values():
            if math.isnan(s.asked_s):
                out.append(s)
                continue
            patience = max(self.patience_s, 5.0 / s.rate_hz)
            backoff = min(patience * 2 ** max(s.asks - 1, 0), self.max_backoff_s)
            heard_recently = now_s - s.last_rx_s <= patience  # False while NaN
            if not heard_recently and now_s - s.asked_s >= backoff:
                out.append(s)
        return out

    def silent(self, now_s: float) -> list[str]:
        """Names of the streams not heard within their patience (for progress messages)."""
        return [s.name for s in self._streams.values()
                if not now_s - s.last_rx_s <= max(self.patience_s, 5.0 / s.rate_hz)]
