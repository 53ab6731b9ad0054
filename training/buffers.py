"""Replay buffer with typed batches (stable-baselines3 style), and a protected share for demonstrations.

Transitions are stored as raw float32 observations; normalisation happens at sampling time in the agent, so the
buffer's content does not depend on statistics that change during training. ``terminated`` marks a true end of the
episode (goal, collision, leaving the deck: no bootstrap); a time-limit truncation is stored with
``terminated = False`` and the final observation as ``next_obs``, so the critic bootstraps through it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch


class Batch(NamedTuple):
    """A batch of transitions as float32 tensors (``terminated`` and ``demo`` are 0/1 floats), shape (B, ...)."""

    obs: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    next_obs: torch.Tensor
    terminated: torch.Tensor
    demo: torch.Tensor
    expert_action: torch.Tensor
    """The demonstrator's own action (the cloning target; equals ``action`` unless noise was injected)."""
    labelled: torch.Tensor
    """1 where ``expert_action`` holds a label: every demonstration, and agent transitions relabelled online."""


class ReplayBuffer:
    """A ring buffer of transitions whose first ``n_demo`` rows (the demonstrations) are never overwritten.

    Args:
        capacity: rows in all, demonstrations included.
        obs_dim, act_dim: sizes of one observation and one action.
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self.capacity = int(capacity)
        self.obs = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.action = np.zeros((capacity, act_dim), dtype=np.float32)
        self.reward = np.zeros(capacity, dtype=np.float32)
        self.terminated = np.zeros(capacity, dtype=np.float32)
        self.expert_action = np.zeros((capacity, act_dim), dtype=np.float32)
        self.labelled = np.zeros(capacity, dtype=np.float32)
        self.n_demo = 0
        self.size = 0
        self._next = 0

    @property
    def n_agent(self) -> int:
        """Rows holding the agent's own transitions."""
        return self.size - self.n_demo

    def _write(self, rows: np.ndarray, obs, action, reward, next_obs, terminated) -> None:  # noqa: ANN001
        self.obs[rows] = obs
        self.action[rows] = action
        self.reward[rows] = reward
        self.next_obs[rows] = next_obs
        self.terminated[rows] = terminated

    def add_demos(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        expert_action: np.ndarray | None = None,
    ) -> None:
        """Store demonstration transitions (before any of the agent's; they stay for the whole run).

        ``expert_action`` is what the demonstrator wanted where noise changed what was done (default ``action``).
        """
        if self.n_agent:
            raise RuntimeError("demonstrations must be added before the agent's own transitions")
        n = len(obs)
        if self.n_demo + n >= self.capacity:
            raise ValueError(
                f"{self.n_demo + n} demonstration transitions leave no room in a buffer of {self.capacity}"
            )
        rows = np.arange(self.n_demo, self.n_demo + n)
        self._write(rows, obs, action, reward, next_obs, terminated)
        self.expert_action[rows] = action if expert_action is None else expert_action
        self.labelled[rows] = 1.0
        self.n_demo += n
        self.size = self._next = self.n_demo

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        expert_action: np.ndarray | None = None,
    ) -> None:
        """Store a batch of the agent's transitions (n, ...), overwriting its oldest when full.

        ``expert_action``: what the demonstrator would have done in each ``obs`` (online relabelling), if known.
        """
        n = len(obs)
        span = self.capacity - self.n_demo
        rows = self.n_demo + (self._next - self.n_demo + np.arange(n)) % span
        self._write(rows, obs, action, reward, next_obs, terminated)
        if expert_action is None:
            self.expert_action[rows] = 0.0
            self.labelled[rows] = 0.0
        else:
            self.expert_action[rows] = expert_action
            self.labelled[rows] = 1.0
        self._next = int(self.n_demo + (rows[-1] - self.n_demo + 1) % span)
        self.size = min(self.capacity, self.size + n)

    def sample(self, batch_size: int, rng: np.random.Generator, demo_fraction: float = 0.0) -> Batch:
        """Uniform rows; ``demo_fraction`` of them from the demonstrations when there are both kinds."""
        if self.size == 0:
            raise RuntimeError("cannot sample from an empty replay buffer")
        n_demo = 0
        if self.n_demo and self.n_agent:
            n_demo = int(round(batch_size * demo_fraction))
        elif self.n_demo:
            n_demo = batch_size
        rows = np.concatenate(
            [
                rng.integers(0, self.n_demo, n_demo) if n_demo else np.zeros(0, dtype=np.int64),
                rng.integers(self.n_demo, self.size, batch_size - n_demo)
                if batch_size > n_demo
                else np.zeros(0, dtype=np.int64),
            ]
        )
        return self.batch(rows)

    def batch(self, rows: np.ndarray) -> Batch:
        """The rows ``rows`` as a typed batch."""
        t = torch.from_numpy
        return Batch(
            obs=t(self.obs[rows]),
            action=t(self.action[rows]),
            reward=t(self.reward[rows]),
            next_obs=t(self.next_obs[rows]),
            terminated=t(self.terminated[rows]),
            demo=t((rows < self.n_demo).astype(np.float32)),
            expert_action=t(self.expert_action[rows]),
            labelled=t(self.labelled[rows]),
        )

    def state_dict(self) -> dict[str, object]:
        """The filled rows and counters, as tensors and ints (loadable with ``torch.load(weights_only=True)``)."""
        n = self.size
        return {
            "capacity": self.capacity,
            "n_demo": self.n_demo,
            "size": n,
            "next": self._next,
            **{k: torch.from_numpy(getattr(self, k)[:n].copy()) for k in self._ARRAYS},
        }

    def load_state_dict(self, state: dict[str, object]) -> None:
        """Restore what ``state_dict`` returned (the buffer must have the same capacity and sizes)."""
        if int(state["capacity"]) != self.capacity:
            raise ValueError(f"checkpoint buffer capacity {state['capacity']} != this run's {self.capacity}")
        n = int(state["size"])
        for k in self._ARRAYS:
            value = state[k].numpy()
            if value.shape[1:] != getattr(self, k).shape[1:]:
                raise ValueError(
                    f"checkpoint buffer {k} has rows of shape {value.shape[1:]}, expected {getattr(self, k).shape[1:]}"
                )
            getattr(self, k)[:n] = value
        self.n_demo, self.size, self._next = int(state["n_demo"]), n, int(state["next"])

    _ARRAYS = ("obs", "next_obs", "action", "reward", "terminated", "expert_action", "labelled")
