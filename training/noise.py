"""Exploration noise for several environments at once: Gaussian and Ornstein-Uhlenbeck.

Both draw from the ``numpy.random.Generator`` they are given (the trainer's), so a run's noise is part of its seed
and its checkpoint. ``sigma`` may be changed between calls (the trainer decays it).
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
