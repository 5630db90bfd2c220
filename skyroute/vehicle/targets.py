"""LANDING_TARGET -> :class:`TargetSighting` (SI, the autopilot's local frame), collected by a :class:`TargetFeed`.

A precision-landing beacon or a downward camera reports a ground target in LANDING_TARGET; with
``position_valid`` 1 its ``x, y, z`` are the target's position (m) in ``frame`` (MAV_FRAME_LOCAL_NED: the
autopilot's local NED frame, the one LOCAL_POSITION_NED is in). Sightings without a valid position, or in
another frame, are not placed and are dropped (counted in ``unplaced``). The exploration mission turns a
sighting's local position into the map frame with the mission's offset.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink


@dataclass(frozen=True)
class TargetSighting:
    """One target sighting: ``target_num``, its local NED position (m), ``distance_m`` slant range (m, NaN if
    not given), ``time_s`` the autopilot's time of the sample, ``received_s`` our monotonic clock."""

    target_num: int
    north_m: float
    east_m: float
    down_m: float
    distance_m: float
    time_s: float
    received_s: float


def sighting_from_landing_target(msg, received_s: float, scale_ne: tuple[float, float] = (1.0, 1.0)
                                 ) -> TargetSighting | None:
    """LANDING_TARGET -> :class:`TargetSighting`, or None when it gives no local position; ``scale_ne`` the
    autopilot's local metres per true metre (:func:`~.telemetry.local_scale`).

    >>> m = mavlink.MAVLink_landing_target_message(3_000_000, 2, mavlink.MAV_FRAME_LOCAL_NED, 0.1, 0.0, 5.1, 0.5,
    ...     0.5, x=12.0, y=-4.0, z=0.0, q=[1, 0, 0, 0], type=3, position_valid=1)
    >>> s = sighting_from_landing_target(m, 0.0)
    >>> s.target_num, s.north_m, s.east_m, s.time_s
    (2, 12.0, -4.0, 3.0)
    """
    if not getattr(msg, "position_valid", 0) or msg.frame != mavlink.MAV_FRAME_LOCAL_NED:
        return None
    distance = float(msg.distance) if msg.distance > 0 else float("nan")
    return TargetSighting(int(msg.target_num), float(msg.x) / scale_ne[0], float(msg.y) / scale_ne[1], float(msg.z),
                          distance, msg.time_usec * 1e-6, received_s)


class TargetFeed:
    """Thread-safe queue of sightings: the link's reader calls :meth:`handle`, the mission :meth:`drain`."""

    MESSAGES = ("LANDING_TARGET",)

    def __init__(self, keep: int = 256) -> None:
        self._lock = threading.Lock()
        self._queue: list[TargetSighting] = []
        self.keep = keep
        self.unplaced = 0
        self.sightings = 0

    def handle(self, msg, received_s: float, scale_ne: tuple[float, float] = (1.0, 1.0)) -> bool:
        """Translate and queue ``msg`` if it is a LANDING_TARGET; True if it was one."""
        if msg.get_type() not in self.MESSAGES:
            return False
        sighting = sighting_from_landing_target(msg, received_s, scale_ne)
        with self._lock:
            if sighting is None:
                self.unplaced += 1
                return True
            self.sightings += 1
            self._queue.append(sighting)
            del self._queue[:-self.keep]
        return True

    def drain(self) -> list[TargetSighting]:
        """Every sighting since the last call, oldest first."""
        with self._lock:
            out, self._queue = self._queue, []
            return out
