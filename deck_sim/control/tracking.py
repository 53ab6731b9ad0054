"""Low-level tracking: turn the policy's desired displacement into actuator commands within vehicle limits.

The policy asks for a planar displacement over the next decision period (paper's action (X, Y), scaled by the
scene's reach). A wheeled aircraft cannot move sideways, so ``AircraftTracker`` turns the request into a speed
and a heading to steer to: the nose wheel is set for the yaw rate that closes the heading error within
``heading_time`` (bicycle model, authority limited by speed), and thrust or brakes close the speed error within
``speed_time``. Commands are computed once per decision and held, as a pilot's would be. The same speed and
yaw-rate law drives taxiing aircraft that are movers. A pedestrian simply walks at the requested velocity.

Plain Python and numpy only, so it is cheap enough to run every control step and tested without MuJoCo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AircraftLimits:
    """Physical constants of the aircraft the tracker needs (from aircraft.xml) and its comfort limits."""

    mass: float
    """kg, whole vehicle."""
    wheelbase: float = 5.4
    """m, nose-wheel axle to main-gear axle."""
    max_steer: float = 1.2
    """rad, nose-wheel lock."""
    max_thrust: float = 30000.0
    """N at thrust command 1."""
    brake_kv: float = 4000.0
    """N m s per rad of one main-wheel brake damper at command 1."""
    wheel_radius: float = 0.45
    """m, main wheels."""
    max_speed: float = 6.0
    """m/s, taxi speed limit."""
    max_lateral_accel: float = 2.0
    """m/s^2, limits steering with speed (the nose tyre saturates beyond)."""
    max_yaw_rate: float = 0.8
    """rad/s."""
    heading_time: float = 1.0
    """s, time constant to close a heading error."""
    speed_time: float = 0.6
    """s, time constant to close a speed error."""
    min_turn_speed: float = 1.0
    """m/s kept while turning towards a direction far off the nose (an aircraft cannot pivot)."""


@dataclass(frozen=True)
class AircraftCommand:
    """Actuator commands for one aircraft: steer (rad), thrust (0..1), brake (0..1, both main wheels)."""

    steer: float
    thrust: float
    brake: float


def steer_for_yaw_rate(yaw_rate: float, speed: float, limits: AircraftLimits) -> float:
    """Nose-wheel angle (rad) giving ``yaw_rate`` (rad/s) at forward ``speed`` (m/s), bicycle model.

    The authority shrinks with speed so the lateral acceleration stays below ``limits.max_lateral_accel``.
    """
    v = max(abs(speed), 0.5)
    steer = math.atan(yaw_rate * limits.wheelbase / v)
    cap = min(limits.max_steer, math.atan(limits.max_lateral_accel * limits.wheelbase / (v * v)))
    return min(max(steer, -cap), cap)


def speed_and_yaw_rate(
    desired_speed: float, desired_yaw_rate: float, speed: float, limits: AircraftLimits
) -> AircraftCommand:
    """Steer, thrust and brake that bring one aircraft to a forward speed (m/s) and yaw rate (rad/s).

    Scalar Python on purpose: it runs every control step, where numpy's per-call cost on one-element arrays
    would be ten times the arithmetic.
    """
    desired_speed = min(max(desired_speed, 0.0), limits.max_speed)
    accel = (desired_speed - speed) / limits.speed_time
    thrust = min(max(accel * limits.mass / limits.max_thrust, 0.0), 1.0)
    brake = 0.0
    if desired_speed < 0.05:
        brake = 1.0  # parking brake when asked to stand
    elif accel < 0.0:
        # damper brakes: decel = 2 kv c v / (r^2 m)  ->  c = -a r^2 m / (2 kv v)
        v = max(speed, 0.2)
        brake = min(-accel * limits.wheel_radius**2 * limits.mass / (2.0 * limits.brake_kv * v), 1.0)
    yaw_rate = min(max(desired_yaw_rate, -limits.max_yaw_rate), limits.max_yaw_rate)
    steer = steer_for_yaw_rate(yaw_rate, max(speed, desired_speed), limits)
    return AircraftCommand(steer=steer, thrust=thrust, brake=brake)


def displacement_request(
    dx: float, dy: float, heading: float, period: float, limits: AircraftLimits
) -> tuple[float, float]:
    """The forward speed (m/s) and yaw rate (rad/s) the tracker asks of an aircraft that should move by (dx, dy)
    metres (world frame) over ``period`` seconds from ``heading`` (radians), before the limits of
    ``speed_and_yaw_rate``; (0, 0) for a request under a millimetre."""
    dist = math.hypot(dx, dy)
    if dist < 1e-3:
        return 0.0, 0.0
    err = (math.atan2(dy, dx) - heading + math.pi) % (2.0 * math.pi) - math.pi
    v_des = dist / period
    # slow down to turn, but keep rolling at up to ``min_turn_speed``: an aircraft turns on the move, it cannot
    # pivot, and a slow creep at full nose-wheel lock ploughs the nose tyre instead of turning
    turning = min(v_des, limits.min_turn_speed)
    v_des = max(v_des * math.cos(err), turning) if abs(err) < math.pi / 2 else turning
    return v_des, err / limits.heading_time


def track_displacement(
    dx: float, dy: float, heading: float, speed: float, period: float, limits: AircraftLimits
) -> AircraftCommand:
    """Commands for an aircraft asked to move by (dx, dy) metres (world frame) over ``period`` seconds.

    Args:
        dx, dy: desired displacement over the next decision period, metres.
        heading: current yaw, radians.
        speed: current forward speed, m/s.
        period: decision period, seconds.
    """
    return speed_and_yaw_rate(*displacement_request(dx, dy, heading, period, limits), speed, limits)


def rollout_displacements(
    xy: np.ndarray,
    yaw: float,
    speed: float,
    targets: np.ndarray,
    period: float,
    limits: AircraftLimits,
    substeps: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Where an aircraft asked to reach ``targets`` (N, 2), one per decision period, would be: the kinematics
    ``track_displacement`` asks for, as if the airframe obtained them.

    Each period the tracker's command (``displacement_request``, then ``speed_and_yaw_rate``) is computed once from
    the state at its start and held: the speed closes
    on the asked speed with time constant ``limits.speed_time`` and the yaw rate is the bicycle model's at the
    commanded nose-wheel angle. A planner uses it to check the path the aircraft will really take, which cuts
    corners and cannot pivot, where the displacement it asks for would move sideways.

    Args:
        xy: (2,) position now, metres (world frame).
        yaw: heading now, radians.
        speed: forward speed now, m/s.
        targets: (N, 2) where the aircraft is asked to be at the end of each of the next N periods, metres.
        period: decision period, seconds.
        substeps: Euler steps per period.

    Returns:
        (N, 2) positions and (N,) headings (radians) at the end of each period.
    """
    x, y, h, v = float(xy[0]), float(xy[1]), float(yaw), float(speed)
    dt = period / substeps
    gain = min(dt / limits.speed_time, 1.0)
    pos = np.empty((len(targets), 2))
    heading = np.empty(len(targets))
    for k, (tx, ty) in enumerate(np.asarray(targets, dtype=float).tolist()):
        asked, yaw_rate = displacement_request(tx - x, ty - y, h, period, limits)
        steer = speed_and_yaw_rate(asked, yaw_rate, v, limits).steer  # the nose-wheel angle the tracker holds
        v_des = min(max(asked, 0.0), limits.max_speed)  # the speed it closes on, as ``speed_and_yaw_rate``
        curvature = math.tan(steer) / limits.wheelbase
        for _ in range(substeps):
            v += (v_des - v) * gain
            h += v * curvature * dt
            x += v * math.cos(h) * dt
            y += v * math.sin(h) * dt
        pos[k] = (x, y)
        heading[k] = h
    return pos, heading


def track_velocity(displacement: np.ndarray, period: float, max_speed: float) -> np.ndarray:
    """World-frame walking velocity (n, 2) m/s for a holonomic walker asked to move by ``displacement``."""
    vel = np.atleast_2d(displacement) / period
    norm = np.hypot(vel[:, 0], vel[:, 1])
    scale = np.minimum(1.0, max_speed / np.maximum(norm, 1e-9))
    return vel * scale[:, None]
