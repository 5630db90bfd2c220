"""The sim's reading of a SET_POSITION_TARGET_LOCAL_NED's acceleration: PX4 OFFBOARD's feed-forward."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from sim.setpoints import local_ned_target
from skyroute.vehicle import TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW, TYPE_MASK_POSITION_VELOCITY_YAW


def autopilot(*, px4: bool, yaw_rad: float = 0.0, local_scale=(1.0, 1.0, 1.0)):
    """The parts of the sim's autopilot a setpoint is read against: at map (10 N, 20 E, 5 up), origin at 0."""
    return SimpleNamespace(cfg=SimpleNamespace(strict=True), is_px4=px4, position_neu=np.array([10.0, 20.0, 5.0]),
                           origin_neu=np.zeros(3), quad=SimpleNamespace(state=SimpleNamespace(yaw_rad=yaw_rad)),
                           local_scale=np.array(local_scale))


def setpoint(mask: int, frame: int = M.MAV_FRAME_LOCAL_NED):
    # north 30 m, east 40 m, 5 m up; 3 m/s north; 1.5 m/s^2 north, 0.5 m/s^2 east, 0.2 m/s^2 down
    return M.MAVLink_set_position_target_local_ned_message(0, 1, 1, frame, mask, 30.0, 40.0, -5.0, 3.0, 0.0, 0.0,
                                                           1.5, 0.5, 0.2, 0.0, 0.0)


def test_px4_takes_a_setpoints_acceleration_as_a_feedforward_in_the_map_frame():
    target = local_ned_target(autopilot(px4=True), SimpleNamespace(classic=False, link_id=1),
                              setpoint(TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW))
    assert target.position_neu == pytest.approx((30.0, 40.0, 5.0))
    assert target.accel_neu == pytest.approx((1.5, 0.5, -0.2))  # NED down -> up


def test_a_body_frame_acceleration_is_turned_by_the_heading():
    target = local_ned_target(autopilot(px4=True, yaw_rad=math.pi / 2), SimpleNamespace(classic=False, link_id=1),
                              setpoint(TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW, M.MAV_FRAME_BODY_OFFSET_NED))
    assert target.accel_neu == pytest.approx((-0.5, 1.5, -0.2))  # forward is east, right is south


@pytest.mark.parametrize("px4, mask", [
    pytest.param(True, TYPE_MASK_POSITION_VELOCITY_YAW, id="px4-acceleration-masked"),
    pytest.param(False, TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW, id="ardupilot"),
    pytest.param(True, TYPE_MASK_POSITION_VELOCITY_ACCEL_YAW | M.POSITION_TARGET_TYPEMASK_FORCE_SET, id="force"),
])
def test_an_acceleration_masked_out_or_sent_to_ardupilot_is_ignored(px4, mask):
    target = local_ned_target(autopilot(px4=px4), SimpleNamespace(classic=False, link_id=1), setpoint(mask))
    assert target.position_neu == pytest.approx((30.0, 40.0, 5.0))
    assert all(math.isnan(a) for a in target.accel_neu)


def test_a_local_setpoint_is_in_the_autopilots_local_metres_not_the_maps():
    """ArduPilot's local north is 0.29 % longer than the map's metres at SF: 30 m north in its frame is 29.9 m."""
    scale = (1.00287, 0.99876, 1.0)
    target = local_ned_target(autopilot(px4=False, local_scale=scale), SimpleNamespace(classic=False, link_id=1),
                              setpoint(TYPE_MASK_POSITION_VELOCITY_YAW))
    assert target.position_neu == pytest.approx((30.0 / 1.00287, 40.0 / 0.99876, 5.0))
