"""Policies for several aircraft at once (the multi-aircraft scenes, ``deck_sim.tasks.multi``).

A team policy maps the composer observation of every aircraft (keys ``aircraft_i:<key>``) to one action per
aircraft, an array (k, 2) in the task's action frame; the action of an aircraft that is done is not read.
``PrioritisedPolicy`` is the full-knowledge reference: prioritised planning over the task's ``planner_view`` of
every aircraft (``control.planners.PrioritisedPlanner``); ``IndependentPolicy`` lets every aircraft plan alone.
``SharedPolicy`` runs one single-agent policy (a learned actor, say) for every aircraft on its own observation; an
actor trained on n dynamic obstacles reads the n nearest of the n + k - 1 an aircraft observes (``nearest_dynamic``,
the documented adapter). ``make_team_policy`` builds any of them by name, as ``deck-sim run`` does for a
multi-aircraft scene.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from dm_control import composer

from deck_sim import agents
from deck_sim.control.planners import PrioritisedPlanner, ScriptedPlanner
from deck_sim.policies.actors import OBSTACLE_SETS, load_actor
from deck_sim.policies.reference import TEACHER_VIEWS, Policy
from deck_sim.policies.registry import TRAINED_DIR, make_policy, policy_file, policy_overrides


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


class IndependentPolicy:
    """Every aircraft plans alone: its own ``ScriptedPlanner`` on its ``MultiNavigate.planner_view`` (full
    knowledge), the other aircraft predicted by the task's predictor like any mover, no plan shared (what prioritised
    planning adds is the shared plans); with ``view`` ``observation``, on its own observation alone
    (``observed_view``: the teacher of the ``planner`` regime), ``observation-without-forecast`` without its
    forecast.

    Args:
        env: a composer environment of a multi-aircraft scene.
        view: what each planner reads (``deck_sim.policies.TEACHER_VIEWS``).
        body: ``ScriptedPlanner.body`` of every planner.
    """

    def __init__(self, env: composer.Environment, view: str = "full", body: bool = True) -> None:
        task = env.task
        if not task.spec.multi_agent:
            raise ValueError(f"scene {task.spec.name!r} has one agent: IndependentPolicy plans for several")
        if view not in TEACHER_VIEWS:
            raise ValueError(f"view: expected one of {', '.join(TEACHER_VIEWS)}, got {view!r}")
        self._env = env
        self.view = view
        self._planners = [ScriptedPlanner(body=body) for _ in range(task.n_agents)]

    def reset(self) -> None:
        """Forget the previous episode."""
        for planner in self._planners:
            planner.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Every aircraft's action (k, 2) in the task's action frame; zeros for an aircraft that is done."""
        task = self._env.task
        out = np.zeros((task.n_agents, 2))
        for i, a in enumerate(task.last_info["agents"]):
            if not a["done"]:
                if self.view == "full":
                    view = task.planner_view(i)
                else:
                    view = task.observed_view(forecast=self.view == "observation", agent=i)
                out[i] = task.action_from_world(self._planners[i].act(view), i)
        return out


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


TEAM_PLANNERS = {"prioritised": PrioritisedPolicy, "independent": IndependentPolicy}
"""The full-knowledge planners of several aircraft, by name."""


def single_scene(scene: str) -> str:
    """The single-aircraft scene a shipped multi-aircraft scene is built on (``deck1-multi`` -> ``deck1``)."""
    return scene.removesuffix("-multi")


def shared_actor_scene(name: str, scene: str) -> str:
    """The scene whose shipped actor a shipped policy name (``mddpg`` ...) means on the multi-aircraft ``scene``: the
    scene's own actor where one is shipped (trained for several aircraft, ``deck_sim/trained/<scene>_<name>.npz``),
    else the single-aircraft actor of the scene it is built on (``single_scene``), shared."""
    return scene if (TRAINED_DIR / f"{scene}_{name}.npz").exists() else single_scene(scene)


def team_policy_overrides(name: str, scene: str) -> dict[str, Any]:
    """The scene fields team policy ``name`` runs with on the multi-aircraft ``scene`` (``make_team_policy``): none
    for the planners, a shared policy's own (``policy_overrides``: a learned actor's predictor and observation)."""
    if name in TEAM_PLANNERS:
        return {}
    if name in (*agents.ORACLES, *agents.CLASSICAL, *agents.OBSERVERS):
        raise _not_a_team_policy(name, scene)
    return policy_overrides(name, shared_actor_scene(name, scene))


def _not_a_team_policy(name: str, scene: str) -> ValueError:
    return ValueError(
        f"policy {name!r} cannot act for the aircraft of scene {scene!r}, which has several: expected "
        f"{', '.join(TEAM_PLANNERS)} (full-knowledge planners of several aircraft), a learned policy "
        f"({', '.join(agents.LEARNED)}) or an actor .npz file shared by every aircraft, random or zero (the "
        "single-aircraft planners read one aircraft's task state)"
    )


def team_policy_file(name: str, scene: str) -> Path | None:
    """The actor file behind team policy ``name`` on the multi-aircraft ``scene`` (``shared_actor_scene`` for a
    shipped name), or None for a planner, ``random`` or ``zero``."""
    if name in TEAM_PLANNERS:
        return None
    return policy_file(name, shared_actor_scene(name, scene))


def make_team_policy(name: str, env: composer.Environment, seed: int = 0) -> TeamPolicy:
    """The team policy called ``name`` for a multi-aircraft ``env``: a planner of ``TEAM_PLANNERS``
    (``prioritised``, ``independent``), or a single-agent policy that reads the observation acting for every aircraft
    (``SharedPolicy``): a shipped learned name (``shared_actor_scene`` says which file), an actor ``.npz`` file,
    ``random`` or ``zero``. ``ValueError`` naming the choices for anything else (the single-aircraft planners
    read one aircraft's task state)."""
    if name in TEAM_PLANNERS:
        return TEAM_PLANNERS[name](env)
    scene = env.task.spec.name
    path = team_policy_file(name, scene)
    if path is not None:
        return SharedPolicy(load_actor(path), env)
    if name in ("random", "zero"):
        return SharedPolicy(make_policy(name, env, seed=seed), env)
    raise _not_a_team_policy(name, scene)
