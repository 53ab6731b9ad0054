"""Policies that need no training: the full-knowledge scripted planner and the classical planners (through
``ScriptedPolicy``), random and zero actions; and the ``Policy`` protocol every policy follows."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from dm_control import composer

from deck_sim.control.planners import APFPlanner, AStarPlanner, MPCPlanner, ScriptedPlanner


class Policy(Protocol):
    """Anything that maps an observation to an action in [-1, 1]^2."""

    def reset(self) -> None:
        """Start of an episode."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Action (2,) for this observation."""


TEACHER_VIEWS = ("full", "observation", "observation-without-forecast")
"""What ``ScriptedPolicy``'s planner reads: ``full``, the task's privileged state (``Navigate.planner_view``);
``observation``, only what the step's observation holds (``Navigate.observed_view``: the observed footprints and
the observed forecast); ``observation-without-forecast``, the same with every mover taken to stand where it is
(the view of an agent whose observation holds no prediction)."""


class ScriptedPolicy:
    """A planner (by default the scripted one) reading the task's privileged ``planner_view``, or with ``view``
    only what the observation holds (``TEACHER_VIEWS``)."""

    def __init__(
        self,
        env: composer.Environment,
        planner: ScriptedPlanner | APFPlanner | AStarPlanner | MPCPlanner | None = None,
        view: str = "full",
    ) -> None:
        if view not in TEACHER_VIEWS:
            raise ValueError(f"view: expected one of {', '.join(TEACHER_VIEWS)}, got {view!r}")
        self._env = env
        self.planner = planner or ScriptedPlanner()
        self.view = view

    def reset(self) -> None:
        """Forget the previous episode."""
        self.planner.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Plan from the task's state as ``view`` allows (the observation argument is not needed: the task holds
        this step's); the planner's world-frame action is turned into the task's action frame
        (``episode.frame``)."""
        task = self._env.task
        if self.view == "full":
            view = task.planner_view()
        else:
            view = task.observed_view(forecast=self.view == "observation")
        return task.action_from_world(self.planner.act(view))


class RandomPolicy:
    """Uniform random actions from a seeded generator."""

    def __init__(self, seed: int = 0) -> None:
        self._rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """Nothing to reset; the generator continues."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """A uniform draw from [-1, 1]^2."""
        return self._rng.uniform(-1.0, 1.0, 2)


class ZeroPolicy:
    """Always asks to stand still."""

    def reset(self) -> None:
        """Nothing to reset."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """(0, 0)."""
        return np.zeros(2)
