"""Where a run's environments step: in the learner's process, or in one worker process beside it.

Both runners hold the same environments (one Gymnasium adapter per slot, and the scripted planner when its
actions label the agent's transitions; ``body`` picks ``ScriptedPlanner.body``) and answer the same calls.
``step_async`` starts a step of every environment and ``step_wait`` collects it; between the two the learner
updates its networks. ``WorkerEnvs`` steps in a separate process, so the physics and the gradient updates
overlap on two cores; ``InlineEnvs`` steps inside ``step_async``. The trainer calls them in the same order
either way, so a run gives the same numbers, bit for bit, on both.
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np

from training.envs import TEACHER_PREDICTOR, ObservationLayout, env_layout, make_env


@dataclass
class StepResult:
    """One environment's step: the next flat observation (its own layout), the reward, how it ended, the
    planner's action in the state the step started from (or None), and the outcome fields of ``info``."""

    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    expert: np.ndarray | None
    info: dict[str, Any]


_INFO_KEYS = ("reached_goal", "collision", "left_surface", "diverged")


class _Envs:
    """The environments themselves (used directly inline, or inside the worker)."""

    def __init__(self, n: int) -> None:
        self.envs: list[Any] = [None] * n
        self.experts: list[Any] = [None] * n
        self.views: list[tuple[ObservationLayout, ObservationLayout] | None] = [None] * n
        """Per slot: (the environment's layout, the agent's) where the agent sees less than the environment."""

    def build(
        self, i: int, scene: str, predictor: str, overrides: dict[str, Any], expert: bool, body: bool = False
    ) -> dict:
        from deck_sim.control.planners import ScriptedPlanner
        from deck_sim.policies import ScriptedPolicy

        if self.envs[i] is not None:
            self.envs[i].close()
        # an agent without prediction is taught by the planner on the teacher's forecasts, and sees them dropped
        env_predictor = TEACHER_PREDICTOR if expert and predictor == "none" else predictor
        self.envs[i] = make_env(scene, env_predictor, **overrides)
        self.experts[i] = ScriptedPolicy(self.envs[i].composer_env, ScriptedPlanner(body=body)) if expert else None
        full = env_layout(self.envs[i])
        own = full.without(("predicted",)) if env_predictor != predictor else full
        self.views[i] = (full, own) if own.keys != full.keys else None
        return own.shapes

    def _own(self, i: int, obs: np.ndarray) -> np.ndarray:
        view = self.views[i]
        return obs if view is None else view[0].select(obs, view[1])

    def reset(self, i: int, seed: int) -> np.ndarray:
        obs, _ = self.envs[i].reset(seed=seed)
        if self.experts[i] is not None:
            self.experts[i].reset()
        return self._own(i, obs)

    def step_one(self, i: int, action: np.ndarray) -> StepResult:
        expert = None
        if self.experts[i] is not None:  # what the planner would do here (it reads the task's full state)
            expert = np.clip(self.experts[i].act({}), -1.0, 1.0)
        obs, reward, terminated, truncated, info = self.envs[i].step(action)
        return StepResult(self._own(i, obs), float(reward), bool(terminated), bool(truncated), expert,
                          {k: info[k] for k in _INFO_KEYS})

    def step(self, actions: np.ndarray) -> list[StepResult]:
        return [self.step_one(i, a) for i, a in enumerate(actions)]

    def replay(self, i: int, seed: int, actions: np.ndarray) -> np.ndarray:
        obs = self.reset(i, seed)
        for a in actions:
            obs = self.step_one(i, a).obs
        return obs

    def close(self) -> None:
        for env in self.envs:
            if env is not None:
                env.close()


class InlineEnvs:
    """Environments stepped in the learner's own process."""

    def __init__(self, n: int) -> None:
        self._envs = _Envs(n)
        self._pending: list[StepResult] | None = None

    def build(
        self, i: int, scene: str, predictor: str, overrides: dict[str, Any], expert: bool, body: bool = False
    ) -> ObservationLayout:
        return ObservationLayout(self._envs.build(i, scene, predictor, overrides, expert, body))

    def reset(self, i: int, seed: int) -> np.ndarray:
        return self._envs.reset(i, seed)

    def replay(self, i: int, seed: int, actions: np.ndarray) -> np.ndarray:
        return self._envs.replay(i, seed, actions)

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = self._envs.step(actions)

    def step_wait(self) -> list[StepResult]:
        out, self._pending = self._pending, None
        if out is None:
            raise RuntimeError("step_wait without step_async")
        return out

    def close(self) -> None:
        self._envs.close()


def _worker(conn: Any, n: int) -> None:
    import os

    os.environ.setdefault("MUJOCO_GL", "disable")
    envs = _Envs(n)
    while True:
        cmd, args = conn.recv()
        if cmd == "close":
            envs.close()
            conn.send(("ok", None))
            return
        try:
            conn.send(("ok", getattr(envs, cmd)(*args)))
        except Exception as err:  # noqa: BLE001 - sent back to the learner with its traceback
            conn.send(("error", f"{type(err).__name__}: {err}\n{traceback.format_exc()}"))


class WorkerError(RuntimeError):
    """An environment failed inside the worker process (the message carries the worker's traceback)."""


class WorkerEnvs:
    """Environments stepped in one worker process, overlapping with the learner's updates.

    The worker is forked where the platform allows (it builds its own environments and never uses torch), so a
    script without an ``if __name__ == "__main__"`` guard still works; elsewhere it is spawned.
    """

    def __init__(self, n: int) -> None:
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_worker, args=(child, n), daemon=True, name="deck_sim-envs")
        self._proc.start()
        child.close()
        self._waiting = False

    def _call(self, cmd: str, *args: Any) -> Any:
        self._conn.send((cmd, args))
        return self._recv()

    def _recv(self) -> Any:
        try:
            status, value = self._conn.recv()
        except EOFError as err:
            raise WorkerError(f"the environment worker died (exit code {self._proc.exitcode})") from err
        if status == "error":
            raise WorkerError(f"in the environment worker: {value}")
        return value

    def build(
        self, i: int, scene: str, predictor: str, overrides: dict[str, Any], expert: bool, body: bool = False
    ) -> ObservationLayout:
        return ObservationLayout(self._call("build", i, scene, predictor, overrides, expert, body))

    def reset(self, i: int, seed: int) -> np.ndarray:
        return self._call("reset", i, seed)

    def replay(self, i: int, seed: int, actions: np.ndarray) -> np.ndarray:
        return self._call("replay", i, seed, actions)

    def step_async(self, actions: np.ndarray) -> None:
        self._conn.send(("step", (np.asarray(actions),)))
        self._waiting = True

    def step_wait(self) -> list[StepResult]:
        if not self._waiting:
            raise RuntimeError("step_wait without step_async")
        self._waiting = False
        return self._recv()

    def close(self) -> None:
        if self._proc.is_alive():
            try:
                if self._waiting:
                    self._recv()
                self._call("close")
            except (WorkerError, OSError, BrokenPipeError):
                pass
            self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.terminate()
        self._conn.close()


def make_runner(n: int, worker: bool) -> InlineEnvs | WorkerEnvs:
    """``n`` environments in a worker process (``worker``) or inline."""
    return WorkerEnvs(n) if worker else InlineEnvs(n)
