"""The MPC predictor's moving-horizon estimator of a mover's state (symbolic, ``casadi.SX``).

A weighted least-squares fit of the unicycle model with constant acceleration and turn rate over the window
to the mover's newest ``estimation_window`` positions, by a fixed number of damped Gauss-Newton iterations
from two starts (see ``MovingHorizonEstimator.estimate``). Positions are relative to the mover's newest
sample, m; SI units throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from deck_sim.control.models import UnicycleLimits, unicycle, unicycle_ode
from deck_sim.control.mpc_settings import N_ESTIMATE, MPCPredictorSettings
from deck_sim.control.mpc_symbolic import select, wrap_angle


def _quadratic_fit_matrix(window: int, dt: float, forgetting: float) -> np.ndarray:
    """(3, window) matrix B with B @ y = (c0, c1, c2) of the weighted fit y(t) = c0 + c1 t + c2 t^2.

    Sample j (newest first) is at t_j = -j dt seconds with weight ``forgetting**j``.
    """
    t = -np.arange(window) * dt
    a = np.stack([np.ones(window), t, t * t], axis=1)
    w = forgetting ** np.arange(window)
    return np.linalg.solve(a.T @ (w[:, None] * a), a.T * w)


@dataclass(frozen=True)
class Estimate:
    """The mover's state now, in canonical form (speed >= 0, heading wrapped, accel and turn rate bounded)."""

    position: ca.SX
    """(2,) relative to the newest sample, m."""
    heading: ca.SX
    """rad."""
    speed: ca.SX
    """m/s."""
    accel: ca.SX
    """m/s^2."""
    turn_rate: ca.SX
    """rad/s."""
    decel: ca.SX
    """``-accel``, m/s^2."""


class MovingHorizonEstimator:
    """The estimator for one ``MPCPredictorSettings`` (window, forgetting, iterations, priors)."""

    def __init__(self, s: MPCPredictorSettings) -> None:
        self.s = s
        self.W = s.estimation_window

    def residual_function(self) -> ca.Function:
        """r(z, y) of the moving-horizon fit, m; z = (px, py, heading, speed, accel, turn rate) now, y (2, W)."""
        s = self.s
        z = ca.SX.sym("z", N_ESTIMATE)
        y = ca.SX.sym("y", 2, self.W)
        sw = np.sqrt(s.forgetting ** np.arange(self.W))
        x = z[0:4]
        u = z[4:6]
        res = [sw[0] * (x[0:2] - y[:, 0])]
        h = -s.dt / s.estimation_substeps
        for j in range(1, self.W):
            for _ in range(s.estimation_substeps):
                k1 = unicycle_ode(x, u)
                k2 = unicycle_ode(x + 0.5 * h * k1, u)
                k3 = unicycle_ode(x + 0.5 * h * k2, u)
                k4 = unicycle_ode(x + h * k3, u)
                x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
            res.append(sw[j] * (x[0:2] - y[:, j]))
        res.append(np.sqrt(s.accel_weight) * z[4])
        res.append(np.sqrt(s.turn_rate_weight) * z[5])
        return ca.Function("mhe_residual", [z, y], [ca.vertcat(*res)])

    def gauss_newton_function(self, residual: ca.Function) -> ca.Function:
        """One damped Gauss-Newton step z -> z_next."""
        z = ca.SX.sym("z", N_ESTIMATE)
        y = ca.SX.sym("y", 2, self.W)
        r = residual(z, y)
        jac = ca.jacobian(r, z)
        hess = ca.mtimes(jac.T, jac) + self.s.damping * ca.SX.eye(N_ESTIMATE)
        step = -ca.solve(hess, ca.mtimes(jac.T, r))
        return ca.Function("gauss_newton", [z, y], [z + step])

    def estimate(self, y: ca.SX, now: ca.SX, z_prev: ca.SX, valid: ca.SX) -> Estimate:
        """Moving-horizon estimate of the mover's state now, relative to the newest sample.

        Fixed Gauss-Newton iterations from two starts, the closed-form weighted quadratic fit and the previous
        estimate propagated one period (the quadratic fit again while there is none); the start with the
        lower final cost wins.

        Args:
            y: (2, W) the newest W samples, newest first, relative to the newest sample, m.
            now: (2,) the newest sample, world coordinates, m.
            z_prev: (N_ESTIMATE,) the previous step's estimate (position in world coordinates, m).
            valid: 1 if ``z_prev`` holds an estimate.
        """
        s, W = self.s, self.W
        bmat = _quadratic_fit_matrix(W, s.dt, s.forgetting)
        cx = ca.mtimes(ca.DM(bmat), y[0, :].T)
        cy = ca.mtimes(ca.DM(bmat), y[1, :].T)
        vx, vy, ax, ay = cx[1], cy[1], 2 * cx[2], 2 * cy[2]
        sp2 = vx * vx + vy * vy
        sp = ca.sqrt(sp2)
        z_poly = ca.vertcat(
            cx[0],
            cy[0],
            ca.atan2(vy, vx),
            sp,
            (ax * vx + ay * vy) / ca.fmax(sp, 1e-3),
            (vx * ay - vy * ax) / ca.fmax(sp2, 0.25),
        )
        # Warm start: last estimate propagated one period, in coordinates relative to the newest sample.
        x_w = unicycle(s.dt, UnicycleLimits(max_speed=1e3, max_accel=1e3, max_decel=1e3, max_turn_rate=1e3))(
            ca.vertcat(z_prev[0:2] - now, z_prev[2], z_prev[3]), z_prev[4:6]
        )
        z_warm = ca.vertcat(x_w, z_prev[4:6])
        z_warm = select(valid > 0.5, z_warm, z_poly)

        residual = self.residual_function()
        gn = self.gauss_newton_function(residual)
        finals = []
        for z in (z_poly, z_warm):
            for _ in range(s.gauss_newton_iterations):
                z = gn(z, y)
            r = residual(z, y)
            finals.append((z, ca.dot(r, r)))
        (z_a, cost_a), (z_b, cost_b) = finals
        z = select(cost_b < cost_a, z_b, z_a)
        # Canonical form: non-negative speed, wrapped heading, bounded accel and turn rate.
        neg = z[3] < 0
        acc = ca.fmin(ca.fmax(select(neg, -z[4], z[4]), -3.0), 3.0)
        return Estimate(
            position=z[0:2],
            heading=wrap_angle(z[2] + select(neg, np.pi, 0.0)),
            speed=ca.fabs(z[3]),
            accel=acc,
            turn_rate=ca.fmin(ca.fmax(z[5], -1.5), 1.5),
            decel=-acc,
        )
