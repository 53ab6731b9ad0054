"""Where a run's environments step: in the learner's process, in worker processes beside it, or in Ray actors
(``training.ray_backend``).

Every runner holds the same environments (one Gymnasium adapter per slot, and the scripted planner when its
actions label the agent's transitions; ``body`` picks ``ScriptedPlanner.body``) in groups (``EnvGroup``) and
answers the same calls. ``step_async`` sends one ``StepOrder`` and ``step_wait`` collects its results; between the
two the learner updates its networks.

The rollout protocol, one synchronous step of every environment per collect:

1. The learner sends each group its rows of the order: explicit actions (the random phase), or the acting policy
   (the normaliser and the actor as they stand) with the exploration noise drawn by the learner (none: greedy)
   and the actions held in place of the policy's where the exploration holds one (``training.noise.HeldActions``),
   and per environment the reset seed of its next episode and, where the curriculum's stage changed, the scene
   to rebuild it with.
2. Each group acts on its environments' observations in one batched forward pass, steps them, and resets (or
   rebuilds and resets) each environment whose episode ended, while the learner updates.
3. The learner collects the transitions in slot order.

The learner draws every random number (actions, noise, replay samples) and the groups are fixed contiguous runs
of slots, so a run's numbers depend on its configuration and on how many groups act, not on where they run:
``InlineEnvs`` (one group in the learner's process), ``WorkerEnvs`` with one worker, and ``RayEnvs`` with one
actor give the same numbers, bit for bit, and ``WorkerEnvs`` and ``RayEnvs`` with the same worker count do too.
"""

from __future__ import annotations

import multiprocessing as mp
import pickle
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from training.config import TrainConfig
from training.envs import (
    FORECAST_KEYS,
    TEACHER_PREDICTOR,
    ObservationLayout,
    env_layout,
    make_env,
    mover_pad_fills,
)

Policy = Callable[[np.ndarray], np.ndarray]
"""An acting policy: greedy actions (n, 2) float64 for flat observations (n, obs_dim) (``DDPGAgent.acting``)."""


class EnvSpec(NamedTuple):
    """What one environment is built from: the scene, the agent's predictor, scene overrides, whether the planner
    labels its steps, whether that planner checks the agent's whole body (``ScriptedPlanner.body``) and what it
    reads (``deck_sim.policies.TEACHER_VIEWS``)."""

    scene: str
    predictor: str
    overrides: dict[str, Any]
    expert: bool
    body: bool = False
    view: str = "full"


@dataclass
class StepOrder:
    """One step of a run's environments as the learner asks for it (rows in slot order).

    ``actions`` (n, 2) are taken as they are; without them each group acts with ``policy`` plus ``noise`` (n, 2),
    or greedily where ``noise`` is None, except in the rows where ``hold`` (n, 2) is finite: those take the held
    action as it is (``training.noise.HeldActions``; each row of ``hold`` is all NaN or all finite). ``seeds``
    give each environment's next reset seed (None: no reset inside the step), ``builds`` the spec to rebuild it
    with before that reset (None: as it is).
    """

    actions: np.ndarray | None = None
    noise: np.ndarray | None = None
    policy: Policy | None = None
    seeds: Sequence[int | None] | None = None
    builds: Sequence[EnvSpec | None] | None = None
    hold: np.ndarray | None = None

    def rows(self, start: int, stop: int) -> StepOrder:
        """The order of slots ``start`` to ``stop`` (the policy left out: runners send it on its own)."""

        def cut(v: Any) -> Any:
            return None if v is None else v[start:stop]

        return StepOrder(cut(self.actions), cut(self.noise), None, cut(self.seeds), cut(self.builds), cut(self.hold))


@dataclass
class StepResult:
    """One environment's step: the next flat observation (the agent's layout), the reward, how it ended, the
    planner's action in the state the step started from (or None), the outcome fields of ``info``, the action
    taken, and, when the order reset the environment, its next episode's first observation and (if it was
    rebuilt) its own layout's shapes."""

    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    expert: np.ndarray | None
    info: dict[str, Any]
    action: np.ndarray | None = None
    reset_obs: np.ndarray | None = None
    shapes: dict[str, tuple[int, ...]] | None = field(default=None, repr=False)


_INFO_KEYS = ("reached_goal", "collision", "left_surface", "diverged")


@dataclass(frozen=True)
class AgentView:
    """The agent's observation layout (the full scene's) that every environment's observation is padded to, and
    the run's config, whose scene gives the left-out movers' fills (``mover_pad_fills``)."""

    layout: ObservationLayout
    config: TrainConfig


class EnvGroup:
    """A group of environments stepped together, its acting policy and its environments' current observations:
    used directly inline, inside a worker process, or as a Ray actor.

    Args:
        n: environments in the group (indexed 0..n-1 here).
        view: pad every observation to this layout (None: each environment's own observation).
    """

    def __init__(self, n: int, view: AgentView | None = None) -> None:
        self.envs: list[Any] = [None] * n
        self.experts: list[Any] = [None] * n
        self.obs: list[np.ndarray | None] = [None] * n
        self.views: list[tuple[ObservationLayout, ObservationLayout] | None] = [None] * n
        """Per slot: (the environment's layout, the agent's) where the agent sees less than the environment."""
        self.padded: list[ObservationLayout | None] = [None] * n
        """Per slot: the slot's own layout where it is padded to the agent's (a curriculum stage's scene)."""
        self.view = view
        self.policy: Policy | None = None
        self._fills: dict[str, float] | None = None

    def build(self, i: int, *spec: Any) -> dict[str, tuple[int, ...]]:
        """(Re)build environment ``i`` from ``EnvSpec(*spec)``; the shapes of the agent's own observation."""
        from deck_sim.control.planners import ScriptedPlanner
        from deck_sim.policies import ScriptedPolicy

        scene, predictor, overrides, expert, body, view = EnvSpec(*spec)

        if self.envs[i] is not None:
            self.envs[i].close()
        # an agent without prediction is taught by the planner on the teacher's forecasts, and sees them dropped
        env_predictor = TEACHER_PREDICTOR if expert and predictor == "none" else predictor
        self.envs[i] = make_env(scene, env_predictor, **overrides)
        self.experts[i] = (
            ScriptedPolicy(self.envs[i].composer_env, ScriptedPlanner(body=body), view=view) if expert else None
        )
        full = env_layout(self.envs[i])
        own = full.without(FORECAST_KEYS) if env_predictor != predictor else full
        self.views[i] = (full, own) if own.keys != full.keys else None
        agent = None if self.view is None else self.view.layout
        self.padded[i] = None if agent is None or (own.keys, own.shapes) == (agent.keys, agent.shapes) else own
        return own.shapes

    def _agent_obs(self, i: int, obs: np.ndarray) -> np.ndarray:
        """Environment ``i``'s flat observation as the agent sees it: its own part, padded to the agent's layout."""
        view, own = self.views[i], self.padded[i]
        obs = obs if view is None else view[0].select(obs, view[1])
        if own is None:
            return obs
        if self._fills is None:
            self._fills = mover_pad_fills(self.view.config)
        return own.pad_to(obs, self.view.layout, self._fills).astype(np.float32)

    def reset(self, i: int, seed: int) -> np.ndarray:
        obs, _ = self.envs[i].reset(seed=seed)
        if self.experts[i] is not None:
            self.experts[i].reset()
        self.obs[i] = self._agent_obs(i, obs)
        return self.obs[i]

    def step_one(self, i: int, action: np.ndarray) -> StepResult:
        expert = None
        if self.experts[i] is not None:  # what the planner would do here (from what its view lets it read)
            expert = np.clip(self.experts[i].act({}), -1.0, 1.0)
        obs, reward, terminated, truncated, info = self.envs[i].step(action)
        self.obs[i] = self._agent_obs(i, obs)
        return StepResult(self.obs[i], float(reward), bool(terminated), bool(truncated), expert,
                          {k: info[k] for k in _INFO_KEYS}, action)

    def step(self, order: StepOrder | np.ndarray, policy: Policy | None = None) -> list[StepResult]:
        """One step of every environment of the group (``StepOrder``, or plain actions (n, 2)); ``policy``, where
        given, replaces the group's acting policy first."""
        if not isinstance(order, StepOrder):
            order = StepOrder(actions=np.asarray(order))
        if policy is not None:
            self.policy = policy
        actions = order.actions
        if actions is None:
            if self.policy is None:
                raise RuntimeError("an order to act without a policy")
            actions = self.policy(np.stack(self.obs))
            actions = np.clip(actions if order.noise is None else actions + order.noise, -1.0, 1.0)
            if order.hold is not None:
                held = np.isfinite(order.hold[:, 0])
                actions[held] = order.hold[held]
        results = [self.step_one(i, a) for i, a in enumerate(actions)]
        for i, res in enumerate(results):
            seed = None if order.seeds is None else order.seeds[i]
            if (res.terminated or res.truncated) and seed is not None:
                spec = None if order.builds is None else order.builds[i]
                if spec is not None:
                    res.shapes = self.build(i, *spec)
                res.reset_obs = self.reset(i, seed)
        return results

    def replay(self, i: int, seed: int, actions: np.ndarray) -> np.ndarray:
        obs = self.reset(i, seed)
        for a in actions:
            obs = self.step_one(i, a).obs
        return obs

    def close(self) -> None:
        for env in self.envs:
            if env is not None:
                env.close()


def groups(n: int, workers: int) -> list[range]:
    """The slots of each of ``workers`` groups of ``n`` environments: contiguous runs, sizes differing by at most
    one (the first ones the larger)."""
    if not 1 <= workers <= n:
        raise ValueError(f"workers: expected 1 to {n} (one environment at least per worker), got {workers}")
    size, extra = divmod(n, workers)
    bounds = np.cumsum([0] + [size + (w < extra) for w in range(workers)])
    return [range(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


class Runner:
    """The calls every runner answers, by slot index; subclasses route them to their groups."""

    def __init__(self, n: int, workers: int) -> None:
        self.slots = groups(n, workers)
        self._where = [(g, i - r.start) for g, r in enumerate(self.slots) for i in r]
        self._waiting = False

    def _call(self, group: int, cmd: str, *args: Any) -> Any:
        raise NotImplementedError

    def build(self, i: int, *spec: Any) -> ObservationLayout:
        """(Re)build environment ``i`` from ``EnvSpec(*spec)``; the layout of the agent's own observation."""
        g, k = self._where[i]
        return ObservationLayout(self._call(g, "build", k, *EnvSpec(*spec)))

    def reset(self, i: int, seed: int) -> np.ndarray:
        g, k = self._where[i]
        return self._call(g, "reset", k, seed)

    def replay(self, i: int, seed: int, actions: np.ndarray) -> np.ndarray:
        g, k = self._where[i]
        return self._call(g, "replay", k, seed, actions)

    def step_async(self, order: StepOrder | np.ndarray) -> None:
        """Start one step of every environment (a ``StepOrder``, or plain actions (n, 2))."""
        if self._waiting:
            raise RuntimeError("step_async before the previous step_wait")
        if not isinstance(order, StepOrder):
            order = StepOrder(actions=np.asarray(order))
        self._send(order)
        self._waiting = True

    def step_wait(self) -> list[StepResult]:
        """The results of the step started by ``step_async``, in slot order."""
        if not self._waiting:
            raise RuntimeError("step_wait without step_async")
        self._waiting = False
        return [res for part in self._receive() for res in part]

    def _send(self, order: StepOrder) -> None:
        raise NotImplementedError

    def _receive(self) -> list[list[StepResult]]:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class InlineEnvs(Runner):
    """Environments stepped in the learner's own process (one group; it acts with the learner's live networks)."""

    def __init__(self, n: int, view: AgentView | None = None) -> None:
        super().__init__(n, 1)
        self._envs = EnvGroup(n, view)
        self._pending: list[StepResult] | None = None

    def _call(self, group: int, cmd: str, *args: Any) -> Any:
        return getattr(self._envs, cmd)(*args)

    def _send(self, order: StepOrder) -> None:
        self._pending = self._envs.step(replace(order, policy=None), order.policy)

    def _receive(self) -> list[list[StepResult]]:
        out, self._pending = self._pending, None
        return [out]

    def close(self) -> None:
        self._envs.close()


def _worker(conn: Any, n: int, view: AgentView | None) -> None:
    import os
    import signal

    # Ctrl-C in a terminal reaches the whole process group: the learner stops the run at a checkpoint and then
    # closes this worker, which must live until then (and ends on its own if the learner is gone)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    learner = os.getppid()
    os.environ.setdefault("MUJOCO_GL", "disable")
    import torch

    torch.set_num_threads(1)  # the learner's networks act here on one thread, as they do in every worker
    envs = EnvGroup(n, view)
    while True:
        if not conn.poll(5.0):  # (a command arrives at once while the learner lives)
            if os.getppid() != learner:
                envs.close()
                return
            continue
        cmd, args = conn.recv()
        if cmd == "close":
            envs.close()
            conn.send(("ok", None))
            return
        try:
            if cmd == "step":
                order, policy = args
                args = (order, None if policy is None else pickle.loads(policy))
            conn.send(("ok", getattr(envs, cmd)(*args)))
        except Exception as err:  # noqa: BLE001 - sent back to the learner with its traceback
            conn.send(("error", f"{type(err).__name__}: {err}\n{traceback.format_exc()}"))


class WorkerError(RuntimeError):
    """An environment failed inside a worker (the message carries the worker's traceback)."""


class WorkerEnvs(Runner):
    """Environments stepped in ``workers`` worker processes, each holding a contiguous group of them and a copy of
    the acting policy, overlapping with the learner's updates.

    The workers are forked where the platform allows (they build their own environments), so a script without an
    ``if __name__ == "__main__"`` guard still works; elsewhere they are spawned.
    """

    def __init__(self, n: int, workers: int = 1, view: AgentView | None = None) -> None:
        super().__init__(n, workers)
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self._conns, self._procs = [], []
        for w, slots in enumerate(self.slots):
            conn, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, len(slots), view), daemon=True, name=f"deck_sim-envs{w}")
            proc.start()
            child.close()
            self._conns.append(conn)
            self._procs.append(proc)

    def _call(self, group: int, cmd: str, *args: Any) -> Any:
        self._conns[group].send((cmd, args))
        return self._recv(group)

    def _recv(self, group: int) -> Any:
        try:
            status, value = self._conns[group].recv()
        except EOFError as err:
            raise WorkerError(f"environment worker {group} died (exit code {self._procs[group].exitcode})") from err
        if status == "error":
            raise WorkerError(f"in environment worker {group}: {value}")
        return value

    def _send(self, order: StepOrder) -> None:
        policy = None if order.policy is None else pickle.dumps(order.policy, protocol=pickle.HIGHEST_PROTOCOL)
        for conn, slots in zip(self._conns, self.slots, strict=True):
            conn.send(("step", (order.rows(slots.start, slots.stop), policy)))

    def _receive(self) -> list[list[StepResult]]:
        return [self._recv(g) for g in range(len(self._conns))]

    def close(self) -> None:
        for g, (conn, proc) in enumerate(zip(self._conns, self._procs, strict=True)):
            if proc.is_alive():
                try:
                    if self._waiting:
                        self._recv(g)
                    self._call(g, "close")
                except (WorkerError, OSError, BrokenPipeError):
                    pass
                proc.join(timeout=10)
            if proc.is_alive():
                proc.terminate()
            conn.close()
        self._waiting = False


BACKENDS = ("local", "ray")
"""Where the environments step: ``local`` (inline or worker processes) or ``ray`` (Ray actors)."""


def make_runner(
    n: int,
    workers: int,
    view: AgentView | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> Runner:
    """``n`` environments: inline (``local``, ``workers`` 0), in ``workers`` worker processes (``local``) or in
    ``workers`` Ray actors (``ray``, on the cluster at ``ray_address`` or a local one)."""
    if backend == "ray":
        from training.ray_backend import RayEnvs

        return RayEnvs(n, workers, view, ray_address)
    if backend != "local":
        raise ValueError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    return WorkerEnvs(n, workers, view) if workers else InlineEnvs(n, view)
