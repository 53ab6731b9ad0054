"""Hindsight goals and n-step returns for the replay buffer: what a stored transition would have been worth with
another target, and over several steps.

Hindsight Experience Replay (Andrychowicz et al. 2017, built for DDPG) relabels a sampled transition with a target
the agent did reach later in the same episode (the ``future`` strategy): the target-dependent parts of both
observations (``target``, and ``target_near`` when the scene observes it) and of the reward (eq. 10's attraction and
eq. 13's goal term) are recomputed from what the buffer stores, the agent's ``position`` and ``heading`` in each
observation; the repulsion and collision terms do not depend on the target and are kept. A relabelled transition
ends where the agent comes within ``agent.goal_radius`` of the new target without failing, or where it failed
(collision, leaving the surface, divergence), as the task ends an episode.

The attraction of the stored target is recomputed from the stored float32 observation, as the new one is, so a
relabelled reward differs from the task's own by float32 rounding of the distances at most.

n-step returns (Sutton and Barto, ch. 7) sum the discounted rewards of the next n transitions of the episode and
bootstrap from the state after them with gamma^n, or stop at the episode's end (no bootstrap after a terminal
transition; a time-limit truncation bootstraps from the final observation, as the 1-step target does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from deck_sim.scenes import SceneSpec
from training.buffers import Batch, ReplayBuffer


class GoalLayoutError(ValueError):
    """The scene's observation holds target-dependent parts that hindsight relabelling cannot recompute."""


ROUTE_REFUSAL = (
    "hindsight goals: the observation holds 'route' (episode.route_steps > 0), the way to the target round the "
    "static obstacles, which a relabelled target would need planned again; set route_steps = 0"
)
"""Why an observation with ``route`` takes no hindsight targets."""


@dataclass(frozen=True)
class GoalGeometry:
    """Where the target-dependent parts of a flat observation lie, and the reward constants that depend on the target.

    Attributes:
        target: columns of ``target`` (target minus agent, metres).
        target_near: columns of ``target_near`` (that vector clipped to ``near`` metres), or None.
        position: columns of ``position`` (the agent's world position, metres).
        heading: columns of ``heading`` (cos and sin of the agent's yaw).
        agent_frame: relative vectors are in the agent's axes (``episode.frame = "agent"``).
        near: the near field's radius, metres (0 without ``target_near``).
        goal_radius: metres (``agent.goal_radius``).
        attraction_min, attraction_max, deadband: eq. 10's l, L and the dead band, metres.
        w_attraction, w_goal: eq. 16's weights of the attraction and goal terms.
        goal_reward: eq. 13's r4.
    """

    target: slice
    target_near: slice | None
    position: slice
    heading: slice
    agent_frame: bool
    near: float
    goal_radius: float
    attraction_min: float
    attraction_max: float
    deadband: float
    w_attraction: float
    w_goal: float
    goal_reward: float

    @classmethod
    def of(cls, spec: SceneSpec, shapes: dict[str, tuple[int, ...]]) -> GoalGeometry:
        """The geometry of ``spec``'s observation laid out as ``shapes`` (keys in the flat vector's order).

        Raises:
            GoalLayoutError: the observation holds ``route`` (the shortest way to the target, which a relabelled
                target would need planned again) or lacks ``target``, ``position`` or ``heading``.
        """
        columns: dict[str, slice] = {}
        start = 0
        for key, shape in shapes.items():
            size = int(np.prod(shape))
            columns[key] = slice(start, start + size)
            start += size
        if "route" in columns:
            raise GoalLayoutError(ROUTE_REFUSAL)
        missing = [k for k in ("target", "position", "heading") if k not in columns]
        if missing:
            raise GoalLayoutError(f"hindsight goals: the observation lacks {', '.join(missing)}")
        r = spec.reward
        near = spec.episode.near_steps * spec.agent.reach if "target_near" in columns else 0.0
        return cls(
            target=columns["target"],
            target_near=columns.get("target_near"),
            position=columns["position"],
            heading=columns["heading"],
            agent_frame=spec.episode.frame == "agent",
            near=float(near),
            goal_radius=float(spec.agent.goal_radius),
            attraction_min=float(r.attraction_min),
            attraction_max=float(r.attraction_max),
            deadband=float(r.progress_deadband),
            w_attraction=float(r.w_attraction),
            w_goal=float(r.w_goal),
            goal_reward=float(r.goal),
        )

    def relative(self, goals: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """``goals`` (B, 2) minus each observation's agent position, in the observation's axes (B, 2), float64."""
        rel = goals.astype(np.float64) - obs[:, self.position].astype(np.float64)
        if not self.agent_frame:
            return rel
        c, s = obs[:, self.heading.start].astype(np.float64), obs[:, self.heading.start + 1].astype(np.float64)
        return np.stack([rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c], axis=1)

    def with_goals(self, obs: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """Copies of ``obs`` (B, D) whose target-dependent parts point at ``goals`` (B, 2, world metres)."""
        out = obs.copy()
        rel = self.relative(goals, obs)
        out[:, self.target] = rel
        if self.target_near is not None:
            length = np.hypot(rel[:, 0], rel[:, 1])
            scale = np.where(length > self.near, self.near / np.maximum(length, 1e-300), 1.0)
            out[:, self.target_near] = rel * scale[:, None]
        return out

    def distance(self, obs: np.ndarray) -> np.ndarray:
        """The distance to the target each observation (B, D) holds, metres (B,), float64."""
        t = obs[:, self.target].astype(np.float64)
        return np.hypot(t[:, 0], t[:, 1])

    def attraction(self, before: np.ndarray, after: np.ndarray) -> np.ndarray:
        """Eq. 10 for distances to the target before and after each step (B,): the progress's sign, its magnitude
        clipped to [l, L], 0 inside the dead band (``deck_sim.tasks.rewards.attraction``, vectorised)."""
        change = before - after
        magnitude = np.clip(np.abs(change), self.attraction_min, self.attraction_max)
        return np.where(np.abs(change) < self.deadband, 0.0, np.where(change >= 0, magnitude, -magnitude))

    def target_terms(self, obs: np.ndarray, next_obs: np.ndarray, reached: np.ndarray) -> np.ndarray:
        """The target-dependent part of each transition's reward, w1 r1 + w4 r4 (B,), for the targets the
        observations hold; ``reached`` (B,) says where r4 was paid."""
        r1 = self.attraction(self.distance(obs), self.distance(next_obs))
        return self.w_attraction * r1 + self.w_goal * self.goal_reward * reached.astype(np.float64)


def relabel(
    geometry: GoalGeometry,
    obs: np.ndarray,
    next_obs: np.ndarray,
    reward: np.ndarray,
    reached: np.ndarray,
    failed: np.ndarray,
    goals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Transitions (B rows) with their targets replaced by ``goals`` (B, 2, world metres).

    Args:
        obs, next_obs: (B, D) the stored float32 observations.
        reward: (B,) the stored rewards.
        reached: (B,) 1 where the transition reached its own target.
        failed: (B,) 1 where it ended in a collision, off the surface or in divergence.
        goals: (B, 2) the new targets.

    Returns:
        (obs, next_obs, reward, terminated) for the new targets, float32; a failed transition stays terminal.
    """
    new_obs = geometry.with_goals(obs, goals)
    new_next = geometry.with_goals(next_obs, goals)
    failed = failed.astype(bool)
    now_reached = (geometry.distance(new_next) <= geometry.goal_radius) & ~failed
    rest = reward.astype(np.float64) - geometry.target_terms(obs, next_obs, reached)
    new_reward = rest + geometry.target_terms(new_obs, new_next, now_reached)
    terminated = now_reached | failed
    return (
        new_obs.astype(np.float32),
        new_next.astype(np.float32),
        new_reward.astype(np.float32),
        terminated.astype(np.float32),
    )


def n_step_discounts(gamma: float, n: int) -> np.ndarray:
    """gamma^k for k = 0 .. n (n + 1 values, float64)."""
    return np.array([math.pow(gamma, k) for k in range(n + 1)])


class HindsightSampler:
    """Turns sampled rows of an episode-tracking ``ReplayBuffer`` into a batch with hindsight targets and n-step
    returns.

    Args:
        geometry: the scene's ``GoalGeometry`` (required when ``her_ratio`` > 0).
        her_ratio: the share of the agent's sampled transitions given a later position of their episode as the
            target (0: none).
        n_step: transitions summed per return (1: the one-step target).
        gamma: the discount.
    """

    def __init__(self, geometry: GoalGeometry | None, her_ratio: float, n_step: int, gamma: float) -> None:
        if not 0.0 <= her_ratio <= 1.0:
            raise ValueError(f"her_ratio must lie in [0, 1], got {her_ratio}")
        if n_step < 1:
            raise ValueError(f"n_step must be at least 1, got {n_step}")
        if her_ratio > 0.0 and geometry is None:
            raise ValueError("hindsight goals need the scene's GoalGeometry")
        self.geometry = geometry
        self.her_ratio = float(her_ratio)
        self.n_step = int(n_step)
        self.gamma = float(gamma)
        self._powers = n_step_discounts(gamma, n_step)

    def chains(self, buffer: ReplayBuffer, rows: np.ndarray) -> tuple[np.ndarray, list[list[int] | None]]:
        """(B, n_step) rows of each sampled transition and the ones after it in its episode (-1 past the rows
        stored), and each one's episode rows (None for a demonstration)."""
        chains = np.full((len(rows), self.n_step), -1, dtype=np.int64)
        chains[:, 0] = rows
        lists = [buffer.episode_rows.get(int(e)) if e >= 0 else None for e in buffer.episode[rows].tolist()]
        if self.n_step > 1:
            for b, (lst, pos) in enumerate(zip(lists, buffer.episode_pos[rows].tolist(), strict=True)):
                if lst is not None:
                    seg = lst[pos : pos + self.n_step]
                    chains[b, : len(seg)] = seg
        return chains, lists

    def goals(
        self, buffer: ReplayBuffer, rows: np.ndarray, lists: list[list[int] | None], rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which sampled transitions get a hindsight target (B,) bool, and the targets (B, 2): the position after
        a transition drawn uniformly from the same one to its episode's last stored one."""
        geo = self.geometry
        n = len(rows)
        draw = rng.random(n)
        where = rng.random(n)
        chosen = np.zeros(n, dtype=bool)
        goals = np.zeros((n, 2))
        if geo is None:
            return chosen, goals
        positions = buffer.episode_pos[rows]
        for b, lst in enumerate(lists):
            if lst is None or draw[b] >= self.her_ratio or not buffer.goal_ok[rows[b]]:
                continue
            pos = int(positions[b])
            j = lst[pos + int(where[b] * (len(lst) - pos))]
            chosen[b] = True
            goals[b] = buffer.next_obs[j, geo.position]
        return chosen, goals

    def batch(self, buffer: ReplayBuffer, rows: np.ndarray, rng: np.random.Generator) -> Batch:
        """The batch of ``rows`` (drawn by ``buffer.sample_rows``) with hindsight targets and n-step returns."""
        chains, lists = self.chains(buffer, rows)
        chosen, goals = self.goals(buffer, rows, lists, rng) if self.her_ratio > 0 else (None, None)
        n = len(rows)
        ret = np.zeros(n)
        alive = np.ones(n, dtype=bool)
        last_next = np.zeros((n, buffer.obs.shape[1]), dtype=np.float32)
        last_term = np.zeros(n, dtype=np.float32)
        steps = np.zeros(n, dtype=np.int64)
        first_obs = buffer.obs[rows].copy()
        for k in range(self.n_step):
            rk = chains[:, k]
            live = alive & (rk >= 0)
            if not live.any():
                break
            r_k = np.where(live, rk, rows)  # (a stand-in row where the chain has ended: masked out below)
            obs, next_obs = buffer.obs[r_k], buffer.next_obs[r_k]
            reward, term = buffer.reward[r_k].astype(np.float64), buffer.terminated[r_k].copy()
            if chosen is not None and chosen.any():
                sel = chosen & live & (buffer.goal_ok[r_k] > 0)
                if sel.any():
                    o, no, rw, tm = relabel(
                        self.geometry,
                        obs[sel],
                        next_obs[sel],
                        buffer.reward[r_k[sel]],
                        buffer.reached[r_k[sel]],
                        buffer.failed[r_k[sel]],
                        goals[sel],
                    )
                    next_obs = next_obs.copy()
                    next_obs[sel], reward[sel], term[sel] = no, rw, tm
                    if k == 0:
                        first_obs[sel] = o
            ret += np.where(live, self._powers[k] * reward, 0.0)
            last_next[live] = next_obs[live]
            last_term[live] = term[live]
            steps[live] = k + 1
            alive = live & (term == 0)
        t = torch.from_numpy
        discount = None if self.n_step == 1 else t(self._powers[steps].astype(np.float32))
        return Batch(
            obs=t(first_obs),
            action=t(buffer.action[rows]),
            reward=t(ret.astype(np.float32)),
            next_obs=t(last_next),
            terminated=t(last_term),
            demo=t((rows < buffer.n_demo).astype(np.float32)),
            expert_action=t(buffer.expert_action[rows]),
            labelled=t(buffer.labelled[rows]),
            discount=discount,
        )
