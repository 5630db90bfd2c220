"""The vehicle package's pure parts: MAVLink -> SI translation, STATUSTEXT reassembly, parameter decoding, the
autopilots' limits, readiness, link health, stream keeping, modes and connection strings.

Messages are encoded to real MAVLink 2 bytes with ``mavlink.MAVLink(io.BytesIO())`` and decoded again, so the
translation functions see exactly what the wire delivers. Expected values are worked out from the MAVLink spec
(degE7, mm, cm/s, cdeg; PX4 main mode in bits 16-23) and from what the SITL autopilots were measured to send, not
copied from the code. The link itself is tested against a fake autopilot in ``test_vehicle_link.py``.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
import struct

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyroute import vehicle as vh
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic
from skyroute.vehicle.health import LinkHealth
from skyroute.vehicle.streams import StreamKeeper
from skyroute.vehicle.transport import check_connection_string

MAP_ORIGIN = Geodetic(37.792480, -122.397450, 0.0)


def roundtrip(make):
    """Encode with a sender (system 1, component 1), pack to bytes, decode with a fresh parser."""
    sender = mavlink.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=1)
    buf = make(sender).pack(sender)
    return mavlink.MAVLink(io.BytesIO()).decode(bytearray(buf))


def px4_heartbeat(enc, main_mode=6, sub_mode=0, armed=True):
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
                                (main_mode << 16) | (sub_mode << 24), mavlink.MAV_STATE_ACTIVE)


# ------------------------------------------------------------------------------------------- translation
def test_heartbeat_px4_offboard_armed():
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), roundtrip(px4_heartbeat), now_s=12.5)
    assert t.autopilot is vh.Autopilot.PX4
    assert t.armed is True
    assert t.mode == "OFFBOARD"
    assert t.last_heartbeat_s == 12.5


def test_heartbeat_px4_auto_land_disarmed():
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), roundtrip(lambda e: px4_heartbeat(e, 4, 6, armed=False)), 0.0)
    assert (t.mode, t.armed) == ("LAND", False)


def test_heartbeat_ardupilot_guided():
    msg = roundtrip(lambda e: e.heartbeat_encode(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, mavlink.MAV_STATE_STANDBY))
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0)
    assert (t.autopilot, t.mode, t.armed) == (vh.Autopilot.ARDUPILOT, "GUIDED", False)


def test_gcs_heartbeat_is_not_an_autopilot():
    gcs = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    assert not vh.is_autopilot_heartbeat(gcs)
    assert vh.is_autopilot_heartbeat(roundtrip(px4_heartbeat))


def test_global_position_int_units():
    # 37.7924801 deg, 25.5 m AMSL, 10.25 m above home, 1 m/s N, -2 m/s E, 0.5 m/s down, heading 90 deg
    msg = roundtrip(lambda e: e.global_position_int_encode(4200, 377924801, -1223974500, 25500, 10250,
                                                           100, -200, 50, 9000))
    t = vh.telemetry_from_global_position_int(vh.Telemetry(), msg, 0.0)
    assert t.lat_deg == pytest.approx(37.7924801, abs=1e-9)
    assert t.lon_deg == pytest.approx(-122.39745, abs=1e-9)
    assert (t.alt_amsl_m, t.relative_alt_m) == (pytest.approx(25.5), pytest.approx(10.25))
    assert (t.v_north_mps, t.v_east_mps, t.v_down_mps) == (pytest.approx(1.0), pytest.approx(-2.0),
                                                           pytest.approx(0.5))
    assert t.global_time_s == pytest.approx(4.2)
    assert t.heading_rad == pytest.approx(math.pi / 2)


def test_global_position_int_unknown_heading_stays_nan():
    msg = roundtrip(lambda e: e.global_position_int_encode(0, 0, 0, 0, 0, 0, 0, 0, 65535))
    assert math.isnan(vh.telemetry_from_global_position_int(vh.Telemetry(), msg, 0.0).heading_rad)


def test_local_position_ned():
    msg = roundtrip(lambda e: e.local_position_ned_encode(1500, 3.0, -4.0, -12.0, 0.5, 0.25, -1.0))
    t = vh.telemetry_from_local_position_ned(vh.Telemetry(), msg, 0.0)
    assert t.local == LocalNED(3.0, -4.0, -12.0)
    assert (t.local_v_north_mps, t.local_v_east_mps, t.local_v_down_mps) == (0.5, 0.25, -1.0)
    assert t.local_time_s == pytest.approx(1.5)
    assert t.ground_speed_mps == pytest.approx(math.hypot(0.5, 0.25))


@pytest.mark.parametrize("autopilot, radius_m", [(vh.Autopilot.ARDUPILOT, 6378137.0), (vh.Autopilot.PX4, 6371000.0),
                                                 (vh.Autopilot.GENERIC, None)])
def test_local_positions_are_turned_from_the_autopilots_sphere_into_wgs84_metres(autopilot, radius_m):
    """A point 300 m north and 350 m east of the origin on the WGS84 ellipsoid, as the autopilot's local frame
    puts it: latitude and longitude differences times its sphere's radius (ArduPilot's LOCATION_SCALING_FACTOR,
    PX4's CONSTANTS_RADIUS_OF_EARTH); a generic autopilot's is taken as it is."""
    origin = Geodetic(37.79248, -122.39745, 0.0)
    point = ned_to_geodetic(LocalNED(300.0, 350.0, 0.0), origin)
    if radius_m is None:
        x, y = 300.0, 350.0
    else:
        x = math.radians(point.lat_deg - origin.lat_deg) * radius_m
        y = math.radians(point.lon_deg - origin.lon_deg) * radius_m * math.cos(math.radians(origin.lat_deg))
    assert radius_m is None or abs(x - 300.0) > 0.5  # the frames differ by more than half a metre here
    msg = roundtrip(lambda e: e.local_position_ned_encode(1500, x, y, -5.0, 0.0, 0.0, 0.0))
    t = vh.telemetry_from_local_position_ned(vh.Telemetry(autopilot=autopilot, origin=origin), msg, 0.0)
    assert (t.north_m, t.east_m) == (pytest.approx(300.0, abs=0.05), pytest.approx(350.0, abs=0.05))  # 2nd order


def test_attitude_heading_wraps_to_positive():
    msg = roundtrip(lambda e: e.attitude_encode(0, 0.1, -0.2, -math.pi / 2, 0, 0, 0))
    t = vh.telemetry_from_attitude(vh.Telemetry(), msg, 0.0)
    assert t.heading_rad == pytest.approx(3 * math.pi / 2)
    assert t.roll_rad == pytest.approx(0.1)


def test_attitude_carries_the_yaw_rate_and_the_samples_time():
    msg = roundtrip(lambda e: e.attitude_encode(12_340, 0.0, 0.0, 0.5, 0, 0, -0.25))
    t = vh.telemetry_from_attitude(vh.Telemetry(), msg, 0.0)
    assert t.yaw_rate_rad_s == pytest.approx(-0.25) and t.attitude_time_s == pytest.approx(12.34)


@pytest.mark.parametrize("raw, expected", [(1, vh.LandedState.ON_GROUND), (2, vh.LandedState.IN_AIR),
                                           (4, vh.LandedState.LANDING), (0, vh.LandedState.UNDEFINED),
                                           (200, vh.LandedState.UNDEFINED)])  # a value MAVLink does not define
def test_extended_sys_state(raw, expected):
    msg = roundtrip(lambda e: e.extended_sys_state_encode(0, raw))
    assert vh.telemetry_from_extended_sys_state(vh.Telemetry(), msg, 0.0).landed_state is expected


def test_sys_status_battery_and_prearm():
    pre = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    msg = roundtrip(lambda e: e.sys_status_encode(pre, pre, pre, 0, 12600, -1, 87, 0, 0, 0, 0, 0, 0))
    t = vh.telemetry_from_sys_status(vh.Telemetry(), msg, 0.0)
    assert (t.battery_voltage_v, t.battery_remaining_pct, t.prearm_ok) == (pytest.approx(12.6), 87.0, True)
    msg = roundtrip(lambda e: e.sys_status_encode(0, 0, 0, 0, 65535, -1, -1, 0, 0, 0, 0, 0, 0))
    t = vh.telemetry_from_sys_status(vh.Telemetry(), msg, 0.0)
    assert math.isnan(t.battery_voltage_v) and math.isnan(t.battery_remaining_pct) and t.prearm_ok is None


def test_sys_status_says_whether_a_proximity_sensor_or_a_rangefinder_is_present():
    base = mavlink.MAV_SYS_STATUS_SENSOR_GPS
    for present, ranging in ((base, False), (base | mavlink.MAV_SYS_STATUS_SENSOR_PROXIMITY, True),
                             (base | mavlink.MAV_SYS_STATUS_SENSOR_LASER_POSITION, True)):
        msg = roundtrip(lambda e, p=present: e.sys_status_encode(p, p, p, 0, 12600, -1, 87, 0, 0, 0, 0, 0, 0))
        assert vh.telemetry_from_sys_status(vh.Telemetry(), msg, 0.0).range_sensors is ranging


def test_home_position():
    msg = roundtrip(lambda e: e.home_position_encode(377924800, -1223974500, 3500, 0, 0, 0, [1, 0, 0, 0],
                                                     0, 0, 0))
    home = vh.telemetry_from_home_position(vh.Telemetry(), msg, 0.0).home
    assert home == (pytest.approx(37.79248), pytest.approx(-122.39745), pytest.approx(3.5))


def test_statustext_keeps_the_latest():
    t = vh.Telemetry()
    for i in range(vh.STATUSTEXT_KEEP + 3):
        t = vh.with_statustext(t, vh.StatusText(4, f"msg {i}", float(i)))
    assert len(t.statustexts) == vh.STATUSTEXT_KEEP
    assert t.statustexts[-1] == vh.StatusText(4, f"msg {vh.STATUSTEXT_KEEP + 2}", float(vh.STATUSTEXT_KEEP + 2))


def test_gps_global_origin_and_gps_raw_int():
    msg = roundtrip(lambda e: e.gps_global_origin_encode(377924800, -1223974500, 846, 649199))
    assert vh.telemetry_from_gps_global_origin(vh.Telemetry(), msg, 0.0).origin == (
        pytest.approx(37.79248), pytest.approx(-122.39745), pytest.approx(0.846))
    raw = roundtrip(lambda e: e.gps_raw_int_encode(0, 3, 377924781, -1223974503, -150, 70, 110, 5, 12640, 10))
    t = vh.telemetry_from_gps_raw_int(vh.Telemetry(), raw, 0.0)
    assert (t.gps_fix_type, t.satellites) == (3, 10)
    assert math.isnan(t.horizontal_accuracy_m)  # h_acc 0 (not sent): unknown


@pytest.mark.parametrize("h_acc, metres", [(900, 0.9), (300, 0.3), (0, math.nan), (0xFFFFFFFF, math.nan)])
def test_gps_raw_int_horizontal_accuracy_in_metres_and_unknown_as_nan(h_acc, metres):
    raw = roundtrip(lambda e: e.gps_raw_int_encode(0, 3, 377924781, -1223974503, -150, 70, 110, 5, 12640, 10,
                                                   h_acc=h_acc))
    accuracy = vh.telemetry_from_gps_raw_int(vh.Telemetry(), raw, 0.0).horizontal_accuracy_m
    assert accuracy == pytest.approx(metres, nan_ok=True)


def test_a_zero_position_is_no_global_position():
    # ArduCopter streams GLOBAL_POSITION_INT with lat = lon = 0 until its GPS has a fix
    msg = roundtrip(lambda e: e.global_position_int_encode(700, 0, 0, 0, 0, 0, 0, 0, 65535))
    assert not vh.telemetry_from_global_position_int(vh.Telemetry(), msg, 0.0).has_global


def test_update_telemetry_ignores_other_messages():
    t = vh.Telemetry(lat_deg=1.0)
    assert vh.update_telemetry(t, roundtrip(lambda e: e.ping_encode(0, 0, 0, 0)), 0.0) is t


# -------------------------------------------------------------------------------------------- modes, frames
@pytest.mark.parametrize("autopilot, mode, expected", [
    (vh.Autopilot.PX4, "OFFBOARD", (6, 0)),  # px4_custom_mode.h: MAIN_MODE_OFFBOARD = 6
    (vh.Autopilot.PX4, "LAND", (4, 6)),  # AUTO = 4, SUB_MODE_AUTO_LAND = 6
    (vh.Autopilot.PX4, "LOITER", (4, 3)),
    (vh.Autopilot.GENERIC, "offboard", (6, 0)),
    (vh.Autopilot.ARDUPILOT, "GUIDED", (4, 0)),  # ArduCopter mode numbers
    (vh.Autopilot.ARDUPILOT, "LAND", (9, 0)),
    (vh.Autopilot.ARDUPILOT, "LOITER", (5, 0)),
    (vh.Autopilot.ARDUPILOT, "BRAKE", (17, 0)),
])
def test_mode_numbers(autopilot, mode, expected):
    assert vh.mode_numbers(autopilot, mode) == expected


def test_unknown_mode_raises():
    with pytest.raises(vh.UnsupportedMode, match="GUIDED"):
        vh.mode_numbers(vh.Autopilot.PX4, "GUIDED")


def test_type_mask_position_and_yaw_only():
    # bits: vx vy vz (8 16 32), ax ay az (64 128 256), yaw rate (2048); x y z and yaw (1024) not ignored
    assert vh.TYPE_MASK_POSITION_YAW == 8 + 16 + 32 + 64 + 128 + 256 + 2048


def test_type_mask_position_velocity_and_yaw():
    # bits: ax ay az (64 128 256), yaw rate (2048); position, velocity (feed-forward) and yaw used
    assert vh.TYPE_MASK_POSITION_VELOCITY_YAW == 64 + 128 + 256 + 2048


def test_map_offset_when_autopilot_origin_is_elsewhere():
    # The vehicle hovers 120 m north, 40 m west of the map origin, 2 m above its EKF origin (local down -2), at
    # 52 m AMSL; the map's ground is at 47 m AMSL, so it is 5 m above the map's ground (it booted on a 3 m roof).
    where = ned_to_geodetic(LocalNED(120.0, -40.0, 0.0), MAP_ORIGIN)
    t = vh.Telemetry(lat_deg=where.lat_deg, lon_deg=where.lon_deg, alt_amsl_m=52.0, relative_alt_m=2.0,
                     global_time_s=5.0, north_m=0.0, east_m=0.0, down_m=-2.0, local_v_north_mps=0.0,
                     local_v_east_mps=0.0, local_v_down_mps=0.0, local_time_s=5.0)
    offset = vh.map_offset(t, MAP_ORIGIN, ground_amsl_m=47.0)
    assert offset == (pytest.approx(120.0, abs=1e-3), pytest.approx(-40.0, abs=1e-3), pytest.approx(-3.0))
    assert vh.map_position(t, MAP_ORIGIN, 47.0) == (pytest.approx(120.0, abs=1e-3), pytest.approx(-40.0, abs=1e-3),
                                                    pytest.approx(-5.0))


def test_map_offset_needs_both_samples_and_a_ground():
    with pytest.raises(ValueError):
        vh.map_offset(vh.Telemetry(lat_deg=1.0, lon_deg=1.0), MAP_ORIGIN, 0.0)
    t = vh.Telemetry(lat_deg=1.0, lon_deg=1.0, north_m=0.0, east_m=0.0, down_m=0.0)
    with pytest.raises(ValueError, match="finite"):
        vh.map_offset(t, MAP_ORIGIN, math.nan)


def test_heartbeat_generic_autopilot_reads_px4_modes():
    msg = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC,
                                                 mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6 << 16, 0))
    t = vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0)
    assert (t.autopilot, t.mode) == (vh.Autopilot.GENERIC, "OFFBOARD")


def test_on_ground_from_landed_state_or_altitude():
    assert vh.Telemetry(landed_state=vh.LandedState.ON_GROUND, relative_alt_m=30.0).on_ground
    assert not vh.Telemetry(landed_state=vh.LandedState.IN_AIR, relative_alt_m=0.0).on_ground
    assert vh.Telemetry(relative_alt_m=0.1, v_down_mps=0.0).on_ground


def test_a_stale_on_ground_state_is_not_trusted_while_climbing():
    # Just after takeoff the last EXTENDED_SYS_STATE can still say ON_GROUND while the vehicle climbs at 3 m/s.
    assert not vh.Telemetry(landed_state=vh.LandedState.ON_GROUND, relative_alt_m=4.0, v_down_mps=-3.0).on_ground
    assert not vh.Telemetry(relative_alt_m=5.0, v_down_mps=0.0).on_ground
    assert not vh.Telemetry().on_ground  # nothing known yet



# -------------------------------------------------------------------------------------------- STATUSTEXT
def feed(assembler, messages, t0=0.0):
    """Feed (severity, text, id, chunk_seq) tuples through real MAVLink STATUSTEXT packets; returns the texts."""
    out = []
    for k, (severity, text, ident, seq) in enumerate(messages):
        msg = roundtrip(lambda e, s=severity, x=text, i=ident, q=seq: e.statustext_encode(s, x.encode(), i, q))
        out += assembler.add(msg.severity, msg.text, msg.id, msg.chunk_seq, t0 + 0.01 * k)
    return out


def test_px4_chunked_refusal_is_reassembled_whole():
    # measured on PX4 1.15 SITL: a 51-byte text in two chunks, the second "t" plus PX4's event tab
    texts = feed(vh.StatusTextAssembler(), [(2, "Arming denied: Resolve system health failures firs", 1, 0),
                                            (2, "t\t", 1, 1)])
    assert [(s.severity, s.text) for s in texts] == [(2, "Arming denied: Resolve system health failures first")]


def test_a_text_of_exactly_50_bytes_waits_for_its_next_chunk_and_unchunked_texts_pass_at_once():
    a = vh.StatusTextAssembler()
    first = "x" * 50
    assert feed(a, [(4, first, 9, 0)]) == []
    assert [s.text for s in feed(a, [(6, "PreArm: Need Position Estimate", 0, 0)])] == [
        "PreArm: Need Position Estimate"]  # ArduPilot: id 0, never chunked
    assert [s.text for s in feed(a, [(4, "yz", 9, 1)])] == [first + "yz"]


def test_a_lost_chunk_is_marked_and_a_stale_text_is_flushed():
    a = vh.StatusTextAssembler(stale_s=1.0)
    texts = feed(a, [(3, "a" * 50, 5, 0), (3, "end", 5, 2)])  # chunk 1 lost
    assert [s.text for s in texts] == ["a" * 50 + "…end"]
    feed(a, [(3, "b" * 50, 6, 0)])
    late = a.add(6, b"unrelated", 0, 0, 10.0)
    assert [s.text for s in late] == ["b" * 50 + "…", "unrelated"]


def test_the_refusal_quoted_is_the_one_that_came_with_the_refusal():
    texts = (vh.StatusText(2, "PreArm: Throttle below failsafe", 1.0),  # an older refusal
             vh.StatusText(6, "EKF3 IMU0 is using GPS", 5.0),  # info, not a reason
             vh.StatusText(2, "Arming denied: Resolve system health failures first", 5.1),
             vh.StatusText(2, "Preflight Fail: horizontal velocity unstable", 5.2),
             vh.StatusText(4, "Battery 1 low", 9.0))  # later
    assert vh.refusal_reason(texts, 5.0, 6.0, "arm") == (
        "Arming denied: Resolve system health failures first; Preflight Fail: horizontal velocity unstable")
    assert vh.refusal_reason(texts, 5.0, 5.05, "arm") is None


# ------------------------------------------------------------------------------------------- parameters
def param_message(name, value, ptype):
    return roundtrip(lambda e: e.param_value_encode(name.encode(), value, ptype, 1000, 65535))


def test_px4_sends_integers_bytewise_and_ardupilot_as_floats():
    from skyroute.vehicle.params import bytewise_encoding, decode_param_value

    bits = struct.unpack("<f", struct.pack("<i", 4))[0]  # NAV_DLL_ACT = 4 as PX4 puts it on the wire
    px4 = param_message("NAV_DLL_ACT", bits, mavlink.MAV_PARAM_TYPE_INT32)
    assert decode_param_value(px4.param_value, px4.param_type, bytewise=True) == 4.0
    ardu = param_message("FS_GCS_ENABLE", 1.0, mavlink.MAV_PARAM_TYPE_INT8)
    assert decode_param_value(ardu.param_value, ardu.param_type, bytewise=False) == 1.0
    real = param_message("COM_OF_LOSS_T", 1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert decode_param_value(real.param_value, real.param_type, bytewise=True) == 1.0
    # AUTOPILOT_VERSION decides (PX4 1.15 sets PARAM_ENCODE_BYTEWISE, ArduCopter 4.7 does not)
    assert bytewise_encoding(vh.Autopilot.PX4, 0xE8FF) and not bytewise_encoding(vh.Autopilot.ARDUPILOT, 0xFBEF)


# ------------------------------------------------------------------------------------------------ limits
def test_ardupilot_defaults_hover_on_a_lost_link_and_accelerate_at_2_5():
    # ArduCopter SITL defaults (read on V4.7.0-dev): FS_GCS_ENABLE 0, GUID_TIMEOUT 3, WPNAV_SPEED 1000 cm/s,
    # WPNAV_ACCEL 250 cm/s/s
    lim = vh.flight_limits(vh.Autopilot.ARDUPILOT, {"FS_GCS_ENABLE": 0.0, "GUID_TIMEOUT": 3.0, "WPNAV_SPEED": 1000.0,
                                                    "WPNAV_ACCEL": 250.0}, our_system=255)
    assert (lim.cruise_mps, lim.accel_mps2, lim.hold_last_s) == (10.0, 2.5, 3.0)
    assert lim.lateral_accel_mps2 == pytest.approx(1.5)  # corners planned with 0.6 x: its target has a jerk limit
    assert lim.leaves_flying and "FS_GCS_ENABLE=0" in lim.link_loss and "hovering" in lim.link_loss
    # the measured coast: 5 m/s for GUID_TIMEOUT then braking at 2.5 m/s^2 ended 20.5 m past the last target
    assert lim.coast_m(5.0) == pytest.approx(5.0 * 3.0 + 25.0 / 5.0)


def test_the_autopilots_return_altitude_in_metres_and_said_with_its_parameter():
    ardu = vh.flight_limits(vh.Autopilot.ARDUPILOT, {"RTL_ALT": 2500.0}, our_system=255)
    assert (ardu.return_altitude_m, ardu.return_described) == (25.0, "RTL_ALT=2500 cm")
    unread = vh.flight_limits(vh.Autopilot.ARDUPILOT, {}, our_system=255)  # ArduCopter's default, said so
    assert unread.return_altitude_m == 15.0 and "not reported" in unread.return_described
    px4 = vh.flight_limits(vh.Autopilot.PX4, {"RTL_RETURN_ALT": 30.0}, our_system=255)
    assert (px4.return_altitude_m, px4.return_described) == (30.0, "RTL_RETURN_ALT=30 m")


def test_ardupilot_gcs_failsafe_counts_only_its_own_gcs_system():
    on = {"FS_GCS_ENABLE": 5.0, "FS_GCS_TIMEOUT": 5.0, "MAV_GCS_SYSID": 255.0}
    assert not vh.flight_limits(vh.Autopilot.ARDUPILOT, on, our_system=255).leaves_flying
    assert "LAND" in vh.flight_limits(vh.Autopilot.ARDUPILOT, on, our_system=255).link_loss
    other = vh.flight_limits(vh.Autopilot.ARDUPILOT, {**on, "MAV_GCS_SYSID": 250.0}, our_system=255)
    assert other.leaves_flying and "system 250" in other.link_loss


def test_px4_defaults_land_without_rc_and_only_hold_leaves_the_vehicle_hovering():
    # PX4 1.15 defaults (read on SITL): COM_OF_LOSS_T 1.0, COM_OBL_RC_ACT 0, NAV_DLL_ACT 0, MPC_ACC_HOR 3; after an
    # offboard loss PX4 SITL (no RC) went to position mode, descended at 0.6-0.9 m/s and disarmed on landing
    stock = vh.flight_limits(vh.Autopilot.PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0.0, "NAV_DLL_ACT": 0.0,
                                                "MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MPC_XY_P": 0.95},
                              our_system=255)
    assert not stock.leaves_flying and "position mode" in stock.link_loss and "lands" in stock.link_loss
    assert (stock.cruise_mps, stock.accel_mps2) == (12.0, 3.0)
    hold = vh.flight_limits(vh.Autopilot.PX4, {"COM_OBL_RC_ACT": 5.0, "NAV_DLL_ACT": 0.0}, our_system=255)
    assert hold.leaves_flying and "hovering" in hold.link_loss
    assert stock.hold_last_s == pytest.approx(1.0 / 0.95)  # the feed-forward overshoots by v / MPC_XY_P


def test_a_longer_px4_offboard_timeout_does_not_lengthen_the_coast_past_a_held_position():
    # PX4 1.15 SITL, COM_OF_LOSS_T = 5 s: 5 m/s went 6.6 m past the last position target and settled back towards
    # 5.3 m until the failsafe; the coast bound (v / MPC_XY_P, then braking) is 9.4 m either way, not 5 s x 5 m/s
    params = {"COM_OBL_RC_ACT": 0.0, "NAV_DLL_ACT": 0.0, "MPC_ACC_HOR": 3.0, "MPC_XY_P": 0.95}
    short = vh.flight_limits(vh.Autopilot.PX4, {**params, "COM_OF_LOSS_T": 1.0}, our_system=255)
    long = vh.flight_limits(vh.Autopilot.PX4, {**params, "COM_OF_LOSS_T": 5.0}, our_system=255)
    assert long.coast_m(5.0) == short.coast_m(5.0) == pytest.approx(5.0 / 0.95 + 25.0 / 6.0)
    assert long.coast_m(5.0) >= 6.9
    assert "after 5 s without setpoints" in long.link_loss  # the failsafe itself still comes when it says
    landing = vh.flight_limits(vh.Autopilot.PX4, {"COM_OBL_RC_ACT": 4.0}, our_system=255)
    assert not landing.leaves_flying and "Land" in landing.link_loss and "not reported" in landing.link_loss


def test_the_clearance_speed_is_the_inverse_of_the_coast():
    lim = vh.FlightLimits(hold_last_s=3.0, brake_mps2=2.5)
    for speed in (0.5, 3.0, 10.0):
        assert lim.speed_for_clearance_mps(lim.coast_m(speed)) == pytest.approx(speed)
    assert lim.speed_for_clearance_mps(0.0) == 0.0


# --------------------------------------------------------------------------------------------- readiness
def test_a_fresh_ardupilot_is_not_ready_until_its_ekf_uses_gps():
    # what a freshly booted ArduCopter SITL sends: GLOBAL_POSITION_INT at 0, 0 and no LOCAL_POSITION_NED
    t = vh.Telemetry(last_heartbeat_s=0.0, lat_deg=0.0, lon_deg=0.0, global_rx_s=9.5, gps_fix_type=1,
                     satellites=0, prearm_ok=False,
                     statustexts=(vh.StatusText(2, "PreArm: Need Position Estimate", 9.0),
                                  vh.StatusText(6, "Barometer 1 calibration complete", 9.1)))
    r = vh.readiness(t, now_s=10.0)
    assert not r.ready
    assert r.missing == ("a 3D GPS fix (0 satellites)", "a global position estimate", "a home position",
                         "a local position estimate", "a landed state (EXTENDED_SYS_STATE)",
                         "the autopilot's pre-arm checks")
    assert r.reasons == ("PreArm: Need Position Estimate",)
    ready = vh.Telemetry(last_heartbeat_s=0.0, lat_deg=37.0, lon_deg=-122.0, global_rx_s=9.9, north_m=0.0,
                         east_m=0.0, down_m=0.0, local_rx_s=9.9, home=MAP_ORIGIN, gps_fix_type=3, prearm_ok=True,
                         landed_rx_s=9.9)
    assert vh.readiness(ready, now_s=10.0).ready
    assert "a fresh local position" in vh.readiness(ready, now_s=20.0).describe()  # the stream stopped


# ------------------------------------------------------------------------------------------- link health
def test_any_message_keeps_the_link_alive_and_the_timeout_follows_the_round_trip():
    now = [0.0]
    health = LinkHealth(floor_s=2.0, rtt_factor=4.0, clock=lambda: now[0])
    assert not health.ok()  # nothing heard yet
    for k in range(100):  # positions at 20 Hz, no heartbeat for 5 s
        now[0] = 0.05 * k
        health.heard()
    assert health.ok()
    now[0] = 4.95 + 1.9
    assert health.ok()
    now[0] = 4.95 + 2.1
    assert not health.ok()
    for _ in range(5):
        health.round_trip(0.4)  # 200 ms each way
    assert health.timeout_s == pytest.approx(1.6 if 1.6 > 2.0 else 2.0)
    health.round_trip(0.9)
    assert health.timeout_s == pytest.approx(3.6) and health.rtt_s == pytest.approx(0.8 * 0.4 + 0.2 * 0.9)


# ----------------------------------------------------------------------------------------------- streams
def test_a_stream_that_stops_is_asked_for_again_with_backoff():
    k = StreamKeeper({"GLOBAL_POSITION_INT": 10.0}, patience_s=2.0, max_backoff_s=8.0)
    asked = []
    for step in range(300):  # 30 s, the stream never arrives
        now = 0.1 * step
        if k.due(now):
            k.asked("GLOBAL_POSITION_INT", now)
            asked.append(round(now, 1))
    assert asked == [0.0, 2.0, 6.0, 14.0, 22.0]  # 2, 4, 8, 8 (capped) s apart
    k.received("GLOBAL_POSITION_INT", 24.5)
    assert not k.due(25.0) and k.silent(25.0) == []


# ------------------------------------------------------------------------------------------- modes
@pytest.mark.parametrize("autopilot, mode, kind", [
    (vh.Autopilot.PX4, "OFFBOARD", "ours"), (vh.Autopilot.PX4, "LOITER", "hold"),
    (vh.Autopilot.PX4, "RTL", "return"), (vh.Autopilot.PX4, "POSCTL", "pilot"), (vh.Autopilot.PX4, "ALTCTL", "pilot"),
    (vh.Autopilot.PX4, "MISSION", "other"),
    (vh.Autopilot.ARDUPILOT, "GUIDED", "ours"), (vh.Autopilot.ARDUPILOT, "LAND", "return"),
    (vh.Autopilot.ARDUPILOT, "LOITER", "pilot"), (vh.Autopilot.ARDUPILOT, "STABILIZE", "pilot"),
    (vh.Autopilot.ARDUPILOT, "BRAKE", "hold"), (vh.Autopilot.ARDUPILOT, "AUTO", "other"),
    (vh.Autopilot.GENERIC, "OFFBOARD", "ours"),
])
def test_mode_kinds(autopilot, mode, kind):
    assert vh.mode_kind(autopilot, mode).value == kind


# ------------------------------------------------------------------------------------------- connections
@pytest.mark.parametrize("text, why", [
    ("bogus://x", "unknown connection type 'bogus'"), ("tcp:127.0.0.1:abc", "needs HOST:PORT"),
    ("tcp:localhost", "needs HOST:PORT"), ("udpin:0.0.0.0:99999", "port 99999 is not in 1..65535"),
    ("", "empty"), ("localhost:14550", "unknown connection type 'localhost'"),
])
def test_connection_strings_pymavlink_would_misread_are_refused(text, why):
    with pytest.raises(vh.BadConnection, match=re.escape(why)):
        check_connection_string(text)


def test_connection_strings_pymavlink_cannot_open_are_bad_connections():
    with pytest.raises(vh.BadConnection, match="/dev/skyroute-no-such-device"):
        vh.MavlinkVehicle("/dev/skyroute-no-such-device", heartbeat_timeout_s=0.5)
    with pytest.raises(vh.BadConnection, match="unknown host"):
        vh.MavlinkVehicle("tcp:no-such-host.invalid:5760", heartbeat_timeout_s=0.5)


def test_signing_key_is_hex_or_the_sha256_of_a_passphrase():
    assert vh.signing_key("ab" * 32) == bytes([0xAB] * 32)
    assert vh.signing_key("correct horse") == hashlib.sha256(b"correct horse").digest()
    with pytest.raises(ValueError):
        vh.signing_key("  ")


# ------------------------------------------------------------------ what mutmut found unguarded in translation
def test_update_telemetry_dispatches_each_message_and_stamps_its_receive_time():
    t = vh.Telemetry()
    t = vh.update_telemetry(t, roundtrip(lambda e: e.global_position_int_encode(
        4200, 377924801, -1223974500, 25500, 10250, 100, -200, 50, 9000)), 7.25)
    t = vh.update_telemetry(t, roundtrip(lambda e: e.local_position_ned_encode(1500, 3.0, -4.0, -12.0, 0, 0, 0)),
                            7.5)
    t = vh.update_telemetry(t, roundtrip(lambda e: e.extended_sys_state_encode(0, 2)), 7.75)
    t = vh.update_telemetry(t, roundtrip(lambda e: e.attitude_encode(0, 0.1, -0.2, 0.3, 0, 0, 0)), 8.0)
    assert t.lat_deg == pytest.approx(37.7924801, abs=1e-9) and t.global_rx_s == 7.25
    assert t.local == LocalNED(3.0, -4.0, -12.0) and t.local_rx_s == 7.5
    assert t.landed_state is vh.LandedState.IN_AIR and t.landed_rx_s == 7.75
    assert (t.roll_rad, t.pitch_rad, t.heading_rad) == (pytest.approx(0.1), pytest.approx(-0.2), pytest.approx(0.3))


def test_a_heartbeat_carries_the_system_status_and_a_gcs_is_never_an_autopilot():
    msg = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                 mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6 << 16,
                                                 mavlink.MAV_STATE_CRITICAL))
    assert vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0).system_status == mavlink.MAV_STATE_CRITICAL
    # a ground station that fills in an autopilot field (QGroundControl says ARDUPILOTMEGA) is still a GCS
    qgc = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0))
    assert not vh.is_autopilot_heartbeat(qgc)


def test_a_generic_autopilot_without_the_custom_mode_flag_has_no_px4_mode():
    msg = roundtrip(lambda e: e.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC,
                                                 mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 6 << 16, 0))
    assert vh.telemetry_from_heartbeat(vh.Telemetry(), msg, 0.0).mode != "OFFBOARD"


def test_unknown_satellites_are_minus_one_and_an_empty_battery_is_zero_not_unknown():
    raw = roundtrip(lambda e: e.gps_raw_int_encode(0, 3, 377924781, -1223974503, -150, 70, 110, 5, 12640, 255))
    assert vh.telemetry_from_gps_raw_int(vh.Telemetry(), raw, 0.0).satellites == -1
    pre = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    empty = roundtrip(lambda e: e.sys_status_encode(pre, pre, 0, 0, 10500, -1, 0, 0, 0, 0, 0, 0, 0))
    t = vh.telemetry_from_sys_status(vh.Telemetry(), empty, 0.0)
    assert t.battery_remaining_pct == 0.0
    assert t.prearm_ok is False  # the pre-arm check is present but not healthy


def test_map_offset_extrapolates_the_local_sample_to_the_global_one_up_to_a_second_apart():
    # at the map origin, 10 m up (AMSL 10, ground 0); local sample at (1, 2, -4) moving (2, -3, 0.5) m/s
    def offset(local_time_s):
        t = vh.Telemetry(lat_deg=MAP_ORIGIN.lat_deg, lon_deg=MAP_ORIGIN.lon_deg, alt_amsl_m=10.0, global_time_s=10.0,
                         north_m=1.0, east_m=2.0, down_m=-4.0, local_v_north_mps=2.0, local_v_east_mps=-3.0,
                         local_v_down_mps=0.5, local_time_s=local_time_s)
        return tuple(vh.map_offset(t, MAP_ORIGIN, ground_amsl_m=0.0))

    # map (0, 0, -10) = local extrapolated by dt = global - local seconds + offset
    for dt in (0.5, -0.5, 1.0):
        expected = (0 - (1 + 2 * dt), 0 - (2 - 3 * dt), -10 - (-4 + 0.5 * dt))
        assert offset(10.0 - dt) == pytest.approx(expected, abs=1e-6), dt
    for local_time_s in (8.5, 11.5, math.nan):  # more than a second apart (or unknown): not extrapolated
        assert offset(local_time_s) == pytest.approx((-1.0, -2.0, -6.0), abs=1e-6), local_time_s
