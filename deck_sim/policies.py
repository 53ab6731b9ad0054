"""Policies that need no training, with the ``act(observation) -> action`` interface of learned agents.

``scripted`` plans with full knowledge of the scene through the task's ``planner_view`` (run it with the
``oracle`` predictor so that it sees the movers' true future); ``random`` and ``zero`` are references.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from dm_control import composer

from deck_sim.control.planners import ScriptedPlanner


class Policy(Protocol):
    """Anything that maps an observation to an action in [-1, 1]^2."""

    def reset(self) -> None:
        """Start of an episode."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Action (2,) for this observation."""


class ScriptedPolicy:
    """The full-knowledge ``ScriptedPlanner`` reading the task's privileged ``planner_view``."""

    def __init__(self, env: composer.Environment, planner: ScriptedPlanner | None = None) -> None:
        self._env = env
        self.planner = planner or ScriptedPlanner()

    def reset(self) -> None:
        """Forget the previous episode."""
        self.planner.reset()

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Plan from the task's full state (the observation is not needed)."""
        return self.planner.act(self._env.task.planner_view())


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


POLICY_NAMES = ("scripted", "random", "zero")


def make_policy(name: str, env: composer.Environment, seed: int = 0) -> Policy:
    """The policy called ``name`` for ``env``; raises ``ValueError`` listing the known names."""
    if name == "scripted":
        return ScriptedPolicy(env)
    if name == "random":
        return RandomPolicy(seed)
    if name == "zero":
        return ZeroPolicy()
    raise ValueError(f"unknown policy {name!r}; expected one of {', '.join(POLICY_NAMES)}")
