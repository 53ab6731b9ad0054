"""The APF-shaped reward of the paper (Section II.E, eq. 10-16), as pure functions (numpy only).

r1 (target attraction): progress d = D_target(t) - D_target(t+1); approaching gives clip(d, l, L), moving away
clip(d, -L, -l); so every step's attraction has a magnitude between l and L with the sign of the progress.
r2 (obstacle repulsion): same shape with bounds h, H on the change of clearance to the nearest obstacle within
the influence radius. **Sign decision** (paper.md): the printed formula rewards approaching an obstacle, which
contradicts "repulsion"; here d = D_obs(t+1) - D_obs(t), so moving away is rewarded and closing in penalised.
With a look-ahead (``lookahead_clearances``) a mover's clearance in r2 is lowered by how much nearer its centre
comes at its closest point of approach over the next few steps of a forecast. r3 on collision, r4 on reaching
the target; R = w1 r1 + w2 r2 + w3 r3 + w4 r4 (eq. 16).
A dead band on |d| (``progress_deadband``) keeps numerical jitter of a standing vehicle from earning +l or -l.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from deck_sim.tasks.observation import closest_approach


def shaped(change: float, lo: float, hi: float, deadband: float) -> float:
    """The paper's clipped shaping: sign of ``change``, magnitude clipped to [lo, hi]; 0 inside the dead band."""
    if not math.isfinite(change):  # (math, not numpy: this runs twice a control step on one float)
        raise ValueError(f"reward shaping got a non-finite change {change!r}")
    if abs(change) < deadband:
        return 0.0
    if change >= 0:  # the paper's d >= 0 branch
        return float(min(max(change, lo), hi))
    return float(max(min(change, -lo), -hi))


def attraction(dist_before: float, dist_after: float, lo: float, hi: float, deadband: float) -> float:
    """r1: positive when the distance to the target shrank (metres)."""
    return shaped(dist_before - dist_after, lo, hi, deadband)


def repulsion(
    clearances_before: np.ndarray,
    clearances_after: np.ndarray,
    influence_radius: float,
    lo: float,
    hi: float,
    deadband: float,
) -> float:
    """r2 for the obstacle nearest after the step, if within ``influence_radius`` (metres of clearance).

    Args:
        clearances_before, clearances_after: (k,) clearance to each obstacle before and after the step.
    """
    if len(clearances_after) == 0:
        return 0.0
    j = int(np.argmin(clearances_after))
    if clearances_after[j] >= influence_radius:
        return 0.0
    return shaped(float(clearances_after[j] - clearances_before[j]), lo, hi, deadband)


def lookahead_clearances(
    clearances: np.ndarray,
    agent_xy: np.ndarray,
    agent_velocity: np.ndarray,
    mover_xy: np.ndarray,
    forecast: np.ndarray,
    dt: float,
) -> np.ndarray:
    """The movers' clearances that r2 reads with a look-ahead (scene field ``reward.lookahead_steps``), metres.

    Each mover's clearance now, less how much nearer its centre comes to the agent's over the forecast's K steps
    (the agent carried on at ``agent_velocity``, the mover along ``forecast``): the closest point of approach within
    K steps, measured between centres and counted against the footprint clearance now, never more than now.

    Args:
        clearances: (n,) each mover's clearance now, metres.
        agent_xy, agent_velocity: (2,) the agent's position (metres) and planar velocity (m/s).
        mover_xy: (n, 2) the movers' positions now, metres.
        forecast: (n, K, 2) the movers' forecast positions, one every ``dt`` seconds from now, metres.
    """
    now = mover_xy - agent_xy
    nearest = closest_approach(now, forecast - agent_xy, agent_velocity, dt)[:, 1]  # (now included: never more)
    return clearances + (nearest - np.sqrt(np.einsum("ij,ij->i", now, now)))


@dataclass(frozen=True)
class RewardTerms:
    """The reward's terms for one step and their weighted sum."""

    r1: float
    r2: float
    r3: float
    r4: float
    total: float

    def as_dict(self) -> dict[str, float]:
        """Terms by name."""
        return {"r1": self.r1, "r2": self.r2, "r3": self.r3, "r4": self.r4, "total": self.total}


def total_reward(
    r1: float,
    r2: float,
    collided: bool,
    reached: bool,
    collision_reward: float,
    goal_reward: float,
    weights: tuple[float, float, float, float],
) -> RewardTerms:
    """Eq. 16: weighted sum of attraction, repulsion, collision and goal terms."""
    r3 = collision_reward if collided else 0.0
    r4 = goal_reward if reached else 0.0
    w1, w2, w3, w4 = weights
    return RewardTerms(r1, r2, r3, r4, w1 * r1 + w2 * r2 + w3 * r3 + w4 * r4)
