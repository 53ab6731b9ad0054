"""The MPC predictor of the dynamic obstacles (paper Section II.B.1, eq. 1-2), built with CasADi.

At every control step, for every mover, one compiled CasADi Function does three things (the paper's
multi-step prediction, rolling optimisation and feedback correction):

1. **Moving-horizon estimation.** A weighted least-squares fit of the mover's kinematic model (a unicycle
   with constant acceleration and turn rate over the window) to its last ``estimation_window`` observed
   positions, by a fixed number of damped Gauss-Newton iterations from two starts: the previous step's
   estimate propagated by one period (warm start, the feedback correction) and a closed-form weighted
   quadratic fit; the start with the lower final cost wins. Result: position, heading, speed, acceleration
   and turn rate now.
2. **Intent.** A belief over the map's special spots (public map knowledge), plus a "none of them"
   hypothesis, updated every step from how well each spot explains the mover's heading (anticipated by its
   turn rate) and its braking (the deceleration needed to stop at the spot against the one observed),
   discounted over time, reset when the mover stops at a spot, and excluding the spot it just left. The
   likeliest hypothesis is chosen.
3. **Rollout.** The mover's model (``deck_sim.control.models``: unicycle for wheeled movers, holonomic point
   for pedestrians) is rolled forward ``horizon`` steps under a goal-seeking control law within its speed,
   acceleration and turn-rate limits: turn towards the chosen spot (gently while the mover is not yet
   turning towards it: it may be on a detour leg around an obstacle the predictor cannot see), cruise, brake
   to a stop on it. Under "none" it keeps its heading and speed (finishing an acceleration it has begun, or a
   braking with no spot to explain it). Movers stop, for a few seconds at most, while another mover
   (extrapolated at constant velocity) is close ahead of them, as deck movers yield. A mover standing still
   stays put.

All movers are evaluated by one ``Function.map`` of that Function, generated as C, compiled with gcc and
cached on disk (``MPCPredictorSettings.compile``); without a C compiler the same Function runs in CasADi's
virtual machine. Non-finite results fall back to constant velocity for that mover (``Prediction.fallback``,
``fallback_count``).

A control-law rollout rather than an optimal-control solve: the movers themselves follow a control law, and
an IPOPT solve of a mover's optimal approach to its spot (``benchmarks/prediction_synthetic.py``,
``OptimalControl``) predicted them slightly worse (it brakes later and harder than the movers do) at about
7 ms per mover, some 500x the rollout's cost.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from deck_sim.control.models import PointLimits, UnicycleLimits, holonomic_point, unicycle, unicycle_ode
from deck_sim.control.prediction import (
    PredictionInputError,
    constant_velocity_rollout,
    least_squares_velocity,
    validate_tracks,
)
from deck_sim.types import ObstacleKind, ObstacleTracks, Prediction

log = logging.getLogger(__name__)

_FUNCTION_NAME = "deck_sim_mpc_predictor"
_N_EST = 6  # estimate: px, py, heading, speed, accel, turn rate
_N_INFO = 8
_PEDESTRIAN = int(ObstacleKind.PEDESTRIAN)


@dataclass(frozen=True)
class MoverModel:
    """Limits and behaviour of one kind of mover, as the predictor assumes them."""

    max_speed: float
    """Largest speed, m/s."""
    max_accel: float
    """Acceleration used when the mover speeds up towards its cruise speed, m/s^2."""
    brake_decel: tuple[float, float]
    """Range (lo, hi) of the braking deceleration movers use to stop at a spot, m/s^2."""
    max_turn_rate: float
    """Largest turn rate, rad/s (wheeled movers; pedestrians are holonomic and ignore it)."""
    cruise_speed: tuple[float, float]
    """Range (lo, hi) of the cruise speeds movers pick at every departure, m/s."""
    heading_gain: float = 1.5
    """Turn rate commanded per radian of bearing error to the spot in the rollout, 1/s."""
    speed_time_constant: float = 0.5
    """Time constant of the rollout's speed tracking, s."""
    yield_distance: float = 0.0
    """A mover stops while another mover is less than this far ahead of it (centre to centre), m; 0: never."""
    yield_width: float = 0.0
    """... and less than this far to the side of its line of travel, m."""
    yield_time: float = 4.0
    """... for at most this long, then goes anyway, s."""


@dataclass(frozen=True)
class MPCPredictorSettings:
    """Everything the MPC predictor needs; frozen, hashed into the compiled artefact's cache key."""

    horizon: int = 10
    """Number of predicted steps N, each ``dt`` seconds apart."""
    dt: float = 0.5
    """Seconds between samples, in the history and in the prediction (the task's decision period)."""
    history: int = 10
    """Samples of history used (the last ``history`` of the tracks); tracks must hold at least this many."""
    max_spots: int = 16
    """Capacity for special spots compiled into the Function; ``reset`` refuses more."""
    max_movers: int = 16
    """Capacity for movers that others may yield to, compiled into the Function; ``predict`` refuses more."""

    # Moving-horizon estimation.
    estimation_window: int = 5
    """Most recent samples fitted by the moving-horizon estimator (at most ``history``, at least 3)."""
    forgetting: float = 0.6
    """Weight of a sample j periods old in the fit is ``forgetting**j`` (0 < forgetting <= 1)."""
    gauss_newton_iterations: int = 2
    """Fixed number of damped Gauss-Newton iterations from each start."""
    damping: float = 1e-6
    """Levenberg damping added to the Gauss-Newton normal matrix, in the residuals' units (m^2)."""
    accel_weight: float = 0.01
    """Prior weight pulling the estimated acceleration to zero, (m / (m/s^2))^2."""
    turn_rate_weight: float = 0.1
    """Prior weight pulling the estimated turn rate to zero, (m / (rad/s))^2."""
    estimation_substeps: int = 1
    """RK4 substeps per period when the estimator integrates the model back over the window."""

    # Movers.
    wheeled: MoverModel = field(
        default_factory=lambda: MoverModel(
            max_speed=6.0,
            max_accel=1.0,
            brake_decel=(1.0, 1.5),
            max_turn_rate=0.6,
            cruise_speed=(2.0, 5.0),
            yield_distance=10.0,
            yield_width=3.0,
            yield_time=2.0,
        )
    )
    """Model of wheeled movers (deck tractors): unicycle."""
    pedestrian: MoverModel = field(
        default_factory=lambda: MoverModel(
            max_speed=2.0,
            max_accel=1.0,
            brake_decel=(0.8, 1.2),
            max_turn_rate=3.0,
            cruise_speed=(1.0, 1.6),
            heading_gain=3.0,
            speed_time_constant=0.4,
        )
    )
    """Model of pedestrians: holonomic point."""

    # Intent belief.
    belief_decay: float = 0.8
    """Each step the log-belief is multiplied by this before the new log-likelihood is added (0..1)."""
    heading_sigma: float = 0.25
    """Standard deviation of a mover's heading about the bearing to its spot, rad."""
    speed_noise: float = 0.1
    """Speed uncertainty widening the heading likelihood of slow movers: var += (speed_noise / v)^2, m/s."""
    lateral_sigma: float = 0.5
    """Standard deviation of a spot's lateral offset from the line of travel of a mover heading to it, m."""
    heading_floor: float = 0.15
    """Likelihood floor of the heading term (detours around obstacles point away from the spot)."""
    turn_lookahead: float = 1.0
    """Seconds of the current turn rate added to the heading before comparing it with a spot's bearing, s."""
    brake_sigma: float = 0.3
    """Standard deviation of the observed deceleration about the one needed to stop at a spot, m/s^2."""
    brake_sigma_rel: float = 0.25
    """Part of that deviation proportional to the needed deceleration (estimates lag as braking starts)."""
    brake_margin: float = 0.2
    """Tolerance added to the braking range when judging whether a mover should already be braking, m/s^2."""
    brake_floor: float = 0.02
    """Likelihood floor of a spot the mover should already be braking for but is not."""
    free_keeps_braking: bool = True
    """Under "none", a braking mover keeps braking at the rate seen to a stop (else it holds its speed)."""
    brake_threshold: float = 0.3
    """Deceleration above which a mover counts as braking, m/s^2."""
    none_loglik: float = -4.0
    """Log-likelihood per step of the "heading to no spot" hypothesis (on the spots' scale: 0 is perfect)."""
    at_spot_radius: float = 4.0
    """A mover stopped within this distance of a spot is at that spot, m."""
    stop_speed: float = 0.25
    """A mover whose newest displacement is below ``stop_speed * dt`` (plus noise) is standing still, m/s."""
    stop_samples: int = 1
    """How many newest displacements must be below that for a mover to count as standing (1 or 2)."""
    position_noise: float = 0.01
    """Standard deviation of the noise on observed positions, m (widens the standing-still test)."""

    # Cruise speed.
    cruise_accel_threshold: float = 0.2
    """Movers with |accel| below this and |turn rate| below ``cruise_turn_threshold`` cruise, m/s^2."""
    cruise_turn_threshold: float = 0.1
    """See ``cruise_accel_threshold``, rad/s."""
    cruise_memory: int = 8
    """Cruise speed is the running mean of the last ``cruise_memory`` cruising speed estimates."""

    # Rollout.
    steady_line_window: int = 4
    """While a mover holds its speed and heading, the rollout starts from a straight-line fit over this many
    samples rather than from the moving-horizon estimate (0: always the estimate)."""
    detour_heading_gain: float = 0.15
    """Rollout turn rate per radian of bearing error to the spot while the mover is not yet turning towards
    it (it may be on a straight detour leg around something the predictor cannot see), 1/s. While it turns
    towards the spot, brakes, is near it or is slower than ``steer_speed``, the model's ``heading_gain``
    applies."""
    steer_time: float = 5.0
    """Within ``speed * steer_time`` metres of the spot the rollout steers at it with the full gain, s."""
    steer_speed: float = 1.0
    """Below this speed (departing) the rollout steers at the spot with the full heading gain, m/s."""
    rollout_substeps: int = 1
    """Model integration substeps per predicted step."""
    stop_offset: float = 0.2
    """Movers stop this far short of the spot's centre, m."""

    # Compilation.
    compile: str = "auto"
    """"auto": generate C, compile it with ``compiler`` into the cache, load it; fall back to CasADi's virtual
    machine (logged) if that fails. "c": the same but raise on failure. "none": virtual machine only."""
    compiler: str = "gcc"
    """C compiler executable."""
    compiler_flags: tuple[str, ...] = ("-O1", "-fPIC", "-shared")
    """Flags for the compiler (-O2 runs about 10% faster but compiles about 50% longer)."""
    cache_dir: str | None = None
    """Directory for compiled artefacts; None: ``default_cache_dir()`` (``$DECK_SIM_CACHE/casadi``, else
    ``$XDG_CACHE_HOME/deck_sim/casadi``, else ``~/.cache/deck_sim/casadi``). Artefacts are keyed by a hash of
    the C source, compiler, flags, CasADi version and platform."""

    def __post_init__(self) -> None:
        problems = []
        if self.horizon < 1:
            problems.append(f"horizon must be >= 1, got {self.horizon}")
        if not self.dt > 0:
            problems.append(f"dt must be > 0 s, got {self.dt}")
        if not 3 <= self.estimation_window <= self.history:
            problems.append(
                f"estimation_window must be in [3, history={self.history}], got {self.estimation_window}"
            )
        if not 0 < self.forgetting <= 1:
            problems.append(f"forgetting must be in (0, 1], got {self.forgetting}")
        if not 0 <= self.belief_decay <= 1:
            problems.append(f"belief_decay must be in [0, 1], got {self.belief_decay}")
        if self.max_spots < 1:
            problems.append(f"max_spots must be >= 1, got {self.max_spots}")
        if self.stop_samples not in (1, 2):
            problems.append(f"stop_samples must be 1 or 2, got {self.stop_samples}")
        if self.gauss_newton_iterations < 1 or self.rollout_substeps < 1 or self.estimation_substeps < 1:
            problems.append("gauss_newton_iterations, rollout_substeps and estimation_substeps must be >= 1")
        if self.max_movers < 1:
            problems.append(f"max_movers must be >= 1, got {self.max_movers}")
        if self.compile not in ("auto", "c", "none"):
            problems.append(f"compile must be 'auto', 'c' or 'none', got {self.compile!r}")
        if problems:
            raise ValueError("invalid MPCPredictorSettings: " + "; ".join(problems))

    @property
    def memory_size(self) -> int:
        """Length of the per-mover memory vector carried between steps."""
        return _N_EST + 4 + 2 * self.max_spots + 1


def _wrap(a: ca.SX) -> ca.SX:
    """Angle wrapped into (-pi, pi]."""
    return ca.atan2(ca.sin(a), ca.cos(a))


def _sel(cond: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """``a`` where ``cond`` else ``b`` (both evaluated)."""
    return ca.if_else(cond, a, b)


def _quadratic_fit_matrix(window: int, dt: float, forgetting: float) -> np.ndarray:
    """(3, window) matrix B with B @ y = (c0, c1, c2) of the weighted fit y(t) = c0 + c1 t + c2 t^2.

    Sample j (newest first) is at t_j = -j dt seconds with weight ``forgetting**j``.
    """
    t = -np.arange(window) * dt
    a = np.stack([np.ones(window), t, t * t], axis=1)
    w = forgetting ** np.arange(window)
    return np.linalg.solve(a.T @ (w[:, None] * a), a.T * w)


class _Builder:
    """Builds the single-mover symbolic Function; see the module docstring for what it computes."""

    def __init__(self, s: MPCPredictorSettings) -> None:
        self.s = s
        self.K = s.max_spots
        self.W = s.estimation_window

    # ----- estimation -----
    def residual_function(self) -> ca.Function:
        """r(z, y) of the moving-horizon fit; z = (px, py, heading, speed, accel, turn rate) now, y (2, W)."""
        s = self.s
        z = ca.SX.sym("z", _N_EST)
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
        z = ca.SX.sym("z", _N_EST)
        y = ca.SX.sym("y", 2, self.W)
        r = residual(z, y)
        jac = ca.jacobian(r, z)
        hess = ca.mtimes(jac.T, jac) + self.s.damping * ca.SX.eye(_N_EST)
        step = -ca.solve(hess, ca.mtimes(jac.T, r))
        return ca.Function("gauss_newton", [z, y], [z + step])

    # ----- rollouts -----
    def speed_command(self, v, gap, v_cruise, b, b_lim, m: MoverModel):
        """(desired speed m/s, acceleration m/s^2) of a mover at speed ``v`` that cruises at ``v_cruise``
        and stops ``gap`` metres ahead braking at ``b``: track min(cruise, stopping profile) with the mover's
        time constant, braking no harder than ``b_lim``; once the deceleration needed to stop in the gap
        reaches ``b``, brake with exactly that deceleration."""
        room = gap - self.s.stop_offset
        v_des = ca.fmin(v_cruise, ca.sqrt(2.0 * b * ca.fmax(room, 0.0)))
        need = v * v / (2.0 * ca.fmax(room, 0.05))
        track = ca.fmax((v_des - v) / m.speed_time_constant, -b_lim)
        return v_des, _sel(need >= b, -ca.fmin(need, 2.0 * b), track)

    def blocked(self, p, direction, t: float, m: MoverModel):
        """1 where another mover (moving at its current velocity) is within ``m.yield_distance`` ahead of a
        mover at ``p`` going along the unit vector ``direction``, ``t`` seconds from now, and within
        ``m.yield_width`` of its line; else 0. Uses the ``others`` inputs set by ``build``."""
        if m.yield_distance <= 0:
            return ca.SX(0)
        rel = self.others + t * self.others_vel - ca.repmat(p, 1, self.others.shape[1])
        along = direction[0] * rel[0, :] + direction[1] * rel[1, :]
        lateral = ca.fabs(direction[0] * rel[1, :] - direction[1] * rel[0, :])
        ahead = (along > 0.1) * (along < m.yield_distance) * (lateral < m.yield_width) * self.others_live
        return ca.mmax(ahead)

    def rollout_wheeled(self, p0, th0, v0, goal, v_cruise, b, b_lim, steer, m: MoverModel) -> list:
        """Positions (N of (2,)) of a unicycle driving to ``goal`` (see ``speed_command``).

        Steering (``steer``): turn at the bearing error times the model's heading gain, slowing as
        cos(error), and brake for the spot itself; otherwise turn at the detour gain and brake for the point
        abeam the spot. Stops while another mover is close ahead (``blocked``)."""
        s = self.s
        h = s.dt / s.rollout_substeps
        lim = UnicycleLimits(
            max_speed=m.max_speed,
            max_accel=m.max_accel,
            max_decel=2.0 * m.brake_decel[1],
            max_turn_rate=m.max_turn_rate,
        )
        f = unicycle(h, lim)
        gain = _sel(steer, m.heading_gain, s.detour_heading_gain)
        x = ca.vertcat(p0, th0, v0)
        out = []
        t = 0.0
        waited = ca.SX(0.0)
        for _ in range(s.horizon):
            for _ in range(s.rollout_substeps):
                d = goal - x[0:2]
                dist = ca.norm_2(d)
                err = _wrap(ca.atan2(d[1], d[0]) - x[2])
                err = _sel(dist < 0.5, 0.0, err)
                gap = _sel(steer, dist, dist * ca.cos(err))
                v_des, acc = self.speed_command(x[3], gap, v_cruise, b, b_lim, m)
                slow = _sel(steer, ca.fmax(ca.cos(err), 0.0), 1.0)
                acc = _sel(slow < 1.0, ca.fmin(acc, (v_des * slow - x[3]) / m.speed_time_constant), acc)
                stop = self.blocked(x[0:2], ca.vertcat(ca.cos(x[2]), ca.sin(x[2])), t, m) * (
                    waited < m.yield_time
                )
                waited = waited + h * stop
                acc = _sel(stop, ca.fmax(-x[3] / h, -2.0 * m.brake_decel[1]), acc)
                x = f(x, ca.vertcat(acc, gain * err))
                t += h
            out.append(x[0:2])
        return out

    def rollout_point(self, p0, vel0, goal, v_cruise, b, b_lim, steer, m: MoverModel) -> list:
        """Positions (N of (2,)) of a pedestrian (holonomic point) walking to ``goal``.

        Its desired walking direction turns towards the goal (full or detour gain, within the turn-rate
        limit), its desired speed follows ``speed_command``, and the point tracks that desired velocity within
        its acceleration limit."""
        s = self.s
        h = s.dt / s.rollout_substeps
        f = holonomic_point(h, PointLimits(max_speed=m.max_speed, max_accel=2.0 * m.brake_decel[1]))
        gain = _sel(steer, m.heading_gain, s.detour_heading_gain)
        x = ca.vertcat(p0, vel0)
        psi = ca.atan2(vel0[1], vel0[0])
        out = []
        t = 0.0
        waited = ca.SX(0.0)
        for _ in range(s.horizon):
            for _ in range(s.rollout_substeps):
                d = goal - x[0:2]
                dist = ca.norm_2(d)
                err = _wrap(ca.atan2(d[1], d[0]) - psi)
                err = _sel(dist < 0.3, 0.0, err)
                psi = psi + h * ca.fmin(ca.fmax(gain * err, -m.max_turn_rate), m.max_turn_rate)
                gap = _sel(steer, dist, dist * ca.cos(err))
                speed = ca.norm_2(x[2:4])
                _, acc = self.speed_command(speed, gap, v_cruise, b, b_lim, m)
                heading = ca.vertcat(ca.cos(psi), ca.sin(psi))
                stop = self.blocked(x[0:2], heading, t, m) * (waited < m.yield_time)
                waited = waited + h * stop
                acc = _sel(stop, -speed / h, acc)
                x = f(x, (ca.fmax(speed + acc * h, 0.0) * heading - x[2:4]) / h)
                t += h
            out.append(x[0:2])
        return out

    # ----- the whole step -----
    def build(self) -> ca.Function:
        s, K, W = self.s, self.K, self.W
        H, N = s.history, s.horizon
        y_abs = ca.SX.sym("history", 2, H)
        spots_abs = ca.SX.sym("spots", 2, K)
        mask = ca.SX.sym("spot_mask", 1, K)
        kind = ca.SX.sym("kind")
        mem = ca.SX.sym("memory", s.memory_size)
        force = ca.SX.sym("force_spot")
        me = ca.SX.sym("self_index")
        others = ca.SX.sym("others", 2, s.max_movers)
        others_vel = ca.SX.sym("others_velocity", 2, s.max_movers)
        others_mask = ca.SX.sym("others_mask", 1, s.max_movers)
        self.others = others - ca.repmat(y_abs[:, H - 1], 1, s.max_movers)
        self.others_vel = others_vel
        self.others_live = others_mask * ca.horzcat(*[me != j for j in range(s.max_movers)])

        now = y_abs[:, H - 1]
        # Newest first, relative to the newest sample.
        y = ca.horzcat(*[y_abs[:, H - 1 - j] - now for j in range(W)])
        spots = spots_abs - ca.repmat(now, 1, K)

        z_prev = mem[0:_N_EST]
        valid = mem[6]
        v_avg = mem[7]
        n_cruise = mem[8]
        logb = mem[10 : 10 + K].T
        logb_none = mem[10 + K]
        excl = mem[11 + K : 11 + 2 * K].T

        ped = kind > 0.5
        mw, mp = s.wheeled, s.pedestrian

        def by_kind(a: float, b: float) -> ca.SX:
            return _sel(ped, b, a)

        # 1. Moving-horizon estimation from two starts.
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
        z_warm = _sel(valid > 0.5, z_warm, z_poly)

        residual = self.residual_function()
        gn = self.gauss_newton_function(residual)
        finals = []
        for z in (z_poly, z_warm):
            for _ in range(s.gauss_newton_iterations):
                z = gn(z, y)
            r = residual(z, y)
            finals.append((z, ca.dot(r, r)))
        (z_a, cost_a), (z_b, cost_b) = finals
        z = _sel(cost_b < cost_a, z_b, z_a)
        # Canonical form: non-negative speed, wrapped heading, bounded accel and turn rate.
        neg = z[3] < 0
        p0 = z[0:2]
        th = _wrap(z[2] + _sel(neg, np.pi, 0.0))
        v = ca.fabs(z[3])
        acc = ca.fmin(ca.fmax(_sel(neg, -z[4], z[4]), -3.0), 3.0)
        w = ca.fmin(ca.fmax(z[5], -1.5), 1.5)

        # 2. Standing still? Near a spot? Standing still: the newest displacement is below the threshold
        # (displacements of a standing mover are pure measurement noise: allow 3 sigma of a difference of two
        # samples). One sample suffices: a fit across a hard stop sees a spurious acceleration, and a mover
        # that has just stopped is likelier to stay.
        d1 = ca.norm_2(y[:, 0] - y[:, 1])
        d2 = ca.norm_2(y[:, 1] - y[:, 2])
        still_step = s.stop_speed * s.dt + 3.0 * np.sqrt(2.0) * s.position_noise
        stopped = _sel(s.stop_samples >= 2, ca.fmax(d1, d2), d1) < still_step
        dist = ca.sqrt(ca.sum1(spots * spots) + 1e-12)  # (1, K)
        big = 1e6
        dist_valid = dist + (1 - mask) * big
        dmin = ca.mmin(dist_valid)
        nearest = dist_valid <= dmin  # one-hot (ties: several)
        at_spot = stopped * (dmin < s.at_spot_radius)

        # 3. Belief update. Heading: lateral offset of each spot from the mover's (anticipated) line of
        # travel, in metres near the mover and in radians far away; spots behind it count as fully off the
        # line.
        bearing = ca.atan2(spots[1, :], spots[0, :])
        err = _wrap(bearing - (th + w * s.turn_lookahead))
        lateral = _sel(ca.cos(err) > 0, dist * ca.sin(err), dist)
        ang_var = s.heading_sigma**2 + (s.speed_noise / ca.fmax(v, 0.05)) ** 2
        var = s.lateral_sigma**2 + ang_var * dist * dist
        # The floor (detours) only for spots ahead: a mover does not drive away from its spot.
        floor = s.heading_floor * ca.fmax(ca.cos(err), 0.0) + 1e-6
        ll_head = ca.log(floor + ca.exp(-(lateral * lateral) / (2 * var)))
        # Braking: a mover brakes for its spot once the deceleration needed to stop there (a_req) reaches its
        # own braking deceleration, drawn from [b_lo, b_hi]. Braking now: a_req should match the deceleration
        # seen. Not braking yet: P = fraction of braking decelerations still above a_req.
        b_lo = by_kind(mw.brake_decel[0], mp.brake_decel[0])
        b_hi = by_kind(mw.brake_decel[1], mp.brake_decel[1])
        a_req = v * v / (2 * ca.fmax(dist - s.stop_offset, 0.5))
        decel = -acc
        braking = 1.0 / (1.0 + ca.exp(-(decel - s.brake_threshold) / 0.1))
        sig_a = s.brake_sigma + s.brake_sigma_rel * a_req
        ll_brake = -((a_req - decel) ** 2) / (2 * sig_a * sig_a)
        frac = (b_hi + s.brake_margin - a_req) / (b_hi - b_lo + s.brake_margin)
        ll_cruise = ca.log(ca.fmin(ca.fmax(frac, s.brake_floor), 1.0))
        ll = ll_head + braking * ll_brake + (1 - braking) * ll_cruise
        moving = 1 - stopped
        allowed = mask * (1 - excl)
        lb = _sel(moving, s.belief_decay * logb + ll, logb)
        lb_none = _sel(moving, s.belief_decay * logb_none + s.none_loglik, logb_none)
        lb = lb * allowed - (1 - allowed) * 1e3
        # Reset at a stop at a spot: uniform belief, exclude the spot it is at.
        lb = _sel(at_spot, -(1 - mask) * 1e3 - nearest * 1e3, lb)
        lb_none = _sel(at_spot, 0.0, lb_none)
        excl_new = _sel(at_spot, nearest, excl)
        top = ca.fmax(ca.mmax(lb), lb_none)
        lb = ca.fmax(lb - top, -1e3)
        lb_none = ca.fmax(lb_none - top, -1e3)

        # Likeliest hypothesis (index -1: none), or the forced one.
        best = ca.SX(-1.0)
        best_l = lb_none
        for j in range(K):
            better = lb[j] > best_l
            best = _sel(better, j, best)
            best_l = _sel(better, lb[j], best_l)
        best = _sel(force >= 0, force, best)
        onehot = ca.horzcat(*[best == j for j in range(K)])
        goal = ca.mtimes(spots, onehot.T)
        # A mover heading away from the spot and not turning towards it may be on a detour leg around
        # something the predictor cannot see: steer at the spot only gently then.
        goal_err = _wrap(ca.atan2(goal[1], goal[0]) - th)
        turning_to = (w * goal_err > 0) * (ca.fabs(w) > s.cruise_turn_threshold)
        near = ca.norm_2(goal) < v * s.steer_time
        steer = ca.logic_or(
            ca.logic_or(turning_to, v < s.steer_speed), ca.logic_or(near, decel > s.brake_threshold)
        )
        has_goal = best >= 0
        p_best = ca.exp(best_l) / (ca.sum2(ca.exp(lb)) + ca.exp(lb_none))

        # 4. Cruise speed.
        cruising = moving * (ca.fabs(acc) < s.cruise_accel_threshold) * (ca.fabs(w) < s.cruise_turn_threshold)
        cruising = cruising * (v > 0.5)
        n_new = _sel(at_spot, 0.0, n_cruise + cruising)
        v_avg_new = _sel(cruising, v_avg + (v - v_avg) / ca.fmin(n_new, s.cruise_memory), v_avg)
        v_avg_new = _sel(at_spot, 0.0, v_avg_new)
        c_lo = by_kind(mw.cruise_speed[0], mp.cruise_speed[0])
        c_hi = by_kind(mw.cruise_speed[1], mp.cruise_speed[1])
        accelerating = acc > s.cruise_accel_threshold
        v_guess = _sel(accelerating, 0.5 * (ca.fmax(v, c_lo) + c_hi), v)
        v_cruise = _sel(n_new > 0.5, _sel(accelerating, ca.fmax(v_avg_new, v), v_avg_new), v_guess)
        v_cruise = ca.fmax(v_cruise, v)
        # Braking along its stopping profile for the goal: use the deceleration it shows (v^2 / 2d).
        d_goal = ca.norm_2(goal)
        b_seen = v * v / (2 * ca.fmax(d_goal - s.stop_offset, 0.1))
        b = _sel(decel > s.brake_threshold, ca.fmin(ca.fmax(b_seen, b_lo), b_hi), 0.5 * (b_lo + b_hi))
        v_free = _sel(accelerating, v_cruise, v)
        # Braking with no spot to explain it (yielding): keep braking at the rate seen, or hold the speed.
        brake_free = decel > s.brake_threshold
        if s.free_keeps_braking:
            v_free = _sel(brake_free, 0.0, v_free)
        b_free = _sel(brake_free, ca.fmin(decel, b_hi), b_hi)

        # 5. Rollouts, from the estimate; while the mover holds speed and heading, from a straight-line fit
        # over the last few samples instead (fewer parameters, less noise: constant velocity is near-perfect
        # there).
        if s.steady_line_window >= 2:
            nl = s.steady_line_window
            tl = -np.arange(nl) * s.dt
            cl = (tl - tl.mean()) / np.sum((tl - tl.mean()) ** 2)
            v_line = ca.mtimes(y[:, 0:nl], ca.DM(cl))
            p_line = ca.sum2(y[:, 0:nl]) / nl - v_line * tl.mean()
            steady = (
                (ca.fabs(acc) < s.cruise_accel_threshold) * (ca.fabs(w) < s.cruise_turn_threshold) * (v > 0.5)
            )
            p_r = _sel(steady, p_line, p0)
            th_r = _sel(steady, ca.atan2(v_line[1], v_line[0]), th)
            v_r = _sel(steady, ca.norm_2(v_line), v)
            v_free = _sel(steady, v_r, v_free)
            v_cruise = _sel(steady, v_r, v_cruise)
        else:
            p_r, th_r, v_r = p0, th, v
        # One rollout per kind: to the chosen spot, or under "none" to a point far ahead on the current line.
        far = p_r + 1e4 * ca.vertcat(ca.cos(th_r), ca.sin(th_r))
        r_goal = _sel(has_goal, goal, far)
        r_vc = _sel(has_goal, v_cruise, v_free)
        r_blim = _sel(has_goal, 2.0 * b_hi, b_free)
        r_steer = ca.logic_and(has_goal, steer)
        vel0 = v_r * ca.vertcat(ca.cos(th_r), ca.sin(th_r))
        rw = self.rollout_wheeled(p_r, th_r, v_r, r_goal, r_vc, b, r_blim, r_steer, mw)
        rp = self.rollout_point(p_r, vel0, r_goal, r_vc, b, r_blim, r_steer, mp)
        still = 0.5 * (y[:, 0] + y[:, 1])
        pred = []
        for k in range(N):
            pk = _sel(ped, rp[k], rw[k])
            pk = _sel(stopped, still, pk)
            pred.append(pk + now)
        pred_m = ca.horzcat(*pred)

        mem_new = ca.vertcat(
            p0 + now,
            th,
            v,
            acc,
            w,
            1.0,
            v_avg_new,
            n_new,
            stopped,
            lb.T,
            lb_none,
            excl_new.T,
        )
        info = ca.vertcat(best, p_best, stopped, at_spot, v, th, acc, w)
        return ca.Function(
            _FUNCTION_NAME,
            [y_abs, spots_abs, mask, kind, mem, force, me, others, others_vel, others_mask],
            [pred_m, mem_new, info],
            [
                "history",
                "spots",
                "spot_mask",
                "kind",
                "memory",
                "force_spot",
                "self_index",
                "others",
                "others_velocity",
                "others_mask",
            ],
            ["prediction", "memory_next", "info"],
            {"cse": True},
        )


def default_cache_dir() -> Path:
    """``$DECK_SIM_CACHE`` or ``$XDG_CACHE_HOME/deck_sim`` or ``~/.cache/deck_sim``, plus ``casadi``."""
    root = os.environ.get("DECK_SIM_CACHE")
    if root:
        return Path(root) / "casadi"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "deck_sim" / "casadi"


def compile_function(
    fn: ca.Function, compiler: str, flags: tuple[str, ...], cache_dir: Path
) -> tuple[ca.Function, Path, bool]:
    """Generate C for ``fn``, compile it into ``cache_dir`` (once per hash), load it with ``casadi.external``.

    The cache key hashes the C source, compiler, flags, CasADi version and machine. The library is compiled
    into a temporary file and renamed into place, so concurrent processes never load a half-written file.

    Returns:
        (loaded Function, path of the shared library, whether it was compiled now rather than found cached).

    Raises:
        RuntimeError: if the compiler is missing or fails (its output is in the message).
    """
    cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
    cg.add(fn)
    source = cg.dump()
    key = hashlib.sha256(
        "\n".join(
            [source, compiler, " ".join(flags), ca.__version__, platform.machine(), platform.system()]
        ).encode()
    ).hexdigest()[:20]
    lib = cache_dir / f"{fn.name()}_{key}.so"
    if lib.exists():
        return ca.external(fn.name(), str(lib)), lib, False
    exe = shutil.which(compiler)
    if exe is None:
        raise RuntimeError(f"C compiler {compiler!r} not found on PATH")
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache_dir) as tmp:
        src = Path(tmp) / f"{fn.name()}.c"
        src.write_text(source)
        out = Path(tmp) / "lib.so"
        proc = subprocess.run([exe, *flags, str(src), "-o", str(out), "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{compiler} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
        os.replace(out, lib)
    return ca.external(fn.name(), str(lib)), lib, True


@dataclass
class _Batch:
    """The Function mapped over n movers, its zero-copy buffer and the arrays the buffer points to."""

    function: ca.Function
    buffer: object
    run: object
    history: np.ndarray
    spots: np.ndarray
    mask: np.ndarray
    kind: np.ndarray
    memory: np.ndarray
    force: np.ndarray
    me: np.ndarray
    others: np.ndarray
    others_velocity: np.ndarray
    others_mask: np.ndarray
    prediction: np.ndarray
    memory_next: np.ndarray
    info: np.ndarray


_FUNCTIONS: dict[MPCPredictorSettings, tuple[ca.Function, str, Path | None]] = {}
"""Functions already built in this process, by settings (a Function is stateless and may be shared)."""


def _function_for(settings: MPCPredictorSettings) -> tuple[ca.Function, str, Path | None]:
    """(Function, backend "c" or "casadi-vm", shared library or None) of the predictor for ``settings``.

    Built once per process and settings; compiled once per machine (see ``compile_function``).
    """
    hit = _FUNCTIONS.get(settings)
    if hit is not None:
        return hit
    fn = _Builder(settings).build()
    backend, library = "casadi-vm", None
    if settings.compile != "none":
        cache = Path(settings.cache_dir) if settings.cache_dir else default_cache_dir()
        try:
            t0 = time.perf_counter()
            fn, library, fresh = compile_function(fn, settings.compiler, settings.compiler_flags, cache)
            backend = "c"
            if fresh:
                log.info("MPC predictor compiled into %s in %.1f s", library, time.perf_counter() - t0)
            else:
                log.debug("MPC predictor loaded from %s", library)
        except (RuntimeError, OSError) as err:
            if settings.compile == "c":
                raise
            log.warning("MPC predictor: compilation unavailable (%s); using CasADi's virtual machine", err)
    _FUNCTIONS[settings] = (fn, backend, library)
    return fn, backend, library


class MPCPredictor:
    """Predicts every mover's next ``horizon`` positions by estimation, intent inference and a model rollout.

    Call ``reset(spots, kinds)`` at the start of every episode (the spots are the map's special spots) and
    ``predict(tracks)`` once per control step, with consecutive tracks. See the module docstring.

    Attributes:
        name: "mpc".
        horizon: Predicted steps N.
        needs_future: False.
        fallback_count: Movers that fell back to constant velocity since construction (all calls together).
        last_solve_time_s: Wall time of the last compiled-Function evaluation, s.
        last_info: (n, 8) from the last call: chosen spot (-1 none), its belief, stopped, at a spot,
            speed m/s, heading rad, acceleration m/s^2, turn rate rad/s.
        backend: "c" (compiled, loaded from ``library``) or "casadi-vm".
        compile_time_s: Seconds spent building and compiling (or loading) the Function.
    """

    name = "mpc"
    needs_future = False

    def __init__(self, settings: MPCPredictorSettings | None = None) -> None:
        self.settings = settings or MPCPredictorSettings()
        self.horizon = self.settings.horizon
        self.fallback_count = 0
        self.last_solve_time_s = 0.0
        self.last_info = np.zeros((0, _N_INFO))
        self.library: Path | None = None
        t0 = time.perf_counter()
        fn, self.backend, self.library = _function_for(self.settings)
        self.compile_time_s = time.perf_counter() - t0
        self._fn = fn
        self._batches: dict[int, _Batch] = {}
        self._spots = np.zeros((self.settings.max_spots, 2))
        self._mask = np.zeros(self.settings.max_spots)
        self._mem: np.ndarray | None = None
        k = min(4, self.settings.history)
        t = (np.arange(k) - 0.5 * (k - 1)) * self.settings.dt
        self._velocity_weights = t / np.dot(t, t)

    # ----- episode -----
    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Start an episode: remember the map's special spots ``(k, 2)`` m and forget every mover's history.

        Raises:
            PredictionInputError: spots of the wrong shape, non-finite, or more than ``settings.max_spots``.
        """
        sp = (
            np.asarray(spots, dtype=np.float64).reshape(-1, 2)
            if np.size(spots) == 0
            else np.asarray(spots, float)
        )
        if sp.ndim != 2 or sp.shape[1] != 2:
            raise PredictionInputError(f"spots must have shape (k, 2), got {np.shape(spots)}")
        if not np.all(np.isfinite(sp)):
            raise PredictionInputError("spots hold NaN or infinite values")
        k = sp.shape[0]
        if k > self.settings.max_spots:
            raise PredictionInputError(
                f"{k} spots exceed the compiled capacity max_spots={self.settings.max_spots}; "
                "raise it in the settings"
            )
        self._spots[...] = 0.0
        self._spots[:k] = sp
        self._mask[...] = 0.0
        self._mask[:k] = 1.0
        self._mem = self._initial_memory(len(np.atleast_1d(kinds)))

    def _initial_memory(self, n: int) -> np.ndarray:
        """(n, memory_size) memory of movers never seen: no estimate, uniform belief, nothing excluded."""
        return np.zeros((n, self.settings.memory_size))

    def _batch(self, n: int) -> _Batch:
        """The Function mapped over ``n`` movers (spots and mask shared) with persistent argument arrays."""
        batch = self._batches.get(n)
        if batch is None:
            s = self.settings
            fm = self._fn.map(f"{_FUNCTION_NAME}_map{n}", "serial", n, [1, 2, 7, 8, 9], [])
            buf, run = fm.buffer()
            batch = _Batch(
                function=fm,
                buffer=buf,
                run=run,
                history=np.zeros((n, s.history, 2)),
                spots=self._spots,
                mask=self._mask,
                kind=np.zeros(n),
                memory=np.zeros((n, s.memory_size)),
                force=np.full(n, -1.0),
                me=np.arange(n, dtype=np.float64),
                others=np.zeros((s.max_movers, 2)),
                others_velocity=np.zeros((s.max_movers, 2)),
                others_mask=(np.arange(s.max_movers) < n).astype(np.float64),
                prediction=np.zeros((n, s.horizon, 2)),
                memory_next=np.zeros((n, s.memory_size)),
                info=np.zeros((n, _N_INFO)),
            )
            # The buffer keeps raw pointers: these arrays live (and are only ever written in place) with the
            # batch.
            args = (
                batch.history,
                batch.spots,
                batch.mask,
                batch.kind,
                batch.memory,
                batch.force,
                batch.me,
                batch.others,
                batch.others_velocity,
                batch.others_mask,
            )
            for i, a in enumerate(args):
                buf.set_arg(i, memoryview(a))
            for i, r in enumerate((batch.prediction, batch.memory_next, batch.info)):
                buf.set_res(i, memoryview(r))
            self._batches[n] = batch
        return batch

    def _evaluate(
        self, hist: np.ndarray, kinds: np.ndarray, mem: np.ndarray, force: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Evaluate the compiled Function for all movers: (n, N, 2) prediction, (n, M) memory, (n, 8) info."""
        batch = self._batch(hist.shape[0])
        batch.history[...] = hist
        batch.kind[...] = kinds
        batch.memory[...] = mem
        batch.force[...] = force
        n = hist.shape[0]
        batch.others[:n] = hist[:, -1]
        # Others' velocities for the yield test: a line fit over the last 4 samples (as ConstantVelocity).
        np.einsum(
            "k,nkd->nd",
            self._velocity_weights,
            hist[:, -len(self._velocity_weights) :],
            out=batch.others_velocity[:n],
        )
        batch.run()
        return batch.prediction.copy(), batch.memory_next.copy(), batch.info.copy()

    def predict(self, tracks: ObstacleTracks, known_spots: np.ndarray | None = None) -> Prediction:
        """Next ``horizon`` positions (n, N, 2) m of every mover.

        Args:
            tracks: The movers' histories (at least ``settings.history`` samples, the settings' ``dt``).
            known_spots: Benchmarks only: (n,) index of each mover's true spot (-1: infer it). The task never
                passes it; it gives the ceiling of spot inference.

        Raises:
            PredictionInputError: malformed tracks (shape, length, NaN) or a ``dt`` other than the settings'.
        """
        s = self.settings
        validate_tracks(tracks, min_history=s.history)
        if abs(tracks.dt - s.dt) > 1e-9 * s.dt:
            raise PredictionInputError(
                f"tracks.dt is {tracks.dt} s but this predictor was built for dt={s.dt} s"
            )
        n = tracks.n
        if n > s.max_movers:
            raise PredictionInputError(f"{n} movers exceed the compiled capacity max_movers={s.max_movers}")
        if self._mem is None or self._mem.shape[0] != n:
            if self._mem is not None:
                log.warning(
                    "MPC predictor: mover count changed from %d to %d without reset", self._mem.shape[0], n
                )
            self._mem = self._initial_memory(n)
        hist = np.ascontiguousarray(tracks.positions[:, -s.history :, :], dtype=np.float64)
        kinds = (np.asarray(tracks.kinds) == _PEDESTRIAN).astype(np.float64)
        force = np.full(n, -1.0)
        if known_spots is not None:
            force = np.ascontiguousarray(np.asarray(known_spots, dtype=np.float64).reshape(n))
        t0 = time.perf_counter()
        pred, mem_new, info = self._evaluate(hist, kinds, self._mem, force)
        self.last_solve_time_s = time.perf_counter() - t0

        bad = ~(np.isfinite(pred).all(axis=(1, 2)) & np.isfinite(mem_new).all(axis=1))
        if bad.any():
            vel = least_squares_velocity(tracks.positions[bad], tracks.dt, 4)
            pred[bad] = constant_velocity_rollout(tracks.current[bad], vel, tracks.dt, self.horizon)
            mem_new[bad] = self._initial_memory(int(np.count_nonzero(bad)))
            self.fallback_count += int(np.count_nonzero(bad))
            log.debug("MPC predictor: constant-velocity fallback for movers %s", np.flatnonzero(bad).tolist())
        self._mem = mem_new
        self.last_info = info
        return Prediction(pred, bad)

    def settings_dict(self) -> dict:
        """The settings as a plain dict (for run records)."""
        return asdict(self.settings)
