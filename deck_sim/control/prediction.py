"""Prediction of the dynamic obstacles' next N positions (paper Section II.B.1).

A ``Predictor`` takes the recent history of every dynamic obstacle (``ObstacleTracks``) and returns its next N
positions (``Prediction``). The task calls ``reset`` at the start of every episode and ``predict`` once per
control step. This module imports only numpy, CasADi and ``deck_sim.types``, so it is tested without MuJoCo.

Implementations:
    ``none``               no prediction (N = 0): the agent sees only the obstacles' current positions.
    ``constant_velocity``  velocity from a least-squares line over the last few samples, extrapolated.
    ``stationary``         every obstacle held at its current position (a forecast without motion, for ablations).
    ``oracle``             the obstacles' true future, computed by the task by simulating ahead.
    ``mpc``                the CasADi MPC predictor (``MPCPredictor``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from deck_sim.types import ObstacleTracks, Prediction


class PredictionInputError(ValueError):
    """The history handed to a predictor is malformed (wrong shape, too short, NaN or infinite)."""


@runtime_checkable
class Predictor(Protocol):
    """What the task needs of a predictor."""

    name: str
    horizon: int
    """Number of predicted steps N, each one decision period ``dt`` apart."""
    needs_future: bool
    """True if the task must fill ``ObstacleTracks.future`` (only the oracle)."""

    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Start a new episode. ``spots`` (k, 2): the special spots of the map (public knowledge), metres."""

    def predict(self, tracks: ObstacleTracks) -> Prediction:
        """Next ``horizon`` positions of every obstacle, (n, horizon, 2) metres."""


def validate_tracks(tracks: ObstacleTracks, min_history: int) -> None:
    """Raise ``PredictionInputError`` naming the problem if ``tracks`` cannot be predicted from."""
    pos = np.asarray(tracks.positions)
    if pos.ndim != 3 or pos.shape[2] != 2:
        raise PredictionInputError(f"positions must have shape (n, H, 2), got {pos.shape}")
    if pos.shape[1] < min_history:
        raise PredictionInputError(
            f"history too short: {pos.shape[1]} samples, this predictor needs at least {min_history}"
        )
    # one reduction on the common path; the element-wise test only when the sum is not finite
    if not np.isfinite(pos.sum()) and not np.all(np.isfinite(pos)):
        bad = sorted({int(i) for i in np.argwhere(~np.isfinite(pos))[:, 0]})
        raise PredictionInputError(f"positions hold NaN or infinite values for obstacle(s) {bad}")
    try:
        dt_ok = math.isfinite(tracks.dt) and tracks.dt > 0
    except TypeError:  # not a number at all (None, a string)
        dt_ok = False
    if not dt_ok:
        raise PredictionInputError(f"dt must be a positive number of seconds, got {tracks.dt!r}")
    if np.shape(tracks.kinds) != (pos.shape[0],):
        raise PredictionInputError(f"kinds must have shape ({pos.shape[0]},), got {np.shape(tracks.kinds)}")


@functools.lru_cache(maxsize=32)
def _slope_weights(k: int, dt: float) -> np.ndarray:
    """Weights w (k,) with sum_i w_i p_i = least-squares slope of k samples dt apart (sum w = 0)."""
    t = (np.arange(k) - (k - 1) / 2.0) * dt
    return t / float(np.dot(t, t))


def least_squares_velocity(positions: np.ndarray, dt: float, window: int) -> np.ndarray:
    """Velocity (n, 2) in m/s of a least-squares line through the last ``window`` samples of each track."""
    k = min(window, positions.shape[1])
    if k < 2:
        return np.zeros((positions.shape[0], 2))
    return np.einsum("k,nkd->nd", _slope_weights(k, float(dt)), positions[:, -k:, :])


@functools.lru_cache(maxsize=32)
def _step_times(horizon: int, dt: float) -> np.ndarray:
    """(1, horizon, 1) times dt, 2 dt, ... horizon dt (read-only, shared)."""
    steps = (np.arange(1, horizon + 1, dtype=np.float64) * dt)[None, :, None]
    steps.setflags(write=False)
    return steps


def constant_velocity_rollout(current: np.ndarray, velocity: np.ndarray, dt: float, horizon: int) -> np.ndarray:
    """Positions (n, horizon, 2) of obstacles moving from ``current`` at constant ``velocity``."""
    return current[:, None, :] + _step_times(int(horizon), float(dt)) * velocity[:, None, :]


@dataclass
class NoPrediction:
    """The ``none`` predictor: N = 0, so the observation holds only current positions (paper's plain DDPG)."""

    name: str = "none"
    horizon: int = 0
    needs_future: bool = False

    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Nothing to reset."""

    def predict(self, tracks: ObstacleTracks) -> Prediction:
        """An empty (n, 0, 2) prediction."""
        validate_tracks(tracks, min_history=1)
        return Prediction(np.zeros((tracks.n, 0, 2)), np.zeros(tracks.n, dtype=bool))


@dataclass
class ConstantVelocity:
    """Extrapolate each obstacle at the velocity of a least-squares line through its last ``window`` samples.

    A constant speed-and-turn-rate fit does worse on movers that brake, dwell and depart
    (``benchmarks/prediction_synthetic.py`` prints both).
    """

    horizon: int = 10
    window: int = 4
    name: str = "constant_velocity"
    needs_future: bool = False

    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Stateless: nothing to reset."""

    def predict(self, tracks: ObstacleTracks) -> Prediction:
        """Constant-velocity positions (n, horizon, 2)."""
        validate_tracks(tracks, min_history=1)
        vel = least_squares_velocity(tracks.positions, tracks.dt, self.window)
        pos = constant_velocity_rollout(tracks.current, vel, tracks.dt, self.horizon)
        return Prediction(pos, np.zeros(tracks.n, dtype=bool))


@dataclass
class Stationary:
    """Every obstacle held where it is now over the whole horizon: a forecast with the motion taken out. A reference
    for how much of a forecast's motion an actor reads (``benchmarks/forecast_use.py``), not a method."""

    horizon: int = 10
    name: str = "stationary"
    needs_future: bool = False

    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Stateless: nothing to reset."""

    def predict(self, tracks: ObstacleTracks) -> Prediction:
        """The current positions repeated (n, horizon, 2)."""
        validate_tracks(tracks, min_history=1)
        pos = np.repeat(np.asarray(tracks.current, dtype=np.float64)[:, None, :], self.horizon, axis=1)
        return Prediction(pos, np.zeros(tracks.n, dtype=bool))


@dataclass
class Oracle:
    """The obstacles' true future, simulated ahead by the task (``needs_future``); an upper bound, not a method."""

    horizon: int = 10
    name: str = "oracle"
    needs_future: bool = True

    def reset(self, spots: np.ndarray, kinds: np.ndarray) -> None:
        """Stateless: nothing to reset."""

    def predict(self, tracks: ObstacleTracks) -> Prediction:
        """Return ``tracks.future``; raise if the task did not provide it."""
        validate_tracks(tracks, min_history=1)
        if tracks.future is None:
            raise PredictionInputError("the oracle predictor needs tracks.future, which the task did not fill")
        fut = np.asarray(tracks.future, dtype=np.float64)
        if fut.shape != (tracks.n, self.horizon, 2):
            raise PredictionInputError(f"tracks.future must have shape {(tracks.n, self.horizon, 2)}, got {fut.shape}")
        return Prediction(fut.copy(), np.zeros(tracks.n, dtype=bool))


PREDICTOR_NAMES = ("none", "constant_velocity", "stationary", "oracle", "mpc")


def make_predictor(name: str, horizon: int, dt: float) -> Predictor:
    """Build the predictor called ``name`` with ``horizon`` steps of ``dt`` seconds.

    Raises:
        ValueError: for an unknown name, listing the known ones.
    """
    if name == "none":
        return NoPrediction()
    if name == "constant_velocity":
        return ConstantVelocity(horizon=horizon)
    if name == "stationary":
        return Stationary(horizon=horizon)
    if name == "oracle":
        return Oracle(horizon=horizon)
    if name == "mpc":
        from deck_sim.control.mpc_predictor import MPCPredictor, MPCPredictorSettings  # CasADi: import on use

        return MPCPredictor(MPCPredictorSettings(horizon=horizon, dt=dt))
    raise ValueError(f"unknown predictor {name!r}; expected one of {', '.join(PREDICTOR_NAMES)}")
