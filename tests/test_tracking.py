"""The low-level tracker: desired displacement -> steer, thrust and brakes within the aircraft's limits."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.control.tracking import (
    AircraftLimits,
    rollout_displacements,
    speed_and_yaw_rate,
    track_displacement,
    track_velocity,
)

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


def test_rollout_of_a_straight_request_follows_it():
    targets = np.stack([3.0 * np.arange(1, 9), np.zeros(8)], axis=1)  # 6 m/s straight ahead
    pos, yaw = rollout_displacements(np.zeros(2), 0.0, 6.0, targets, period=0.5, limits=LIMITS)
    np.testing.assert_allclose(pos, targets, atol=1e-9)
    np.testing.assert_allclose(yaw, 0.0, atol=1e-12)


def test_rollout_of_a_sideways_request_rolls_forward_while_it_turns():
    """An aircraft standing still and asked to move to its left cannot: it rolls ahead as it turns."""
    targets = np.stack([np.zeros(6), 3.0 * np.arange(1, 7)], axis=1)
    pos, yaw = rollout_displacements(np.zeros(2), 0.0, 0.0, targets, period=0.5, limits=LIMITS)
    assert pos[0, 0] > 0.05 and pos[0, 1] < 0.5 * pos[0, 0] + 1e-9  # mostly forward in the first period
    assert np.all(np.diff(yaw) >= 0.0) and 0.0 < yaw[-1] <= 6 * 0.5 * LIMITS.max_yaw_rate
    assert np.max(pos[:, 0]) > 1.0  # the nose goes ahead, where a sideways step would not


@given(
    speed=st.floats(0.0, 6.0),
    yaw=st.floats(-math.pi, math.pi),
    steps=st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)), min_size=1, max_size=8),
)
def test_rollout_stays_within_the_speed_and_yaw_rate_limits(speed, yaw, steps):
    targets = np.cumsum(np.array(steps), axis=0)
    pos, heading = rollout_displacements(np.zeros(2), yaw, speed, targets, period=0.5, limits=LIMITS)
    travel = np.hypot(*np.diff(np.concatenate([np.zeros((1, 2)), pos]), axis=0).T)
    assert np.all(travel <= max(speed, LIMITS.max_speed) * 0.5 + 1e-9)
    turn = np.abs(np.diff(np.concatenate([[yaw], heading])))
    assert np.all(turn <= LIMITS.max_yaw_rate * 0.5 + 1e-9)
