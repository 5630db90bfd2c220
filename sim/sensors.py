"""Obstacle sensors: a 360 degree horizontal range sensor and a downward rangefinder, cast against the TRUE boxes.

The horizontal sensor lies in the plane of the vehicle's centre (its sphere's centre, ``radius_m`` above the
position). Each sector reports the distance to the nearest point of any box within the sector's wedge (the
minimum over the sector, not one ray), exactly: for a box (convex) and a wedge narrower than 180 degrees the
nearest point of their intersection is either the box's nearest point (when it lies in the wedge) or where one of
the wedge's two edge rays enters the box, so a scan costs two ray tests per sector edge and box plus one nearest
point per box, vectorised over the boxes within range.

How each personality streams it (what the real autopilots send a ground station or companion computer):

* PX4: OBSTACLE_DISTANCE (the collision-prevention map it publishes as ``obstacle_distance_fused``): 72 sectors of
  5 degrees, ``frame`` MAV_FRAME_GLOBAL (north aligned: element ``i`` centred on bearing ``5 i`` degrees from
  north, covering ``[5 i - 2.5, 5 i + 2.5)``), centimetres, ``min_distance`` / ``max_distance``; an empty sector
  reads ``max_distance + 1``, a sector without a reading (dropout) ``UINT16_MAX``. Streamed on the onboard link at
  the sensor's rate; the downward rangefinder as DISTANCE_SENSOR (orientation PITCH_270) at the same rate.
* ArduPilot: DISTANCE_SENSOR, one per proximity sector as ``GCS_MAVLINK::send_proximity`` reports AP_Proximity's
  8 sectors of 45 degrees: orientation MAV_SENSOR_ROTATION_NONE .. YAW_315 relative to the vehicle's heading
  (sector ``i`` centred ``45 i`` degrees clockwise from the nose), id ``10 + i`` (PROXIMITY_SENSOR_ID_START),
  type LASER, covariance 0; a sector without an obstacle reads ``max_distance``; a sector that never had a valid
  reading on a link is not sent at all (its ``proximity_ever_valid_bitmask``), nor one that drops out. The
  downward rangefinder (id 0, orientation PITCH_270) comes first. ArduCopter sends all of them when
  DISTANCE_SENSOR is due: in the EXTRA3 stream group or at a SET_MESSAGE_INTERVAL rate; nothing unasked.

Noise is Gaussian on each measured distance (clipped to the sensor's range; empty sectors stay empty); dropout
loses each sector of each scan independently. Both use their own random stream (seeded from the sim's seed), so
turning them on changes no other random sequence. The sensor samples at ``rate_hz`` simulated time; messages carry
the latest sample and its time.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

M = mavlink
UINT16_MAX = 65535
PX4_SECTORS = 72
ARDUPILOT_SECTORS = 8
#: ArduPilot's PROXIMITY_SENSOR_ID_START: sector ``i`` is DISTANCE_SENSOR id ``10 + i``.
PROXIMITY_ID_START = 10
RANGEFINDER_ID = 0
#: Messages the sensors stream.
SENSOR_MESSAGE_IDS = (M.MAVLINK_MSG_ID_OBSTACLE_DISTANCE, M.MAVLINK_MSG_ID_DISTANCE_SENSOR)


@dataclass(frozen=True)
class SensorConfig:
    """Obstacle sensor settings (metres, simulated hertz).

    Attributes
    ----------
    enabled : bool
        Stream the sensors at all (both personalities).
    range_m, min_range_m : float
        Horizontal sensor's maximum and minimum range.
    rate_hz : float
        Samples per simulated second (and PX4's stream rate).
    noise_m : float
        Standard deviation of the range noise.
    dropout_pct : float
        Percentage of sectors lost in each scan.
    down_range_m : float
        The downward rangefinder's maximum range (its minimum is ``min_range_m``).
    """

    enabled: bool = True
    range_m: float = 30.0
    min_range_m: float = 0.2
    rate_hz: float = 10.0
    noise_m: float = 0.0
    dropout_pct: float = 0.0
    down_range_m: float = 40.0

    def __post_init__(self) -> None:
        if not 0.5 <= self.range_m <= 600:
            raise ValueError(f"sensor range must be in [0.5, 600] m, not {self.range_m}")
        if not 0 <= self.min_range_m < self.range_m:
            raise ValueError(f"sensor minimum range must be in [0, range), not {self.min_range_m}")
        if not 0 < self.rate_hz <= 50:
            raise ValueError(f"sensor rate must be in (0, 50] Hz, not {self.rate_hz}")
        if not 0 <= self.noise_m <= 10:
            raise ValueError(f"sensor noise must be in [0, 10] m, not {self.noise_m}")
        if not 0 <= self.dropout_pct <= 100:
            raise ValueError(f"sensor dropout must be in [0, 100] %, not {self.dropout_pct}")
        if not 0.5 <= self.down_range_m <= 600:
            raise ValueError(f"rangefinder range must be in [0.5, 600] m, not {self.down_range_m}")


def sector_minima(lo: np.ndarray, hi: np.ndarray, north_m: float, east_m: float, sectors: int,
                  first_centre_rad: float, range_m: float) -> np.ndarray:
    """Distance (m) from a point to the nearest box point in each sector's wedge; ``inf`` where none is in range.

    Parameters
    ----------
    lo, hi : ndarray, shape (B, 2)
        Box footprints' ``north, east`` minima and maxima (the boxes that cross the sensor's plane).
    north_m, east_m : float
        The sensor.
    sectors : int
        Sectors of equal width ``2 pi / sectors``; sector ``i`` is centred on bearing ``first_centre_rad + i w``
        (radians clockwise from north) and covers ``[centre - w/2, centre + w/2)``.
    range_m : float
        Nothing farther counts.

    Examples
    --------
    A 2 m square 10 m north of the sensor: the north sector sees its near face, the 45 degree sector only the
    square's corner at (9, 1), which is outside a 5 degree sector's wedge but inside the 45 degree one:

    >>> lo, hi = np.array([[9.0, -1.0]]), np.array([[11.0, 1.0]])
    >>> d = sector_minima(lo, hi, 0.0, 0.0, 8, 0.0, 30.0)
    >>> round(float(d[0]), 3), bool(np.isinf(d[1])), bool(np.isinf(d[7]))
    (9.0, True, True)
    >>> d = sector_minima(lo, hi, 0.0, 0.0, 72, 0.0, 30.0)
    >>> [round(float(v), 3) for v in d[:3]]
    [9.0, 9.009, inf]
    """
    out = np.full(sectors, np.inf)
    if len(lo) == 0:
        return out
    p = np.array([north_m, east_m])
    width = 2.0 * math.pi / sectors
    near = np.clip(p, lo, hi)  # nearest point of each box
    gap = near - p
    dist = np.hypot(gap[:, 0], gap[:, 1])
    if (dist == 0.0).any():  # the sensor is inside a box: everything is touching
        out[:] = 0.0
        return out
    near_enough = dist <= range_m  # a box farther than the range shows in no sector (nor on an edge ray)
    if not near_enough.any():
        return out
    lo, hi, gap, dist = lo[near_enough], hi[near_enough], gap[near_enough], dist[near_enough]
    bearing = np.arctan2(gap[:, 1], gap[:, 0])
    index = np.floor((bearing - first_centre_rad + width / 2.0) / width).astype(np.int64) % sectors
    np.minimum.at(out, index, dist)
    # Edge rays: ray k is sector k's lower edge and sector k-1's upper edge.
    angles = first_centre_rad - width / 2.0 + width * np.arange(sectors)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]  # (S, 1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo[None, :, :] - p) * inv
        t1 = (hi[None, :, :] - p) * inv
    t_lo = np.where(np.isnan(t0), -np.inf, np.minimum(t0, t1))  # NaN: ray parallel to an axis, inside the slab
    t_hi = np.where(np.isnan(t1), np.inf, np.maximum(t0, t1))
    # A ray parallel to a slab it lies outside of: 0 * inf -> nan above would have been caught; +-inf stays.
    enter = t_lo.max(axis=2)
    leave = t_hi.min(axis=2)
    hit = (enter <= leave) & (leave >= 0.0)
    ray = np.where(hit, np.maximum(enter, 0.0), np.inf).min(axis=1)  # (S,)
    out = np.minimum(out, np.minimum(ray, np.roll(ray, -1)))
    out[out > range_m] = np.inf
    return out


class ObstacleSensor:
    """The vehicle's obstacle sensors in the true city; owned by the simulation thread.

    Parameters
    ----------
    config : SensorConfig
    city : sim.world.CityMap
        The TRUE boxes (the sim's ``--map``).
    autopilot : {"px4", "ardupilot"}
    seed : int
        Seeds the noise and dropout stream.
    """

    def __init__(self, config: SensorConfig, city, autopilot: str, seed: int) -> None:
        self.config = config
        self.city = city
        self.is_px4 = autopilot == "px4"
        self.sectors = PX4_SECTORS if self.is_px4 else ARDUPILOT_SECTORS
        self.rng = random.Random(f"sensor-{seed}")
        self._sample_s = -math.inf
        self.distances_m = np.full(self.sectors, math.nan)  # NaN: dropped, inf: empty
        self.down_m = math.nan
        self.scans = 0
        self.min_reading_m: float | None = None

    def sample(self, sim_time_s: float, centre_neu: np.ndarray, yaw_rad: float, position_neu: np.ndarray) -> None:
        """Take a new sample if ``1 / rate_hz`` simulated seconds have passed since the last one."""
        cfg = self.config
        if sim_time_s - self._sample_s < 1.0 / cfg.rate_hz - 1e-9:
            return
        self._sample_s = sim_time_s
        n, e, up = (float(v) for v in centre_neu)
        idx = self.city.candidates(n, e, cfg.range_m)
        idx = np.unique(idx)
        lo, hi = self.city.lo[idx], self.city.hi[idx]
        crossing = (lo[:, 2] <= up) & (up <= hi[:, 2])
        first = 0.0 if self.is_px4 else yaw_rad
        dist = sector_minima(lo[crossing, :2], hi[crossing, :2], n, e, self.sectors, first, cfg.range_m)
        for i in range(self.sectors):
            if cfg.dropout_pct > 0 and self.rng.random() * 100.0 < cfg.dropout_pct:
                dist[i] = math.nan
            elif math.isfinite(dist[i]) and cfg.noise_m > 0:
                dist[i] = min(max(dist[i] + self.rng.gauss(0.0, cfg.noise_m), cfg.min_range_m), cfg.range_m)
        self.distances_m = dist
        seen = dist[np.isfinite(dist)]
        if seen.size:
            lowest = float(seen.min())
            self.min_reading_m = lowest if self.min_reading_m is None else min(self.min_reading_m, lowest)
        pn, pe, pu = (float(v) for v in position_neu)
        self.down_m = pu - self.city.ground_up_m(pn, pe, pu)
        if cfg.noise_m > 0:
            self.down_m = max(self.down_m + self.rng.gauss(0.0, cfg.noise_m), 0.0)
        self.scans += 1

    # ------------------------------------------------------------------ messages
    def messages(self, msg_id: int, link) -> list:
        """The messages for ``msg_id`` from the latest sample (``link`` keeps ArduPilot's ever-valid sectors)."""
        if self.scans == 0:
            return []  # nothing measured yet
        time_ms = int(max(self._sample_s, 0.0) * 1000)
        if msg_id == M.MAVLINK_MSG_ID_OBSTACLE_DISTANCE:
            return [self._obstacle_distance(time_ms)] if self.is_px4 else []
        if msg_id != M.MAVLINK_MSG_ID_DISTANCE_SENSOR:
            return []
        out = [self._rangefinder(time_ms)]
        if not self.is_px4:
            out += self._proximity(time_ms, link)
        return out

    def _cm(self, metres: float) -> int:
        return int(min(max(round(metres * 100.0), 0), UINT16_MAX - 1))

    def _obstacle_distance(self, time_ms: int):
        cfg = self.config
        max_cm = self._cm(cfg.range_m)
        cells = []
        for d in self.distances_m:
            if math.isnan(d):
                cells.append(UINT16_MAX)
            elif math.isinf(d):
                cells.append(max_cm + 1)
            else:
                cells.append(self._cm(d))
        return M.MAVLink_obstacle_distance_message(
            time_ms * 1000, M.MAV_DISTANCE_SENSOR_LASER, cells, 5, self._cm(cfg.min_range_m), max_cm,
            increment_f=5.0, angle_offset=0.0, frame=M.MAV_FRAME_GLOBAL)

    def _rangefinder(self, time_ms: int):
        cfg = self.config
        reading = min(max(self.down_m, cfg.min_range_m), cfg.down_range_m) if math.isfinite(self.down_m) \
            else cfg.down_range_m
        return M.MAVLink_distance_sensor_message(
            time_ms, self._cm(cfg.min_range_m), self._cm(cfg.down_range_m), self._cm(reading),
            M.MAV_DISTANCE_SENSOR_LASER, RANGEFINDER_ID, M.MAV_SENSOR_ROTATION_PITCH_270, 0)

    def _proximity(self, time_ms: int, link) -> list:
        cfg = self.config
        min_cm, max_cm = self._cm(cfg.min_range_m), self._cm(cfg.range_m)
        ever = getattr(link, "proximity_ever_valid", 0)
        out = []
        for i, d in enumerate(self.distances_m):
            if math.isnan(d):
                continue  # dropped out: nothing this time
            if math.isfinite(d):
                ever |= 1 << i
            elif not ever & (1 << i):
                continue  # never valid on this link: ArduPilot does not send it
            reading = max_cm if math.isinf(d) else self._cm(d)
            out.append(M.MAVLink_distance_sensor_message(
                time_ms, min_cm, max_cm, reading, M.MAV_DISTANCE_SENSOR_LASER, PROXIMITY_ID_START + i,
                M.MAV_SENSOR_ROTATION_NONE + i, 0))
        if link is not None:
            link.proximity_ever_valid = ever
        return out

    def report(self) -> dict:
        """The report's ``sensor`` entry."""
        cfg = self.config
        return {"enabled": cfg.enabled, "range_m": cfg.range_m, "min_range_m": cfg.min_range_m,
                "rate_hz": cfg.rate_hz, "noise_m": cfg.noise_m, "dropout_pct": cfg.dropout_pct,
                "down_range_m": cfg.down_range_m, "sectors": self.sectors,
                "message": "OBSTACLE_DISTANCE" if self.is_px4 else "DISTANCE_SENSOR",
                "scans": self.scans, "min_reading_m": self.min_reading_m}
