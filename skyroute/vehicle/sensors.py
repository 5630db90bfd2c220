"""Obstacle sensor messages -> SI readings: :class:`RangeScan` (horizontal sectors) and :class:`HeightReading`.

Translated at the vehicle boundary like the rest of the telemetry (part of the ``vehicle`` package, the only code
that imports pymavlink), and collected by a :class:`SensorFeed` that the link's reader thread feeds and the
mission drains.

What the autopilots send (``sim/sensors.py`` streams the same):

* OBSTACLE_DISTANCE (PX4's collision-prevention map; any MAVLink range sensor): ``distances[i]`` in cm for the
  sector centred on ``angle_offset + i * increment`` degrees, in ``frame`` MAV_FRAME_GLOBAL / LOCAL_NED (from
  north) or BODY_FRD (from the nose); ``increment_f`` overrides ``increment`` when set. ``UINT16_MAX`` = unknown,
  ``> max_distance`` = nothing within range; a reading below ``min_distance`` is kept as an obstacle that close
  (the spec: 0 means right in front of the sensor).
* DISTANCE_SENSOR with a horizontal orientation (MAV_SENSOR_ROTATION_NONE .. YAW_315, from the nose; ArduPilot's
  AP_Proximity sends one per 45 degree sector): one sector, ``horizontal_fov`` wide when given, else the
  orientation step (45 degrees). ``current_distance >= max_distance`` = nothing within range (ArduPilot reports an
  empty sector as its maximum), ``UINT16_MAX`` = unknown. PITCH_270 (downward) is the height above what is below.
  Other orientations (up, pitched) are ignored.

Bearings are radians clockwise from north in ``[0, 2 pi)``; body-frame ones are turned by the vehicle's heading
at translation time (the latest ATTITUDE). Distances in metres, ``inf`` = nothing within ``max_range_m``, ``NaN``
= unknown.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

UINT16_MAX = 65535
#: Horizontal orientations and their bearing from the nose (degrees).
_YAW_ORIENTATIONS = {getattr(mavlink, f"MAV_SENSOR_ROTATION_{name}"): deg for name, deg in (
    ("NONE", 0), ("YAW_45", 45), ("YAW_90", 90), ("YAW_135", 135), ("YAW_180", 180), ("YAW_225", 225),
    ("YAW_270", 270), ("YAW_315", 315))}
_NORTH_FRAMES = {mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_LOCAL_NED}
_TWO_PI = 2.0 * math.pi
#: How far a heading-relative sector's bearing may be off when all we know is the latest heading: ArduCopter yaws
#: at up to ~90 deg/s and the heading comes with ATTITUDE at 10 Hz, so up to ~10 degrees, with room for the
#: sensor's own sample time.
HEADING_LAG_RAD = math.radians(15.0)
#: Given the heading's own time and rate (ATTITUDE's time_boot_ms and yawspeed), the heading is carried on to the
#: reading's time, and the allowance is this much plus the rate times :data:`HEADING_RATE_WINDOW_S` (a rate that
#: changes within that window), never more than :data:`HEADING_LAG_RAD`. A 15 degree allowance on a 45 degree
#: sector down a street widens the wedge over the street's buildings, whose nearer range then "explains" a wall
#: standing in the street until it is ~10 m away.
HEADING_BASE_ERROR_RAD, HEADING_RATE_WINDOW_S = math.radians(3.0), 0.2
#: Carry the heading on over at most this long (s); a reading further from the heading's time keeps
#: :data:`HEADING_LAG_RAD`.
HEADING_MAX_CARRY_S = 0.5
#: A scan is placed at the position estimate, which may be off by this many times the GPS receiver's reported
#: horizontal accuracy (GPS_RAW_INT h_acc, about one standard deviation; 3: a drift beyond it is ~1 % of the time,
#: 2 left a false replan every ~100 m with 1.5 m of drift): the live layer takes a reading that close to the map's
#: buildings for theirs (:attr:`RangeScan.position_error_m`).
POSITION_ERROR_PER_ACCURACY = 3.0


@dataclass(frozen=True)
class RangeScan:
    """Horizontal range sectors around the vehicle, in SI units.

    ``bearings_rad`` (K,) each sector's centre (clockwise from north), ``half_width_rad`` the sectors' half width,
    ``distances_m`` (K,) to the nearest obstacle in the sector (``inf`` none within ``max_range_m``, ``NaN``
    unknown), ``min_range_m`` / ``max_range_m`` the sensor's limits, ``time_s`` the autopilot's time since boot of
    the sample, ``received_s`` our monotonic clock when it arrived, ``source`` the message name, ``local_ne`` the
    vehicle's latest local position (autopilot's NED frame, north and east m) when it arrived and ``local_down_m``
    its down coordinate (None: not known): the scan is placed there, not where the vehicle is when the mission gets
    round to it (a poll later), and a scan taken low (climbing, landing) can be told apart. ``bearing_error_rad``
    is how far the bearings may be off: 0 for a north-aligned scan, :data:`HEADING_LAG_RAD` for one turned by the
    heading (the latest ATTITUDE lags a yawing vehicle). ``position_error_m`` is how far the position it is placed
    at may be off (m; 0 unknown): :data:`POSITION_ERROR_PER_ACCURACY` times the receiver's horizontal accuracy.
    """

    bearings_rad: np.ndarray
    half_width_rad: float
    distances_m: np.ndarray
    min_range_m: float
    max_range_m: float
    time_s: float
    received_s: float
    source: str
    local_ne: tuple[float, float] | None = None
    local_down_m: float | None = None
    bearing_error_rad: float = 0.0
    position_error_m: float = 0.0


@dataclass(frozen=True)
class HeightReading:
    """The downward rangefinder: ``height_m`` above what is below (``inf`` beyond ``max_range_m``, NaN unknown)."""

    height_m: float
    min_range_m: float
    max_range_m: float
    time_s: float
    received_s: float


def _cm_to_m(value: int, min_cm: int, max_cm: int, empty_at_max: bool) -> float:
    if value == UINT16_MAX:
        return math.nan
    if value > max_cm or (empty_at_max and value >= max_cm):
        return math.inf
    return value / 100.0


def scan_from_obstacle_distance(msg, received_s: float, heading_rad: float) -> RangeScan | None:
    """OBSTACLE_DISTANCE -> :class:`RangeScan`; None for a body-frame scan without a known heading, or no sectors.

    >>> m = mavlink.MAVLink_obstacle_distance_message(2_000_000, 0, [2500] + [3001] * 71, 5, 20, 3000,
    ...                                               increment_f=5.0, frame=mavlink.MAV_FRAME_GLOBAL)
    >>> s = scan_from_obstacle_distance(m, 0.0, math.nan)
    >>> len(s.bearings_rad), float(s.distances_m[0]), bool(np.isinf(s.distances_m[1])), s.time_s
    (72, 25.0, True, 2.0)
    """
    increment = float(msg.increment_f) if msg.increment_f > 0 else float(msg.increment)
    if not increment > 0:
        return None
    count = min(len(msg.distances), int(round(360.0 / increment)))
    if msg.frame in _NORTH_FRAMES:
        base = 0.0
    elif msg.frame == mavlink.MAV_FRAME_BODY_FRD:
        if not math.isfinite(heading_rad):
            return None
        base = heading_rad
    else:
        return None
    raw = list(msg.distances[:count])
    distances = np.array([_cm_to_m(v, msg.min_distance, msg.max_distance, empty_at_max=False) for v in raw])
    bearings = (base + np.radians(float(msg.angle_offset) + increment * np.arange(count))) % _TWO_PI
    return RangeScan(bearings, math.radians(increment) / 2.0, distances, msg.min_distance / 100.0,
                     msg.max_distance / 100.0, msg.time_usec * 1e-6, received_s, "OBSTACLE_DISTANCE",
                     bearing_error_rad=HEADING_LAG_RAD if msg.frame == mavlink.MAV_FRAME_BODY_FRD else 0.0)


def reading_from_distance_sensor(msg, received_s: float, heading_rad: float) -> RangeScan | HeightReading | None:
    """DISTANCE_SENSOR -> a one-sector :class:`RangeScan` (horizontal), a :class:`HeightReading` (downward), or
    None (another orientation, or a horizontal one without a known heading).

    >>> m = mavlink.MAVLink_distance_sensor_message(1500, 20, 3000, 1800, 0, 12, mavlink.MAV_SENSOR_ROTATION_YAW_90, 0)
    >>> s = reading_from_distance_sensor(m, 0.0, math.radians(90.0))   # nose east: the sector looks south
    >>> round(math.degrees(s.bearings_rad[0])), float(s.distances_m[0]), round(math.degrees(s.half_width_rad), 1)
    (180, 18.0, 22.5)
    """
    if msg.orientation == mavlink.MAV_SENSOR_ROTATION_PITCH_270:
        height = _cm_to_m(msg.current_distance, msg.min_distance, msg.max_distance, empty_at_max=True)
        return HeightReading(height, msg.min_distance / 100.0, msg.max_distance / 100.0, msg.time_boot_ms * 1e-3,
                             received_s)
    deg = _YAW_ORIENTATIONS.get(msg.orientation)
    if deg is None or not math.isfinite(heading_rad):
        return None
    fov = float(getattr(msg, "horizontal_fov", 0.0) or 0.0)
    half = fov / 2.0 if fov > 0 else math.radians(22.5)
    distance = _cm_to_m(msg.current_distance, msg.min_distance, msg.max_distance, empty_at_max=True)
    bearing = (heading_rad + math.radians(deg)) % _TWO_PI
    return RangeScan(np.array([bearing]), half, np.array([distance]), msg.min_distance / 100.0,
                     msg.max_distance / 100.0, msg.time_boot_ms * 1e-3, received_s, "DISTANCE_SENSOR",
                     bearing_error_rad=HEADING_LAG_RAD)


def heading_allowance_rad(yaw_rate_rad_s: float) -> float:
    """How far a heading carried on at ``yaw_rate_rad_s`` to a reading's time may still be off (rad).

    >>> [round(math.degrees(heading_allowance_rad(math.radians(rate))), 1) for rate in (0.0, 30.0, 90.0)]
    [3.0, 9.0, 15.0]
    """
    rate = abs(float(yaw_rate_rad_s)) if math.isfinite(yaw_rate_rad_s) else math.inf
    return min(HEADING_BASE_ERROR_RAD + rate * HEADING_RATE_WINDOW_S, HEADING_LAG_RAD)


def carry_heading(scan: RangeScan, heading_time_s: float, yaw_rate_rad_s: float) -> RangeScan:
    """A heading-relative ``scan`` (turned by a heading sampled at ``heading_time_s``, turning at
    ``yaw_rate_rad_s``) turned on by the yaw between then and its own ``time_s``, with the smaller allowance of
    :func:`heading_allowance_rad`; unchanged when the times or the rate are unknown or too far apart.

    >>> s = RangeScan(np.array([math.radians(90.0)]), math.radians(22.5), np.array([20.0]), 0.2, 30.0, 10.1, 0.0, "")
    >>> c = carry_heading(s, 10.0, math.radians(20.0))   # the heading is 0.1 s older, turning at 20 deg/s
    >>> round(math.degrees(c.bearings_rad[0]), 1), round(math.degrees(c.bearing_error_rad), 1)
    (92.0, 7.0)
    """
    dt = float(scan.time_s) - float(heading_time_s)
    if not (math.isfinite(dt) and abs(dt) <= HEADING_MAX_CARRY_S and math.isfinite(yaw_rate_rad_s)):
        return scan
    bearings = (np.asarray(scan.bearings_rad, float) + float(yaw_rate_rad_s) * dt) % _TWO_PI
    return dataclasses.replace(scan, bearings_rad=bearings, bearing_error_rad=heading_allowance_rad(yaw_rate_rad_s))


def translate_sensor(msg, received_s: float, heading_rad: float) -> RangeScan | HeightReading | None:
    """Any sensor message -> its reading (None for messages that are not, or cannot be placed)."""
    kind = msg.get_type()
    if kind == "OBSTACLE_DISTANCE":
        return scan_from_obstacle_distance(msg, received_s, heading_rad)
    if kind == "DISTANCE_SENSOR":
        return reading_from_distance_sensor(msg, received_s, heading_rad)
    return None


@dataclass(frozen=True)
class _Sector:
    """A proximity sector as queued, with the orientation it came with."""

    scan: RangeScan
    orientation: int


class SensorFeed:
    """Thread-safe queue of sensor readings: the link's reader calls :meth:`handle`, the mission :meth:`drain`.

    ``keep`` readings at most are queued (the oldest are dropped, counted in ``dropped``); ``streaming_s`` is how
    recent a horizontal scan must be for :attr:`streaming`.
    """

    MESSAGES = ("OBSTACLE_DISTANCE", "DISTANCE_SENSOR")

    def __init__(self, keep: int = 512, streaming_s: float = 2.0, clock=time.monotonic) -> None:
        self._queue: deque = deque(maxlen=keep)
        self._cond = threading.Condition()
        self.clock = clock
        self.streaming_s = streaming_s
        self.dropped = 0
        self.scans = 0
        self.last_scan_s = math.nan
        self.height: HeightReading | None = None
        self.turning_dropped = 0
        self._heading: tuple[float, float] | None = None  # (heading_rad, time_s) when it last changed
        self._yaw_rate_rad_s = 0.0
        self._sectors_sent: set[int] = set()  # proximity orientations (DISTANCE_SENSOR) seen so far
        self._sample_first: _Sector | None = None  # the first proximity sector of the latest sample

    #: Above this yaw rate (rad/s) heading-relative sectors are dropped: the heading that turns them lags.
    MAX_YAW_RATE_RAD_S = math.radians(30.0)
    #: A scan more than this (s) from the latest local position sample keeps that position as it is (an autopilot
    #: whose scans carry another clock, e.g. UNIX time, is not moved kilometres).
    MAX_EXTRAPOLATION_S = 0.5

    def _note_heading(self, heading_rad: float, reading) -> None:
        """Track the yaw rate from the headings the readings came with (their sample times)."""
        t = float(getattr(reading, "time_s", math.nan))
        if not (math.isfinite(heading_rad) and math.isfinite(t)):
            return
        if self._heading is None:
            self._heading = (heading_rad, t)
            return
        h0, t0 = self._heading
        turned = abs((heading_rad - h0 + math.pi) % _TWO_PI - math.pi)
        if turned > 1e-6 and t > t0:
            self._yaw_rate_rad_s = turned / (t - t0)
            self._heading = (heading_rad, t)
        elif t - t0 > 0.5:  # the heading has held for half a second: not turning
            self._yaw_rate_rad_s = 0.0

    @property
    def turning(self) -> bool:
        """True while the vehicle yaws faster than :attr:`MAX_YAW_RATE_RAD_S`."""
        return self._yaw_rate_rad_s > self.MAX_YAW_RATE_RAD_S

    def handle(self, msg, received_s: float, heading_rad: float,
               local_ne: tuple[float, float] | None = None, local_down_m: float | None = None, *,
               local_time_s: float = math.nan, local_velocity_ned: tuple[float, float, float] | None = None,
               heading_time_s: float = math.nan, yaw_rate_rad_s: float = math.nan,
               horizontal_accuracy_m: float = math.nan) -> bool:
        """Translate and queue ``msg`` if it is a sensor message; True if it was one.

        ``horizontal_accuracy_m``: the GPS receiver's latest horizontal accuracy (m, NaN unknown), which sets the
        scan's ``position_error_m``.

        ``local_ne``, ``local_down_m``: the vehicle's latest local position (m), sampled at ``local_time_s`` (the
        autopilot's seconds since boot) and moving at ``local_velocity_ned`` (m/s). A horizontal scan is stamped
        with where the vehicle was at the scan's own time: that position moved on by the velocity for the
        difference, up to :attr:`MAX_EXTRAPOLATION_S` (the two messages are not sampled together: 0.3 s apart at
        10 m/s is 3 m, and a building's face read from 3 m back looks like a new obstacle in front of it).
        ``heading_time_s``, ``yaw_rate_rad_s``: when the heading was sampled (the autopilot's seconds since boot)
        and its rate: a heading-relative scan is turned by the heading at its own time and given the allowance
        of :func:`heading_allowance_rad` instead of :data:`HEADING_LAG_RAD`."""
        if msg.get_type() not in self.MESSAGES:
            return False
        reading = translate_sensor(msg, received_s, heading_rad)
        if reading is None:
            return True
        self._note_heading(heading_rad, reading)
        if isinstance(reading, RangeScan) and reading.bearing_error_rad > 0 and self.turning:
            self.turning_dropped += 1  # a heading-relative sector while the heading swings: not placed at all
            return True
        if isinstance(reading, RangeScan) and reading.bearing_error_rad > 0:
            reading = carry_heading(reading, heading_time_s, yaw_rate_rad_s)
        if isinstance(reading, RangeScan) and local_ne is not None and all(map(math.isfinite, local_ne)):
            n, e = float(local_ne[0]), float(local_ne[1])
            down = float(local_down_m) if local_down_m is not None and math.isfinite(local_down_m) else None
            dt = reading.time_s - local_time_s
            if local_velocity_ned is not None and abs(dt) <= self.MAX_EXTRAPOLATION_S:  # False while NaN
                vn, ve, vd = (float(v) for v in local_velocity_ned)
                if math.isfinite(vn) and math.isfinite(ve):
                    n, e = n + vn * dt, e + ve * dt
                if down is not None and math.isfinite(vd):
                    down += vd * dt
            reading = dataclasses.replace(reading, local_ne=(n, e), local_down_m=down)
        if isinstance(reading, RangeScan) and horizontal_accuracy_m > 0:  # False while NaN
            reading = dataclasses.replace(reading,
                                          position_error_m=POSITION_ERROR_PER_ACCURACY * float(horizontal_accuracy_m))
        readings = [reading]
        if isinstance(reading, RangeScan) and reading.source == "DISTANCE_SENSOR":
            readings += self._never_sent(msg.orientation, reading)
        with self._cond:
            for r in readings:
                if isinstance(r, HeightReading):
                    self.height = r
                else:
                    self.scans += 1
                    self.last_scan_s = received_s
                if len(self._queue) == self._queue.maxlen:
                    self.dropped += 1
                self._queue.append(r)
            self._cond.notify_all()
        return True

    def _never_sent(self, orientation: int, reading: RangeScan) -> list[RangeScan]:
        """ArduPilot sends a proximity sector only once it has had a valid reading (``proximity_ever_valid_bitmask``
        in ``GCS_MAVLINK::send_proximity``): a sector never sent while others come has had nothing within range.
        When the first sector of a new sample arrives, the sectors never sent by the end of the one before are
        returned as empty (``inf``), placed and stamped as that sample's first sector. Without this, open ground
        ahead stayed unknown and the sight cap held the vehicle at a crawl (a fault-campaign mission with nothing
        within 30 m to the north: 713 m in 559 s; before the crawl floor it never moved). A sector sent before and
        missing now dropped out: it stays unknown."""
        out: list[RangeScan] = []
        first = self._sample_first
        if first is None or reading.time_s != first.scan.time_s:
            if first is not None:
                nose = first.scan.bearings_rad[0] - math.radians(_YAW_ORIENTATIONS[first.orientation])
                out = [dataclasses.replace(first.scan, bearings_rad=np.array([(nose + math.radians(deg)) % _TWO_PI]),
                                           distances_m=np.array([math.inf]))
                       for o, deg in _YAW_ORIENTATIONS.items() if o not in self._sectors_sent]
            self._sample_first = _Sector(reading, orientation)
        self._sectors_sent.add(orientation)
        return out

    def drain(self) -> list[RangeScan | HeightReading]:
        """Every reading queued since the last call, oldest first."""
        with self._cond:
            out = list(self._queue)
            self._queue.clear()
            return out

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for a reading to be queued; True if one is."""
        with self._cond:
            return self._cond.wait_for(lambda: bool(self._queue), timeout=timeout_s)

    @property
    def streaming(self) -> bool:
        """True while horizontal scans arrive (the last within ``streaming_s``)."""
        return self.clock() - self.last_scan_s <= self.streaming_s  # False while NaN
