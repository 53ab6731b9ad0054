"""The low-level tracker: desired displacement -> steer, thrust and brakes within the aircraft's limits."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.control.tracking import AircraftLimits, speed_and_yaw_rate, track_displacement, track_velocity

LIMITS = AircraftLimits(mass=14830.0)


def test_straight_ahead_request_thrusts_without_steering():
    cmd = track_displacement(3.0, 0.0, heading=0.0, speed=0.0, period=0.5, limits=LIMITS)
    assert cmd.steer == 0.0 and cmd.thrust > 0.0 and cmd.brake == 0.0


def test_standing_request_brakes():
    cmd = track_displacement(0.0, 0.0, heading=0.3, speed=4.0, period=0.5, limits=LIMITS)
    assert cmd.thrust == 0.0 and cmd.brake == 1.0


def test_request_to_the_left_steers_left_and_behind_keeps_rolling_slowly():
    left = track_displacement(0.0, 3.0, heading=0.0, speed=2.0, period=0.5, limits=LIMITS)
    assert left.steer > 0.0
    behind = track_displacement(-3.0, 0.1, heading=0.0, speed=0.0, period=0.5, limits=LIMITS)
    assert behind.steer > 0.0 and behind.thrust > 0.0  # turns round on the move, never asks to reverse


@given(speed=st.floats(0, 10), yaw_rate=st.floats(-3, 3), v_des=st.floats(-5, 20))
def test_commands_stay_within_the_actuator_ranges(speed, yaw_rate, v_des):
    cmd = speed_and_yaw_rate(v_des, yaw_rate, speed, LIMITS)
    assert abs(cmd.steer) <= LIMITS.max_steer
    assert 0.0 <= cmd.thrust <= 1.0 and 0.0 <= cmd.brake <= 1.0
    # steering authority shrinks with speed: the lateral acceleration of the bicycle model stays bounded
    v = max(speed, min(max(v_des, 0.0), LIMITS.max_speed), 0.5)
    assert v * v * math.tan(abs(cmd.steer)) / LIMITS.wheelbase <= LIMITS.max_lateral_accel + 1e-9


def test_walking_velocity_is_capped():
    v = track_velocity(np.array([[3.0, 4.0]]), period=0.5, max_speed=1.5)
    assert np.linalg.norm(v) == pytest.approx(1.5)
    np.testing.assert_allclose(v[0] / np.linalg.norm(v), [0.6, 0.8])
