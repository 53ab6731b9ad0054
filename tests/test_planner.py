"""The scripted full-knowledge planner on real physics: it reaches targets and yields to movers."""

import numpy as np
import pytest

import deck_sim
from deck_sim.policies import ScriptedPolicy, make_policy
from deck_sim.rollout import run_episode


def test_scripted_planner_reaches_the_target_on_an_empty_deck():
    env = deck_sim.load("deck1", seed=2, movers__tractors=0, movers__aircraft=0, movers__spots=[])
    policy = ScriptedPolicy(env)
    results = [run_episode(env, policy, k) for k in range(3)]
    assert [r.outcome for r in results] == ["goal"] * 3
    for r in results:
        assert r.path_length >= r.start_target_distance - 2 * env.task.spec.agent.goal_radius


@pytest.mark.slow
def test_scripted_planner_beats_going_straight_on_deck1():
    scripted_env = deck_sim.load("deck1", seed=21, episode__predictor="oracle")
    scripted = [run_episode(scripted_env, ScriptedPolicy(scripted_env), k).outcome for k in range(4)]
    straight_env = deck_sim.load("deck1", seed=21, episode__predictor="oracle")

    class Straight:
        def reset(self):
            pass

        def act(self, obs):
            return obs["target"] / max(np.linalg.norm(obs["target"]), 1e-9)

    straight = [run_episode(straight_env, Straight(), k).outcome for k in range(4)]
    assert scripted.count("goal") >= 3
    assert scripted.count("goal") > straight.count("goal")


def test_unknown_policy_is_named():
    env = deck_sim.load("deck1", seed=0)
    try:
        make_policy("telepathic", env)
    except ValueError as err:
        assert "unknown policy 'telepathic'" in str(err)
    else:
        raise AssertionError("no error")


def test_the_planner_view_carries_the_aircraft_body_and_limits_and_none_for_a_walker():
    deck = deck_sim.load("deck1", seed=0)
    deck.reset()
    view = deck.task.planner_view()
    assert view.agent_circles.shape == (4, 3) and view.agent_circles[0, 0] == 8.2  # the nose, 8.2 m ahead
    assert view.agent_limits is not None and abs(view.agent_limits.wheelbase - 5.4) < 1e-9
    square = deck_sim.load("square", seed=0)
    square.reset()
    walker = square.task.planner_view()
    assert walker.agent_circles.shape == (0, 3) and walker.agent_limits is None


@pytest.mark.slow
def test_the_trainer_teaches_with_the_body_planner_when_asked():
    from training.config import arm_config
    from training.runners import InlineEnvs

    cfg = arm_config("tuned-mddpg-with-body", "deck1", steps=1_000, seed=0)
    envs = InlineEnvs(2)
    envs.build(0, "deck1", "mpc", dict(cfg.scene_overrides), True, cfg.teacher_body)
    envs.build(1, "deck1", "mpc", {}, True)
    assert [e.planner.body for e in envs._envs.experts] == [True, False]
    envs.close()


def test_scripted_body_is_a_policy_name_with_the_oracle():
    from deck_sim.policies import policy_overrides

    env = deck_sim.load("deck1", seed=0)
    assert make_policy("scripted-body", env).planner.body and not make_policy("scripted", env).planner.body
    assert policy_overrides("scripted-body", "deck1") == {"episode__predictor": "oracle"}
