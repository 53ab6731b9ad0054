"""Replay buffer with typed batches (stable-baselines3 style), and a protected share for demonstrations.

Transitions are stored as raw float32 observations; normalisation happens at sampling time in the agent, so the
buffer's content does not depend on statistics that change during training. ``terminated`` marks a true end of the
episode (goal, collision, leaving the deck: no bootstrap); a time-limit truncation is stored with
``terminated = False`` and the final observation as ``next_obs``, so the critic bootstraps through it.

With ``track_episodes`` the buffer also knows which of the agent's transitions belong to one episode, in order
(``episode_rows``), and how each ended (``reached``, ``failed``): what hindsight goals and n-step returns
(``training.her``) read. The bookkeeping draws no random numbers and changes no stored transition.

With ``prioritised`` the agent's rows carry a priority (proportional prioritised replay, Schaul et al. 2016):
``prioritised_rows`` draws them in proportion to it and gives each its importance-sampling weight, and
``update_priorities`` sets the priorities from the last update's TD errors.
"""

from __future__ import annotations

from dataclasses import dataclass
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
    discount: torch.Tensor | None = None
    """Per transition, the discount of the bootstrap from ``next_obs`` (gamma^m after an m-step return); None:
    every transition is one step, discounted by the config's gamma."""
    weight: torch.Tensor | None = None
    """Per transition, the importance-sampling weight of its squared TD error (prioritised replay); None: 1."""


@dataclass(frozen=True)
class EpisodeMarks:
    """Where n transitions stand in their episodes and how they ended (arrays of shape (n,)).

    Attributes:
        episode: an id of each transition's episode, unique to the run.
        step: the transition's step in its episode (0 for the first).
        reached: 1 where it reached the target.
        failed: 1 where it ended in a collision, off the surface or in divergence.
        goal_ok: 1 where its reward can be recomputed for another target (0 after physics divergence).
        end: 1 on the episode's last transition (terminated or truncated).
    """

    episode: np.ndarray
    step: np.ndarray
    reached: np.ndarray
    failed: np.ndarray
    goal_ok: np.ndarray
    end: np.ndarray


class ReplayBuffer:
    """A ring buffer of transitions whose first ``n_demo`` rows (the demonstrations) are never overwritten.

    Args:
        capacity: rows in all, demonstrations included.
        obs_dim, act_dim: sizes of one observation and one action.
        track_episodes: keep each agent episode's rows in step order and how each transition ended (``add``'s
            ``marks``).
        prioritised: keep a priority per agent row (``prioritised_rows``, ``update_priorities``).
    """

    def __init__(
        self, capacity: int, obs_dim: int, act_dim: int, track_episodes: bool = False, prioritised: bool = False
    ) -> None:
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
        self.track_episodes = bool(track_episodes)
        if self.track_episodes:
            self.episode = np.full(capacity, -1, dtype=np.int64)
            """The agent episode each row belongs to (-1: a demonstration, or no row yet)."""
            self.episode_pos = np.zeros(capacity, dtype=np.int64)
            """Each row's index in its episode's ``episode_rows``: the step of the episode it records."""
            self.reached = np.zeros(capacity, dtype=np.float32)
            """1 where the transition reached the episode's target."""
            self.failed = np.zeros(capacity, dtype=np.float32)
            """1 where it ended in a collision, off the surface or in divergence."""
            self.goal_ok = np.zeros(capacity, dtype=np.float32)
            """1 where its reward can be recomputed for another target (0 after physics divergence: reward 0)."""
            self.episode_end = np.zeros(capacity, dtype=np.float32)
            """1 on an episode's last transition (terminated or truncated)."""
            self.episode_rows: dict[int, list[int]] = {}
            """Per episode still in the buffer, its rows by step (-1 where overwritten)."""
        self.prioritised = bool(prioritised)
        if self.prioritised:
            self.priority = np.zeros(capacity, dtype=np.float64)
            """Each agent row's sampling priority, (|TD error| + eps)^alpha of its last update."""
            self.max_priority = 1.0
            """The largest priority given so far: a new row's."""

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
        marks: EpisodeMarks | None = None,
    ) -> None:
        """Store a batch of the agent's transitions (n, ...), overwriting its oldest when full.

        ``expert_action``: what the demonstrator would have done in each ``obs`` (online relabelling), if known.
        ``marks``: where each transition stands in its episode (required with ``track_episodes``).
        """
        n = len(obs)
        span = self.capacity - self.n_demo
        rows = self.n_demo + (self._next - self.n_demo + np.arange(n)) % span
        if self.track_episodes:
            if marks is None:
                raise ValueError("a buffer that tracks episodes needs each transition's EpisodeMarks")
            self._track(rows, marks)
        self._write(rows, obs, action, reward, next_obs, terminated)
        if expert_action is None:
            self.expert_action[rows] = 0.0
            self.labelled[rows] = 0.0
        else:
            self.expert_action[rows] = expert_action
            self.labelled[rows] = 1.0
        if self.prioritised:
            self.priority[rows] = self.max_priority
        self._next = int(self.n_demo + (rows[-1] - self.n_demo + 1) % span)
        self.size = min(self.capacity, self.size + n)

    def _track(self, rows: np.ndarray, marks: EpisodeMarks) -> None:
        """Record which episode and step each new row holds, forgetting the rows it overwrites."""
        steps = np.asarray(marks.step, dtype=np.int64).tolist()
        for row, ep, step in zip(rows.tolist(), np.asarray(marks.episode, dtype=np.int64).tolist(), steps, strict=True):
            old = int(self.episode[row])
            if old >= 0:
                lst = self.episode_rows[old]
                pos = int(self.episode_pos[row])
                lst[pos] = -1
                if pos == len(lst) - 1:  # rows go in step order: nothing of that episode is left
                    del self.episode_rows[old]
            lst = self.episode_rows.setdefault(ep, [])
            lst.extend([-1] * (step - len(lst)))  # (steps whose rows are gone already)
            lst.append(row)
            self.episode[row] = ep
            self.episode_pos[row] = step
        self.reached[rows] = marks.reached
        self.failed[rows] = marks.failed
        self.goal_ok[rows] = marks.goal_ok
        self.episode_end[rows] = marks.end

    def sample(self, batch_size: int, rng: np.random.Generator, demo_fraction: float = 0.0) -> Batch:
        """Uniform rows; ``demo_fraction`` of them from the demonstrations when there are both kinds."""
        return self.batch(self.sample_rows(batch_size, rng, demo_fraction))

    def sample_rows(self, batch_size: int, rng: np.random.Generator, demo_fraction: float = 0.0) -> np.ndarray:
        """The rows ``sample`` takes (the same draws from ``rng``)."""
        n_demo, demo_rows = self._demo_rows(batch_size, rng, demo_fraction)
        agent_rows = (
            rng.integers(self.n_demo, self.size, batch_size - n_demo)
            if batch_size > n_demo
            else np.zeros(0, dtype=np.int64)
        )
        return np.concatenate([demo_rows, agent_rows])

    def _demo_rows(self, batch_size: int, rng: np.random.Generator, demo_fraction: float) -> tuple[int, np.ndarray]:
        """How many of ``batch_size`` rows come from the demonstrations (``demo_fraction`` of them when there are
        both kinds, all when there are only demonstrations) and those rows, drawn uniformly."""
        if self.size == 0:
            raise RuntimeError("cannot sample from an empty replay buffer")
        n_demo = 0
        if self.n_demo and self.n_agent:
            n_demo = int(round(batch_size * demo_fraction))
        elif self.n_demo:
            n_demo = batch_size
        return n_demo, rng.integers(0, self.n_demo, n_demo) if n_demo else np.zeros(0, dtype=np.int64)

    def prioritised_rows(
        self, batch_size: int, rng: np.random.Generator, demo_fraction: float = 0.0, beta: float = 0.4
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows as ``sample_rows`` splits them between demonstrations (uniform) and the agent's rows, these drawn in
        proportion to their priority, and the importance-sampling weight of each: (N P(i))^-beta over the agent
        rows, divided by the batch's largest (demonstrations weigh 1)."""
        if not self.prioritised:
            raise RuntimeError("prioritised_rows needs a buffer made with prioritised=True")
        n_demo, demo_rows = self._demo_rows(batch_size, rng, demo_fraction)
        k = batch_size - n_demo
        weights = np.ones(batch_size, dtype=np.float32)
        if k == 0:
            return demo_rows, weights
        p = self.priority[self.n_demo : self.size]
        cum = np.cumsum(p)
        total = float(cum[-1])
        picks = np.minimum(np.searchsorted(cum, rng.random(k) * total, side="right"), len(p) - 1)
        w = (len(p) * p[picks] / total) ** -beta
        weights[n_demo:] = w / w.max()
        return np.concatenate([demo_rows, self.n_demo + picks]), weights

    def update_priorities(self, rows: np.ndarray, td_error: np.ndarray, alpha: float, eps: float) -> None:
        """Set the priority of the agent's ``rows`` to (|``td_error``| + ``eps``)^``alpha`` (demonstration rows are
        left as they are)."""
        agent = rows >= self.n_demo
        value = (np.abs(np.asarray(td_error, dtype=np.float64)[agent]) + eps) ** alpha
        self.priority[rows[agent]] = value
        if value.size:
            self.max_priority = max(self.max_priority, float(value.max()))

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
            **{k: torch.from_numpy(getattr(self, k)[:n].copy()) for k in self._arrays()},
            **({"max_priority": self.max_priority} if self.prioritised else {}),
        }

    def _arrays(self) -> tuple[str, ...]:
        return (
            self._ARRAYS
            + (self._EPISODE_ARRAYS if self.track_episodes else ())
            + (("priority",) if self.prioritised else ())
        )

    def load_state_dict(self, state: dict[str, object]) -> None:
        """Restore what ``state_dict`` returned (the buffer must have the same capacity and sizes)."""
        if int(state["capacity"]) != self.capacity:
            raise ValueError(f"checkpoint buffer capacity {state['capacity']} != this run's {self.capacity}")
        n = int(state["size"])
        missing = [k for k in self._arrays() if k not in state]
        if missing:
            raise ValueError(
                f"checkpoint buffer lacks {', '.join(missing)} (saved without episode tracking or priorities)"
            )
        for k in self._arrays():
            value = state[k].numpy()
            if value.shape[1:] != getattr(self, k).shape[1:]:
                raise ValueError(
                    f"checkpoint buffer {k} has rows of shape {value.shape[1:]}, expected {getattr(self, k).shape[1:]}"
                )
            getattr(self, k)[:n] = value
        self.n_demo, self.size, self._next = int(state["n_demo"]), n, int(state["next"])
        if self.prioritised:
            self.max_priority = float(state["max_priority"])
        if self.track_episodes:
            self._rebuild_episode_rows()

    def _rebuild_episode_rows(self) -> None:
        """``episode_rows`` from the per-row arrays (after loading a checkpoint)."""
        self.episode_rows = {}
        rows = np.flatnonzero(self.episode[: self.size] >= 0)
        for row in rows[np.lexsort((self.episode_pos[rows], self.episode[rows]))].tolist():
            ep, pos = int(self.episode[row]), int(self.episode_pos[row])
            lst = self.episode_rows.setdefault(ep, [])
            lst.extend([-1] * (pos - len(lst)))  # rows already overwritten
            lst.append(row)

    _ARRAYS = ("obs", "next_obs", "action", "reward", "terminated", "expert_action", "labelled")
    _EPISODE_ARRAYS = ("episode", "episode_pos", "reached", "failed", "goal_ok", "episode_end")
