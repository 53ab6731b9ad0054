"""Kinematic models of the deck's vehicles and walkers as discrete-time CasADi Functions.

Every model is a ``casadi.Function`` ``f(x, u) -> x_next`` that advances the state by one step of ``dt``
seconds with ``substeps`` explicit fourth-order Runge-Kutta steps, inputs held constant over the step
(zero-order hold). Units are SI: metres, seconds, radians, metres per second, metres per second squared.
Headings are measured from the world +x axis towards +y.

Models:
    ``unicycle``          deck tractor (non-holonomic): x = (px, py, heading, speed), u = (accel, turn rate).
    ``holonomic_point``   pedestrian: x = (px, py, vx, vy), u = (ax, ay).
    ``kinematic_bicycle`` the aircraft (rear-axle reference): x = (px, py, yaw, speed), u = (accel, steer).

With ``saturate=True`` (the default) the inputs are clipped to their limits inside the Function and the
speed is kept within its limits, so a rollout can never leave the model's envelope; with ``saturate=False``
the model is smooth (for least-squares fits and optimal-control solvers, which impose the limits as bounds
instead).

Built once and called many times; calling a Function on ``casadi.SX`` arguments inlines it into a larger
expression graph, which is how the predictor batches its rollouts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca

UNICYCLE_STATES = ("px", "py", "heading", "speed")
"""Unicycle state names, in order: position x, y (m), heading (rad), forward speed (m/s)."""
UNICYCLE_INPUTS = ("accel", "turn_rate")
"""Unicycle input names, in order: longitudinal acceleration (m/s^2), turn rate (rad/s)."""
POINT_STATES = ("px", "py", "vx", "vy")
"""Holonomic point state names, in order: position x, y (m), velocity x, y (m/s)."""
POINT_INPUTS = ("ax", "ay")
"""Holonomic point input names, in order: acceleration x, y (m/s^2)."""
BICYCLE_STATES = ("px", "py", "yaw", "speed")
"""Kinematic bicycle state names, in order: rear-axle position x, y (m), yaw (rad), speed (m/s)."""
BICYCLE_INPUTS = ("accel", "steer")
"""Kinematic bicycle input names, in order: acceleration (m/s^2), front (nose) wheel steer angle (rad)."""


@dataclass(frozen=True)
class UnicycleLimits:
    """Bounds of a unicycle (deck tractor). Defaults fit the deck tractors."""

    max_speed: float = 6.0
    """Largest forward speed, m/s (the speed is kept in [0, max_speed]: tractors do not reverse here)."""
    max_accel: float = 1.5
    """Largest forward acceleration, m/s^2."""
    max_decel: float = 1.5
    """Largest braking deceleration (positive number), m/s^2."""
    max_turn_rate: float = 0.6
    """Largest turn rate magnitude, rad/s."""


@dataclass(frozen=True)
class PointLimits:
    """Bounds of a holonomic point (pedestrian). Defaults fit walkers."""

    max_speed: float = 2.0
    """Largest speed magnitude, m/s."""
    max_accel: float = 1.0
    """Largest acceleration magnitude, m/s^2."""


@dataclass(frozen=True)
class BicycleParams:
    """Geometry and bounds of the aircraft's kinematic bicycle model."""

    wheelbase: float = 5.4
    """Main-gear axle (reference point) to nose wheel, m (F/A-18E/F class: about 5.4 m)."""
    max_speed: float = 8.0
    """Largest forward speed, m/s (taxi speeds on deck are a few m/s)."""
    min_speed: float = 0.0
    """Smallest speed, m/s (0: no reversing; aircraft are pushed back by tractors, not by themselves)."""
    max_accel: float = 1.0
    """Largest acceleration, m/s^2."""
    max_decel: float = 2.0
    """Largest braking deceleration (positive number), m/s^2."""
    max_steer: float = 1.2
    """Largest nose-wheel steer angle magnitude, rad (about 70 degrees)."""


def _clip(x: ca.SX, lo: float | ca.SX, hi: float | ca.SX) -> ca.SX:
    """Elementwise clip of ``x`` into [lo, hi]."""
    return ca.fmin(ca.fmax(x, lo), hi)


def rk4_step(ode: Callable[[ca.SX, ca.SX], ca.SX], x: ca.SX, u: ca.SX, h: float | ca.SX) -> ca.SX:
    """One explicit RK4 step of ``dx/dt = ode(x, u)`` over ``h`` seconds (``h`` may be negative)."""
    k1 = ode(x, u)
    k2 = ode(x + 0.5 * h * k1, u)
    k3 = ode(x + 0.5 * h * k2, u)
    k4 = ode(x + h * k3, u)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def unicycle_ode(x: ca.SX, u: ca.SX) -> ca.SX:
    """Continuous unicycle: d(px, py, heading, speed)/dt for inputs (accel m/s^2, turn rate rad/s)."""
    return ca.vertcat(x[3] * ca.cos(x[2]), x[3] * ca.sin(x[2]), u[1], u[0])


def point_ode(x: ca.SX, u: ca.SX) -> ca.SX:
    """Continuous holonomic point dynamics: d(px, py, vx, vy)/dt for inputs (ax, ay) m/s^2."""
    return ca.vertcat(x[2], x[3], u[0], u[1])


def bicycle_ode(wheelbase: float) -> Callable[[ca.SX, ca.SX], ca.SX]:
    """Continuous kinematic bicycle dynamics about the rear axle, for a ``wheelbase`` in metres.

    d(px, py, yaw, speed)/dt = (v cos yaw, v sin yaw, v tan(steer) / wheelbase, accel).
    """

    def ode(x: ca.SX, u: ca.SX) -> ca.SX:
        return ca.vertcat(x[3] * ca.cos(x[2]), x[3] * ca.sin(x[2]), x[3] * ca.tan(u[1]) / wheelbase, u[0])

    return ode


def _discretise(
    name: str,
    ode: Callable[[ca.SX, ca.SX], ca.SX],
    dt: float,
    substeps: int,
    states: tuple[str, ...],
    inputs: tuple[str, ...],
    pre: Callable[[ca.SX, ca.SX], ca.SX] | None,
    post: Callable[[ca.SX], ca.SX] | None,
) -> ca.Function:
    if not dt > 0:
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    if substeps < 1:
        raise ValueError(f"substeps must be at least 1, got {substeps!r}")
    x = ca.SX.sym("x", len(states))
    u = ca.SX.sym("u", len(inputs))
    uu = pre(x, u) if pre is not None else u
    xn = x
    for _ in range(substeps):
        xn = rk4_step(ode, xn, uu, dt / substeps)
        if post is not None:
            xn = post(xn)
    return ca.Function(name, [x, u], [xn], ["x", "u"], ["x_next"])


def unicycle(
    dt: float, limits: UnicycleLimits | None = None, substeps: int = 1, saturate: bool = True
) -> ca.Function:
    """Discrete unicycle ``f(x, u) -> x_next`` over ``dt`` seconds.

    Args:
        dt: Step length, s.
        limits: Input and speed bounds; ``UnicycleLimits()`` if omitted.
        substeps: RK4 substeps per step.
        saturate: Clip accel to [-max_decel, max_accel], turn rate to +-max_turn_rate and speed to
            [0, max_speed].

    Returns:
        Function ``unicycle(x[4], u[2]) -> x_next[4]``, states ``UNICYCLE_STATES``, inputs
        ``UNICYCLE_INPUTS``.
    """
    lim = limits or UnicycleLimits()
    pre = post = None
    if saturate:

        def pre(x: ca.SX, u: ca.SX) -> ca.SX:
            # Braking cannot take the speed below zero within the step: cap the deceleration at speed / dt.
            accel = _clip(u[0], ca.fmax(-lim.max_decel, -x[3] / dt), lim.max_accel)
            return ca.vertcat(accel, _clip(u[1], -lim.max_turn_rate, lim.max_turn_rate))

        def post(x: ca.SX) -> ca.SX:
            return ca.vertcat(x[0], x[1], x[2], _clip(x[3], 0.0, lim.max_speed))

    return _discretise("unicycle", unicycle_ode, dt, substeps, UNICYCLE_STATES, UNICYCLE_INPUTS, pre, post)


def holonomic_point(
    dt: float, limits: PointLimits | None = None, substeps: int = 1, saturate: bool = True
) -> ca.Function:
    """Discrete holonomic point ``f(x, u) -> x_next`` over ``dt`` seconds (a pedestrian).

    Args:
        dt: Step length, s.
        limits: Acceleration and speed bounds; ``PointLimits()`` if omitted.
        substeps: RK4 substeps per step.
        saturate: Scale the acceleration vector down to ``max_accel`` and the velocity vector to
            ``max_speed``.

    Returns:
        Function ``holonomic_point(x[4], u[2]) -> x_next[4]`` with states ``POINT_STATES``, inputs
        ``POINT_INPUTS``.
    """
    lim = limits or PointLimits()
    pre = post = None
    if saturate:

        def pre(x: ca.SX, u: ca.SX) -> ca.SX:
            return u * ca.fmin(1.0, lim.max_accel / ca.fmax(ca.norm_2(u), 1e-12))

        def post(x: ca.SX) -> ca.SX:
            scale = ca.fmin(1.0, lim.max_speed / ca.fmax(ca.norm_2(x[2:4]), 1e-12))
            return ca.vertcat(x[0:2], x[2:4] * scale)

    return _discretise("holonomic_point", point_ode, dt, substeps, POINT_STATES, POINT_INPUTS, pre, post)


def kinematic_bicycle(
    dt: float, params: BicycleParams | None = None, substeps: int = 1, saturate: bool = True
) -> ca.Function:
    """Discrete kinematic bicycle ``f(x, u) -> x_next`` over ``dt`` seconds (the aircraft on its gear).

    The reference point is the middle of the main-gear (rear) axle; the nose wheel, ``wheelbase`` metres
    ahead, steers. Yaw rate = speed * tan(steer) / wheelbase.

    Args:
        dt: Step length, s.
        params: Wheelbase and bounds; ``BicycleParams()`` if omitted.
        substeps: RK4 substeps per step.
        saturate: Clip accel to [-max_decel, max_accel], steer to +-max_steer, speed to
            [min_speed, max_speed].

    Returns:
        Function ``kinematic_bicycle(x[4], u[2]) -> x_next[4]``, states ``BICYCLE_STATES``, inputs
        ``BICYCLE_INPUTS``.
    """
    par = params or BicycleParams()
    if not par.wheelbase > 0:
        raise ValueError(f"wheelbase must be a positive length in metres, got {par.wheelbase!r}")
    pre = post = None
    if saturate:

        def pre(x: ca.SX, u: ca.SX) -> ca.SX:
            return ca.vertcat(
                _clip(u[0], -par.max_decel, par.max_accel), _clip(u[1], -par.max_steer, par.max_steer)
            )

        def post(x: ca.SX) -> ca.SX:
            return ca.vertcat(x[0], x[1], x[2], _clip(x[3], par.min_speed, par.max_speed))

    return _discretise(
        "kinematic_bicycle",
        bicycle_ode(par.wheelbase),
        dt,
        substeps,
        BICYCLE_STATES,
        BICYCLE_INPUTS,
        pre,
        post,
    )
