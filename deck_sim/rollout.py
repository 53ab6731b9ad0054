"""Run episodes of a composer environment with a policy and measure them."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from dm_control import composer

from deck_sim.metrics import EpisodeResult, outcome_of, path_length, turning_angle
from deck_sim.policies import Policy

StepCallback = Callable[[composer.Environment, object, np.ndarray | None], None]


def run_episode(
    env: composer.Environment, policy: Policy, episode: int = 0, on_step: StepCallback | None = None
) -> EpisodeResult:
    """Play one episode from ``env.reset()`` to its end and measure it.

    Args:
        on_step: called after the reset and after every step with (env, timestep, action or None).
    """
    ts = env.reset()
    policy.reset()
    task = env.task
    start = task.last_info["position"].copy()
    positions = [start]
    total = 0.0
    min_clear = task.last_info["min_clearance"]
    fallbacks = 0
    if on_step is not None:
        on_step(env, ts, None)
    steps = 0
    while not ts.last():
        action = np.asarray(policy.act(ts.observation), dtype=np.float64)
        ts = env.step(action)
        steps += 1
        info = task.last_info
        positions.append(info["position"].copy())
        total += float(ts.reward)
        min_clear = min(min_clear, info["min_clearance"])
        fallbacks += info["predictor_fallbacks"]
        if on_step is not None:
            on_step(env, ts, action)
    info = task.last_info
    truncated = ts.discount is not None and ts.discount > 0 and not info["reached_goal"]
    xy = np.array(positions)
    return EpisodeResult(
        scene=task.spec.name,
        episode=episode,
        outcome=outcome_of(info, truncated),
        steps=steps,
        sim_time=float(info["time"]),
        reward=total,
        path_length=path_length(xy),
        start_target_distance=float(np.linalg.norm(task.layout.target_xy - start)),
        turning_angle_deg=float(np.degrees(turning_angle(xy))),
        min_clearance=float(min_clear),
        collision_partner=info["collision"],
        predictor_fallbacks=int(fallbacks),
    )
