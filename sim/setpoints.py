"""SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT to a map-frame :class:`ControlTarget`.

``type_mask`` ignore bits are honoured per axis: a position axis whose bit is clear is
position-controlled (its velocity, if not ignored, is feed-forward); an axis with only velocity is
velocity-controlled; an axis with neither holds the position it had when the setpoint arrived.
An acceleration that goes with a position or a velocity is a feed-forward on the velocity loop, as PX4 OFFBOARD
takes it (PX4 personality only: ArduCopter's GUIDED integrates a target acceleration into a moving target, which
is not simulated, so the ArduPilot personality ignores it).

Classic dialect (udacidrone ``PX4=False``, outside ``--strict`` only): ``(type_mask & 0x3000)``
``0x1000`` = takeoff, ``0x2000`` = land at (x, y), ``0x3000`` = loiter; and ``z`` is a positive
altitude. In ``--strict`` these bits are ignored (with one warning) and ``z`` is NED down.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from .dynamics import ControlTarget

M = mavlink
NAN = math.nan
_LOCAL_FRAMES = {M.MAV_FRAME_LOCAL_NED}
_OFFSET_FRAMES = {M.MAV_FRAME_LOCAL_OFFSET_NED}
_BODY_FRAMES = {M.MAV_FRAME_BODY_NED, M.MAV_FRAME_BODY_OFFSET_NED, M.MAV_FRAME_BODY_FRD}
_GLOBAL_AMSL = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT}
_GLOBAL_REL = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_GLOBAL_TERRAIN = {M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}


def _warn_once(ap, link, key: str, text: str) -> None:
    if key not in link.warned:
        link.warned.add(key)
        ap.statustext(M.MAV_SEVERITY_WARNING, text, link)
        ap.emit("setpoint", f"link {link.link_id}: {text}")


def _build(ap, mask: int, pos_neu, vel_neu, yaw: float, yaw_rate: float, accel_neu=(NAN, NAN, NAN)) -> ControlTarget:
    """Apply the ignore bits; unset axes hold the current position. An acceleration goes with a position or a
    velocity as a feed-forward (PX4 only: ArduCopter's GUIDED integrates it into its target, not simulated)."""
    here = ap.position_neu
    pos = [NAN, NAN, NAN]
    vel = [NAN, NAN, NAN]
    acc = [NAN, NAN, NAN]
    for axis in range(3):
        pos_used = not mask & (1 << axis)
        vel_used = not mask & (8 << axis)
        if pos_used:
            pos[axis] = float(pos_neu[axis])
        if vel_used:
            vel[axis] = float(vel_neu[axis])
        if not pos_used and not vel_used:
            pos[axis] = float(here[axis])
        elif ap.is_px4 and not mask & (64 << axis) and not mask & M.POSITION_TARGET_TYPEMASK_FORCE_SET:
            acc[axis] = float(accel_neu[axis])
    yaw_v = yaw if not mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE else NAN
    rate_v = yaw_rate if not mask & M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE else NAN
    return ControlTarget(tuple(pos), tuple(vel), yaw_v, rate_v, accel_neu=tuple(acc))


def local_ned_target(ap, link, msg) -> ControlTarget | None:
    """Map-frame target of a SET_POSITION_TARGET_LOCAL_NED, or None if refused."""
    mask = int(msg.type_mask)
    special = mask & CLASSIC_BITS
    if special:
        if ap.cfg.strict:
            _warn_once(ap, link, "strict-special",
                       f"--strict: type_mask bits 0x{special:x} ignored, z is NED")
            special = 0
        elif not link.classic:
            link.classic = True
            ap.emit("dialect", f"link {link.link_id}: type_mask 0x{special:x} -> classic dialect")
    classic = link.classic and not ap.cfg.strict
    x, y, z = float(msg.x), float(msg.y), float(msg.z)
    vx, vy, vz = float(msg.vx), float(msg.vy), float(msg.vz)
    if classic:
        z = -z  # positive altitude -> NED down
    frame = int(msg.coordinate_frame)
    here = ap.position_neu
    yaw = float(msg.yaw)
    # positions and offsets are in the personality's local metres (CityMap.local_scale): back to the map's
    if frame in _LOCAL_FRAMES:
        pos = ap.origin_neu + np.array([x, y, -z]) / ap.local_scale
    elif frame in _OFFSET_FRAMES:
        pos = here + np.array([x, y, -z]) / ap.local_scale
    elif frame in _BODY_FRAMES:
        c, s = math.cos(ap.quad.state.yaw_rad), math.sin(ap.quad.state.yaw_rad)
        pos = here + np.array([c * x - s * y, s * x + c * y, -z]) / ap.local_scale
        vx, vy = c * vx - s * vy, s * vx + c * vy
        yaw = ap.quad.state.yaw_rad + yaw
    else:
        _warn_once(ap, link, f"frame-{frame}", f"SET_POSITION_TARGET_LOCAL_NED frame {frame} not supported")
        return None
    vel = (vx, vy, -vz)
    if special == 0x2000:  # classic land at (x, y)
        land = ap._land_speed()
        return ControlTarget((pos[0], pos[1], NAN), (NAN, NAN, -land), max_descent_m_s=land)
    if special in (0x1000, 0x3000):  # classic takeoff / loiter: go to and hold the position
        return ControlTarget(tuple(float(v) for v in pos))
    acc = (float(msg.afx), float(msg.afy), -float(msg.afz))
    if frame in _BODY_FRAMES:
        c, s = math.cos(ap.quad.state.yaw_rad), math.sin(ap.quad.state.yaw_rad)
        acc = (c * acc[0] - s * acc[1], s * acc[0] + c * acc[1], acc[2])
    return _build(ap, mask, pos, vel, yaw, float(msg.yaw_rate), acc)


def global_int_target(ap, link, msg) -> ControlTarget | None:
    """Map-frame target of a SET_POSITION_TARGET_GLOBAL_INT, or None if refused."""
    frame = int(msg.coordinate_frame)
    n, e, _ = ap.city.geodetic_to_map(msg.lat_int * 1e-7, msg.lon_int * 1e-7, 0.0)
    alt = float(msg.alt)
    if frame in _GLOBAL_AMSL:
        up = alt
    elif frame in _GLOBAL_REL:
        up = ap.home_neu[2] + alt
    elif frame in _GLOBAL_TERRAIN:
        up = ap.city.ground_up_m(n, e, math.inf, ap.cfg.radius_m) + alt
    else:
        _warn_once(ap, link, f"gframe-{frame}", f"SET_POSITION_TARGET_GLOBAL_INT frame {frame} not supported")
        return None
    mask = int(msg.type_mask) & 0x0FFF
    if mask & 0b011:  # lat/lon are one pair: ignoring either ignores both
        mask |= 0b011
    vel = (float(msg.vx), float(msg.vy), -float(msg.vz))
    acc = (float(msg.afx), float(msg.afy), -float(msg.afz))
    return _build(ap, mask, (n, e, up), vel, float(msg.yaw), float(msg.yaw_rate), acc)


CLASSIC_BITS = 0x3000
