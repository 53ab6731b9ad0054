"""Exploration for several environments at once: Gaussian and Ornstein-Uhlenbeck noise, and held actions.

All draw from the ``numpy.random.Generator`` they are given (the trainer's), so a run's exploration is part of its
seed and its checkpoint. ``sigma`` may be changed between calls (the trainer decays it).
"""

from __future__ import annotations

import numpy as np


class GaussianNoise:
    """Independent N(0, sigma^2) per step, per environment and per action dimension."""

    def __init__(self, n_envs: int, act_dim: int, sigma: float) -> None:
        self.shape = (n_envs, act_dim)
        self.sigma = float(sigma)

    def reset(self, env_index: int | None = None) -> None:
        """Nothing carries over between steps."""

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Noise (n_envs, act_dim)."""
        return self.sigma * rng.standard_normal(self.shape)

    def state_dict(self) -> dict[str, object]:
        return {"sigma": self.sigma}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.sigma = float(state["sigma"])


class OUNoise:
    """Ornstein-Uhlenbeck noise x <- x - theta x + sigma N(0, 1) per step (the DDPG paper's choice, dt = 1 step)."""

    def __init__(self, n_envs: int, act_dim: int, sigma: float, theta: float = 0.15) -> None:
        self.sigma = float(sigma)
        self.theta = float(theta)
        self.x = np.zeros((n_envs, act_dim))

    def reset(self, env_index: int | None = None) -> None:
        """Start again from zero (one environment's row, or all)."""
        if env_index is None:
            self.x[:] = 0.0
        else:
            self.x[env_index] = 0.0

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """The next noise value (n_envs, act_dim)."""
        self.x = self.x - self.theta * self.x + self.sigma * rng.standard_normal(self.x.shape)
        return self.x.copy()

    def state_dict(self) -> dict[str, object]:
        return {"sigma": self.sigma, "x": self.x.tolist()}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.sigma = float(state["sigma"])
        self.x = np.asarray(state["x"], dtype=np.float64).reshape(self.x.shape)


def make_noise(kind: str, n_envs: int, act_dim: int, sigma: float, theta: float = 0.15) -> GaussianNoise | OUNoise:
    """``gaussian`` or ``ou`` noise for ``n_envs`` environments."""
    if kind == "gaussian":
        return GaussianNoise(n_envs, act_dim, sigma)
    if kind == "ou":
        return OUNoise(n_envs, act_dim, sigma, theta)
    raise ValueError(f"unknown noise {kind!r}; expected gaussian or ou")


HOLD_ACTIONS = ("stop", "random")
"""What a held action is: ``stop`` (no displacement: the agent brakes and waits) or ``random`` (one uniform random
action in [-1, 1]^2, kept for the whole hold: temporally extended epsilon-greedy)."""


class HeldActions:
    """Temporally extended exploration: now and then an environment's action is replaced by one fixed action for
    several steps, whatever the actor wants.

    Each step, an environment not already holding starts a hold with probability ``prob``; the hold lasts a
    uniform whole number of steps in [1, ``max_steps``] and replaces the action by ``(0, 0)`` (``stop``: wait,
    an action small Gaussian noise around a fast actor's rarely comes near) or by one uniform random action (``random``,
    the epsilon-z-greedy exploration of Dabney, Ostrovski and Barreto 2021 with a uniform duration). Outside a
    hold the actor acts with its noise as usual (the noise is drawn during a hold too, and OU noise goes on
    evolving). ``prob`` stays the same over the run. The held actions are stored as taken, so the learner, being
    off policy, learns their values like any other action's.
    """

    def __init__(self, n_envs: int, act_dim: int, prob: float, max_steps: int, action: str = "stop") -> None:
        if action not in HOLD_ACTIONS:
            raise ValueError(f"unknown held action {action!r}; expected one of {', '.join(HOLD_ACTIONS)}")
        self.prob = float(prob)
        self.max_steps = int(max_steps)
        self.action = action
        self.left = np.zeros(n_envs, dtype=np.int64)
        """Steps each environment's hold still lasts (0: not holding)."""
        self.held = np.zeros((n_envs, act_dim))
        """Each environment's held action (meaningful where ``left`` > 0)."""

    def reset(self, env_index: int | None = None) -> None:
        """End the hold of one environment (its episode ended), or of all."""
        if env_index is None:
            self.left[:] = 0
        else:
            self.left[env_index] = 0

    def sample(self, rng: np.random.Generator) -> np.ndarray | None:
        """This step's replacement actions (n_envs, act_dim): the held action where an environment holds, NaN
        where the actor acts; None (and no random number drawn) when holds are off."""
        if self.prob <= 0.0:
            return None
        n, dim = self.held.shape
        starts = (self.left == 0) & (rng.random(n) < self.prob)
        if starts.any():
            k = int(starts.sum())
            self.left[starts] = rng.integers(1, self.max_steps + 1, k)
            self.held[starts] = 0.0 if self.action == "stop" else rng.uniform(-1.0, 1.0, (k, dim))
        out = np.full((n, dim), np.nan)
        holding = self.left > 0
        out[holding] = self.held[holding]
        self.left[holding] -= 1
        return out

    def state_dict(self) -> dict[str, object]:
        return {"left": self.left.tolist(), "held": self.held.tolist()}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.left = np.asarray(state["left"], dtype=np.int64).reshape(self.left.shape)
        self.held = np.asarray(state["held"], dtype=np.float64).reshape(self.held.shape)
