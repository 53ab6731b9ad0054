"""The ``planner`` regime's teacher: a planner that reads only the observation (``Navigate.observed_view``), in
agreement with the task's privileged view wherever the observation holds the same facts."""

from __future__ import annotations

import numpy as np
import pytest

import deck_sim
from deck_sim.policies import ScriptedPolicy
from deck_sim.rollout import run_episode

FOOTPRINTS = {"episode__static_size": True, "episode__mover_size": True, "episode__obstacle_shape": True}


def _stepped(frame: str = "world", predicted_frame: str = "agent", steps: int = 6):
    env = deck_sim.load("deck1", seed=3, episode__predictor="constant_velocity", episode__frame=frame,
                        episode__predicted_frame=predicted_frame, **FOOTPRINTS)
    env.reset()
    for _ in range(steps):
        env.step(np.array([0.6, 0.1]))
    return env


@pytest.mark.parametrize(("frame", "predicted_frame"), [("world", "agent"), ("agent", "mover")])
def test_the_observed_view_holds_the_privileged_facts_in_any_frame(frame, predicted_frame):
    env = _stepped(frame, predicted_frame)
    task = env.task
    full, seen = task.planner_view(), task.observed_view()
    assert np.allclose(seen.agent_xy, full.agent_xy) and np.isclose(seen.agent_yaw, full.agent_yaw)
    assert np.allclose(seen.target_xy, full.target_xy)
    assert abs(seen.agent_speed - full.agent_speed) < 0.05  # planar velocity along the heading; the wheels slip
    # obstacles come nearest first: match them to the privileged ones by position
    for mine, true in ((seen.statics, full.statics), (seen.movers, full.movers)):
        order = [int(np.argmin(np.linalg.norm(true.centers - c, axis=1))) for c in mine.centers]
        assert sorted(order) == list(range(len(true)))
        assert np.allclose(mine.centers, true.centers[order])
        # the observed rectangle contains the true rounded one: never nearer to a point outside than the truth
        rng = np.random.default_rng(0)
        points = mine.centers[:, None] + rng.uniform(-25, 25, (len(mine), 40, 2))
        for k, j in enumerate(order):
            d_seen = mine.distance(points[k])[:, k]
            d_true = true.distance(points[k])[:, j]
            assert np.all(d_seen <= d_true + 1e-9)
            assert np.all(d_seen >= d_true - 0.42 * true.radius[j] - 1e-9)  # at most the rounding's corners
    order = [int(np.argmin(np.linalg.norm(full.movers.centers - c, axis=1))) for c in seen.movers.centers]
    assert np.allclose(seen.mover_future, full.mover_future[order])


def test_without_the_forecast_every_mover_stands_where_it_is():
    task = _stepped().task
    seen = task.observed_view(forecast=False)
    assert np.allclose(seen.mover_future, seen.movers.centers[:, None].repeat(seen.mover_future.shape[1], axis=1))


def test_a_planner_on_the_observation_needs_the_footprints_in_it():
    env = deck_sim.load("deck1", seed=3, episode__mover_size=True)
    env.reset()
    with pytest.raises(ValueError, match=r"turn on episode\.static_size, episode\.obstacle_shape"):
        env.task.observed_view()
    with pytest.raises(ValueError, match="view: expected one of"):
        ScriptedPolicy(env, view="everything")


def test_the_scripted_planner_on_the_observation_reaches_targets():
    env = deck_sim.load("deck1", seed=7, episode__predictor="constant_velocity", **FOOTPRINTS)
    policy = ScriptedPolicy(env, view="observation")
    outcomes = [run_episode(env, policy, episode=k).outcome for k in range(3)]
    assert outcomes.count("goal") >= 2, outcomes
