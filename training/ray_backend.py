"""Rollouts in Ray actors: ``RayEnvs``, the ``ray`` backend of ``training.runners``.

Each actor holds a contiguous group of the run's environments (``EnvGroup``) and a copy of the acting policy,
which the learner (in the driver) puts in Ray's object store once per step that acts with it; every actor of the
step reads that one copy. The protocol is the worker processes' (``training.runners``), so a run gives the same
numbers, bit for bit, with ``--backend ray --workers N`` as with ``--backend local --workers N``. The actors act
on one torch thread, as the local workers do.

On a cluster of several machines, every node needs deck_sim and its training extra installed at the same
versions as the driver (and the same CPU kind for bit-identical numbers: ``docs/training.md``).
"""

from __future__ import annotations

import os
from typing import Any

from training.runners import AgentView, EnvGroup, Runner, StepOrder, StepResult

RAY_INSTALL = "pip install 'deck-sim[ray]'"


def require_ray() -> Any:
    """The ``ray`` module, or ``ValueError`` with the install command."""
    try:
        import ray
    except ImportError as err:
        raise ValueError(f"--backend ray needs Ray: {RAY_INSTALL}") from err
    return ray


class _ActorGroup(EnvGroup):
    """An ``EnvGroup`` in a Ray actor process: one torch thread, no rendering."""

    def __init__(self, n: int, view: AgentView | None = None) -> None:
        os.environ.setdefault("MUJOCO_GL", "disable")
        import torch

        torch.set_num_threads(1)
        super().__init__(n, view)

    def ping(self) -> bool:
        return True


class RayEnvs(Runner):
    """``n`` environments in ``workers`` Ray actors (one CPU each) on the cluster at ``address``, or on a local
    Ray started with ``workers`` CPUs (and stopped by ``close``) when none is running in this process."""

    def __init__(self, n: int, workers: int = 1, view: AgentView | None = None, address: str | None = None) -> None:
        super().__init__(n, workers)
        ray = require_ray()
        self._ray = ray
        from deck_sim.evaluation.harness import init_ray

        self._started = init_ray(workers, address)
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < workers:
            self.close()
            raise ValueError(f"--workers {workers}: the Ray cluster has {cpus:g} CPUs, one needed per worker")
        remote = ray.remote(num_cpus=1)(_ActorGroup)
        self._actors = [remote.remote(len(slots), view) for slots in self.slots]
        ray.get([a.ping.remote() for a in self._actors])
        self._pending: list[Any] = []

    def _call(self, group: int, cmd: str, *args: Any) -> Any:
        return self._ray.get(getattr(self._actors[group], cmd).remote(*args))

    def _send(self, order: StepOrder) -> None:
        policy = None if order.policy is None else self._ray.put(order.policy)
        self._pending = [
            actor.step.remote(order.rows(slots.start, slots.stop), policy)
            for actor, slots in zip(self._actors, self.slots, strict=True)
        ]

    def _receive(self) -> list[list[StepResult]]:
        out, self._pending = self._ray.get(self._pending), []
        return out

    def close(self) -> None:
        ray = self._ray
        actors = getattr(self, "_actors", [])
        try:
            ray.get([a.close.remote() for a in actors], timeout=30)
        except Exception:  # noqa: BLE001 - an actor that died or hangs is killed all the same
            pass
        for actor in actors:
            ray.kill(actor)
        self._actors = []
        self._waiting = False
        if self._started and ray.is_initialized():
            ray.shutdown()
        self._started = False
