"""The scripted full-knowledge planner on real physics: it reaches targets and yields to movers."""

import numpy as np

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
