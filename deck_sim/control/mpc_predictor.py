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
an IPOPT solve of a mover's optimal approach to its spot (``OptimalControl`` in
``benchmarks/prediction_synthetic.py``, which prints both methods' errors and the solve time per mover)
predicts them slightly worse (it brakes later and harder than the movers do) at a far higher cost.

Modules: ``mpc_settings`` (the settings), ``mpc_graph`` (the Function, in stages, with ``mpc_estimation``
and ``mpc_rollout``), ``mpc_codegen`` (C generation and its cache); this module holds the runtime
``MPCPredictor`` and re-exports the others' public names.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from deck_sim.control.mpc_codegen import compile_function, default_cache_dir, function_for
from deck_sim.control.mpc_graph import FUNCTION_NAME
from deck_sim.control.mpc_settings import N_INFO, MoverModel, MPCPredictorSettings
from deck_sim.control.prediction import (
    PredictionInputError,
    constant_velocity_rollout,
    least_squares_velocity,
    validate_tracks,
)
from deck_sim.types import ObstacleKind, ObstacleTracks, Prediction

__all__ = ["MPCPredictor", "MPCPredictorSettings", "MoverModel", "compile_function", "default_cache_dir"]

log = logging.getLogger(__name__)

_PEDESTRIAN = int(ObstacleKind.PEDESTRIAN)


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
        self.last_info = np.zeros((0, N_INFO))
        self.library: Path | None = None
        t0 = time.perf_counter()
        fn, self.backend, self.library = function_for(self.settings)
        self.compile_time_s = time.perf_counter() - t0
        self._fn = fn
        self._batches: dict[int, _Batch] = {}
        self._spots = np.zeros((self.settings.max_spots, 2))
        self._mask = np.zeros(self.settings.max_spots)
        self._mem: np.ndarray | None = None
        self._kinds = np.zeros(0, dtype=int)
        self._pedestrian = self._no_force = np.zeros(0)
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
        # what ``predict_positions`` hands the Function: the kinds of this episode's movers, no forced spots
        self._kinds = np.atleast_1d(np.asarray(kinds)).copy()
        self._pedestrian = (self._kinds == _PEDESTRIAN).astype(np.float64)
        self._no_force = np.full(len(self._kinds), -1.0)

    def forget(self, rows: list[int]) -> None:
        """Forget what was estimated of the movers ``rows`` (indices into the last ``reset``'s kinds): for a
        vehicle that left and stands elsewhere now, whose history the caller has replaced."""
        if self._mem is not None and len(rows):
            self._mem[np.asarray(rows, dtype=int)] = self._initial_memory(len(rows))

    def _initial_memory(self, n: int) -> np.ndarray:
        """(n, memory_size) memory of movers never seen: no estimate, uniform belief, nothing excluded."""
        return np.zeros((n, self.settings.memory_size))

    def _batch(self, n: int) -> _Batch:
        """The Function mapped over ``n`` movers (spots and mask shared) with persistent argument arrays."""
        batch = self._batches.get(n)
        if batch is None:
            s = self.settings
            fm = self._fn.map(f"{FUNCTION_NAME}_map{n}", "serial", n, [1, 2, 7, 8, 9], [])
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
                info=np.zeros((n, N_INFO)),
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
        hist = batch.history  # (the contiguous copy: einsum reads it the same way whatever the caller's strides)
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
        return self._solve(tracks.positions, tracks.dt, hist, kinds, force)

    def predict_positions(self, positions: np.ndarray, dt: float) -> Prediction:
        """``predict`` for the movers given to the last ``reset``, from their positions (n, H, 2) m, oldest first,
        ``dt`` seconds apart: the task's per-step call. The kinds are those of ``reset``; the input checks run
        only when something is out of the ordinary (then ``predict`` names the problem). The same numbers as
        ``predict``."""
        s, mem = self.settings, self._mem
        n = positions.shape[0]
        if (
            mem is None
            or mem.shape[0] != n
            or positions.dtype != np.float64
            or positions.ndim != 3
            or positions.shape[1] < s.history
            or positions.shape[2] != 2
            or abs(dt - s.dt) > 1e-9 * s.dt
            or not math.isfinite(positions.sum())
        ):
            return self.predict(ObstacleTracks(dt=dt, positions=positions, kinds=self._kinds))
        return self._solve(positions, dt, positions[:, -s.history :, :], self._pedestrian, self._no_force)

    def _solve(
        self, positions: np.ndarray, dt: float, hist: np.ndarray, kinds: np.ndarray, force: np.ndarray
    ) -> Prediction:
        """Evaluate the Function for checked inputs, fall back to constant velocity where it is not finite, and
        keep the memory for the next step. ``positions`` (n, H, 2) the whole history, ``hist`` its last
        ``settings.history`` samples, ``kinds`` (n,) 1.0 for pedestrians, ``force`` (n,) forced spots or -1."""
        t0 = time.perf_counter()
        pred, mem_new, info = self._evaluate(hist, kinds, self._mem, force)
        self.last_solve_time_s = time.perf_counter() - t0

        # one reduction on the common path (a sum of finite values that overflows only sends it the long way)
        if math.isfinite(pred.sum() + mem_new.sum()):
            self._mem = mem_new
            self.last_info = info
            return Prediction(pred, np.zeros(len(pred), dtype=bool))
        bad = ~(np.isfinite(pred).all(axis=(1, 2)) & np.isfinite(mem_new).all(axis=1))
        if bad.any():
            vel = least_squares_velocity(positions[bad], dt, 4)
            pred[bad] = constant_velocity_rollout(positions[bad][:, -1, :], vel, dt, self.horizon)
            mem_new[bad] = self._initial_memory(int(np.count_nonzero(bad)))
            self.fallback_count += int(np.count_nonzero(bad))
            log.debug("MPC predictor: constant-velocity fallback for movers %s", np.flatnonzero(bad).tolist())
        self._mem = mem_new
        self.last_info = info
        return Prediction(pred, bad)

    def settings_dict(self) -> dict:
        """The settings as a plain dict (for run records)."""
        return asdict(self.settings)
