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


class ScriptedPolicy:
    """The full-knowledge ``ScriptedPlanner`` reading the task's privileged ``planner_view``."""

    def __init__(
        self, env: composer.Environment, planner: ScriptedPlanner | APFPlanner | AStarPlanner | MPCPlanner | None = None
    ) -> None:
        self._env = env
        self.planner = planner or ScriptedPlanner()

    def reset(self) -> None:
        """Forget the previous episode."""
        self.planner.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Plan from the task's full state (the observation is not needed); the planner's world-frame action is
        turned into the task's action frame (``episode.frame``)."""
        task = self._env.task
        return task.action_from_world(self.planner.act(task.planner_view()))


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
