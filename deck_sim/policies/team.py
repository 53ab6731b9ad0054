"""Policies for several aircraft at once (the multi-aircraft scenes, ``deck_sim.tasks.multi``).

A team policy maps the composer observation of every aircraft (keys ``aircraft_i:<key>``) to one action per
aircraft, an array (k, 2) in the task's action frame; the action of an aircraft that is done is not read.
``PrioritisedPolicy`` is the full-knowledge reference: prioritised planning over the task's ``planner_view`` of
every aircraft (``control.planners.PrioritisedPlanner``). ``SharedPolicy`` runs one single-agent policy (a
learned actor, say) for every aircraft on its own observation; an actor trained on n dynamic obstacles reads the
n nearest of the n + k - 1 an aircraft observes (``nearest_dynamic``, the documented adapter).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np
from dm_control import composer

from deck_sim.control.planners import PrioritisedPlanner
from deck_sim.policies.actors import OBSTACLE_SETS
from deck_sim.policies.reference import Policy


class TeamPolicy(Protocol):
    """Anything that maps the observations of k aircraft to their k actions."""

    def reset(self) -> None:
        """Start of an episode."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Actions (k, 2), one row per aircraft in index order."""


class PrioritisedPolicy:
    """Prioritised planning with full knowledge for every aircraft of a multi-aircraft task
    (``PrioritisedPlanner`` on ``MultiNavigate.planner_view`` of each aircraft that is not done).

    Args:
        env: a composer environment of a multi-aircraft scene.
        **scripted: ``ScriptedPlanner``'s arguments for every aircraft's planner.
    """

    def __init__(self, env: composer.Environment, **scripted: float | bool | tuple[float, ...]) -> None:
        task = env.task
        if not task.spec.multi_agent:
            raise ValueError(f"scene {task.spec.name!r} has one agent: PrioritisedPolicy plans for several")
        self._env = env
        self.planner = PrioritisedPlanner(task.n_agents, **scripted)
        self._rows = task.agent_rows()

    def reset(self) -> None:
        """Forget the previous episode."""
        self.planner.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Every aircraft's action (k, 2) in the task's action frame, planned from the task's state (the observation
        is not needed); zeros for an aircraft that is done."""
        task = self._env.task
        done = [a["done"] for a in task.last_info["agents"]]
        views = [None if d else task.planner_view(i) for i, d in enumerate(done)]
        actions = self.planner.act(views, self._rows)
        return np.array(
            [np.zeros(2) if a is None else task.action_from_world(a, i) for i, a in enumerate(actions)]
        )


def nearest_dynamic(observation: Mapping[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """The observation with its ``n`` nearest dynamic obstacles only: the first ``n`` rows of every key of one row
    per mover (``OBSTACLE_SETS["movers"]``; their rows are sorted nearest first), every other key as it is."""
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    movers = set(OBSTACLE_SETS["movers"])
    return {k: (np.asarray(v)[:n] if k in movers else v) for k, v in observation.items()}


class SharedPolicy:
    """One single-agent policy acting for every aircraft of a multi-aircraft task, each on its own observation.

    A policy that reads the observation (a learned actor, ``random``, ``zero``) runs unchanged: aircraft i's
    observation holds the single-agent keys; when the policy was trained on fewer dynamic obstacles than the
    n + k - 1 an aircraft sees (its recorded ``shapes``), it reads the nearest it was trained on
    (``nearest_dynamic``). Planners that read the task's state for one agent (``scripted`` ...) do not fit: use
    ``PrioritisedPolicy``.

    Args:
        policy: the single-agent policy.
        env: a composer environment of a multi-aircraft scene.
    """

    def __init__(self, policy: Policy, env: composer.Environment) -> None:
        task = env.task
        if not task.spec.multi_agent:
            raise ValueError(f"scene {task.spec.name!r} has one agent: run the policy itself")
        self.policy = policy
        self._names = task.agent_names
        shapes = getattr(policy, "shapes", None) or {}
        trained = shapes.get("dynamic_obstacles")
        seen = task.observation_shapes["dynamic_obstacles"][0]
        self.dynamic = int(trained[0]) if trained is not None and trained[0] < seen else None
        """How many of each aircraft's nearest dynamic obstacles the policy reads (None: all)."""

    def reset(self) -> None:
        """Start of an episode."""
        self.policy.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Every aircraft's action (k, 2) from its own observation."""
        out = np.zeros((len(self._names), 2))
        for i, name in enumerate(self._names):
            prefix = f"{name}:"
            own = {k[len(prefix):]: v for k, v in observation.items() if k.startswith(prefix)}
            if self.dynamic is not None:
                own = nearest_dynamic(own, self.dynamic)
            out[i] = self.policy.act(own)
        return out

