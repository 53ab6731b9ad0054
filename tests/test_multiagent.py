"""Several aircraft at once: the multi-agent scenes, the composer task and the PettingZoo ParallelEnv."""

from __future__ import annotations

import math

import numpy as np
import pytest

import deck_sim
from deck_sim.control.planners import ScriptedPlanner
from deck_sim.scenes import SceneSpecError, load_scene
from deck_sim.tasks.actions import InvalidActionError

pettingzoo = pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test, parallel_seed_test  # noqa: E402

from deck_sim.multiagent import parallel_env  # noqa: E402


@pytest.fixture(scope="module")
def env():
    e = deck_sim.load("deck1-multi", seed=3)
    yield e
    e.close()


def test_the_multi_scenes_are_deck_layouts_with_four_aircraft():
    for name, base in (("deck1-multi", "deck1"), ("deck2-multi", "deck2")):
        spec, single = load_scene(name), load_scene(base)
        assert spec.agents.count == 4 and spec.multi_agent and not single.multi_agent
        assert (spec.static.count, spec.movers.count) == (single.static.count, single.movers.count)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"agents__count": 0}, r"\[agents\]\.count: must be >= 1"),
        ({"agents__count": 9}, r"\[agents\]\.count: must be <= 8"),
        ({"agents__count": 3, "agent__start_sites": ["start_1", "start_2"]}, r"3 aircraft need 3 distinct"),
        ({"agents__count": 2, "episode__predictor": "oracle"}, r"\[agents\]\.count: the 'oracle' predictor"),
    ],
)
def test_a_bad_agent_count_is_named(overrides, message):
    with pytest.raises(SceneSpecError, match=message):
        load_scene("deck1-multi", **overrides)


def test_layouts_give_every_aircraft_its_own_spaced_start_and_target(env):
    task, spec = env.task, env.task.spec
    for seed in range(30):
        layout = task.sample_layout(np.random.default_rng(seed))
        k = spec.agents.count
        assert layout.agents_xy.shape == (k, 2) and layout.targets_xy.shape == (k, 2)
        assert len(set(layout.target_sites)) == k
        gaps = np.linalg.norm(layout.agents_xy[:, None] - layout.agents_xy[None], axis=-1) + np.eye(k) * 1e9
        assert gaps.min() > 2 * spec.agent.radius
        for start, target in zip(layout.agents_xy, layout.targets_xy, strict=True):
            assert spec.agent.min_target_distance <= np.linalg.norm(target - start) <= spec.agent.max_target_distance
        # no mover starts on an aircraft
        for xy in layout.mover_xy:
            assert np.linalg.norm(layout.agents_xy - xy, axis=1).min() > spec.agent.radius


def test_every_aircraft_observes_the_movers_then_the_other_aircraft(env):
    task = env.task
    ts = env.reset()
    k, n = task.n_agents, len(task.movers)
    assert task.agent_names == [f"aircraft_{i}" for i in range(k)]
    assert [s.name for s in env.action_spec()] == [f"aircraft_{i}: dx\tdy" for i in range(k)]
    assert env.reward_spec().shape == (k,) and env.discount_spec().shape == (k,)
    state = task.last_info["agents"]
    for i, name in enumerate(task.agent_names):
        dyn = ts.observation[f"{name}:dynamic_obstacles"]
        assert dyn.shape == (n + k - 1, 2)
        # the other aircraft are among the dynamic obstacles, relative to this one
        me = state[i]["position"]
        seen = {tuple(np.round(me + d, 6)) for d in dyn}
        for j in range(k):
            if j != i:
                assert tuple(np.round(state[j]["position"], 6)) in seen
        np.testing.assert_allclose(ts.observation[f"{name}:target"], state[i]["target"] - me)


def test_bad_actions_are_named_and_nothing_moves(env):
    env.reset()
    before = [a["position"].copy() for a in env.task.last_info["agents"]]
    t = env.physics.data.time
    good = np.zeros((4, 2))
    bad_nan = good.copy()
    bad_nan[2, 0] = math.nan
    with pytest.raises(InvalidActionError, match="aircraft_2: action must be finite"):
        env.step(bad_nan)
    with pytest.raises(InvalidActionError, match=r"one action per aircraft \(4"):
        env.step(np.zeros((3, 2)))
    with pytest.raises(InvalidActionError, match="got a dict"):
        env.step({"aircraft_0": [0, 0]})
    too_far = good.copy()
    too_far[1] = (1.5, 0.0)
    with pytest.raises(InvalidActionError, match="aircraft_1: action must lie in"):
        env.step(too_far)
    assert env.physics.data.time == t
    for a, xy in zip(env.task.last_info["agents"], before, strict=True):
        np.testing.assert_array_equal(a["position"], xy)


def test_two_aircraft_that_meet_both_collide_and_name_each_other():
    env = deck_sim.load("deck1-multi", seed=5, agents__count=2, movers__tractors=0, movers__aircraft=0)
    ts = env.reset()
    task = env.task
    for _ in range(200):
        a0, a1 = (info["position"] for info in task.last_info["agents"])
        toward = (a0 - a1) / max(np.linalg.norm(a0 - a1), 1e-9)
        ts = env.step([np.zeros(2), task.action_from_world(toward, 1)])  # aircraft_0 waits, aircraft_1 drives at it
        if ts.last():
            break
    agents = task.last_info["agents"]
    assert agents[0]["collision"] == "aircraft_1" and agents[1]["collision"] == "aircraft_0"
    assert agents[0]["done"] and agents[1]["done"] and not task.last_info["all_reached"]
    spec = task.spec
    assert np.all(ts.reward <= spec.reward.collision + 2 * spec.reward.attraction_max + 2 * spec.reward.repulsion_max)
    np.testing.assert_array_equal(ts.discount, [0.0, 0.0])
    env.close()


def test_an_aircraft_that_is_done_stands_braked_with_no_reward():
    env = deck_sim.load("deck1-multi", seed=7, agents__count=2, movers__tractors=0, movers__aircraft=0)
    env.reset()
    task = env.task
    planner = ScriptedPlanner(body=True)
    planner.reset()
    # aircraft_1 taxis to its target with the full-knowledge planner, aircraft_0 waits where it is
    for _ in range(300):
        ts = env.step([np.zeros(2), task.action_from_world(planner.act(task.planner_view(1)), 1)])
        if task.last_info["agents"][1]["done"]:
            break
    info = task.last_info["agents"][1]
    assert info["reached_goal"] and info["collision"] is None and ts.reward[1] > 100.0
    parked = info["position"].copy()
    for _ in range(12):
        ts = env.step([np.zeros(2), np.array([1.0, 1.0])])  # its action is ignored
        assert ts.reward[1] == 0.0 and ts.discount[1] == 0.0 and ts.discount[0] == 1.0 and not ts.last()
    # it brakes to a stop from its arrival speed and stays
    assert np.linalg.norm(task.last_info["agents"][1]["position"] - parked) < 6.0
    assert abs(task.last_info["agents"][1]["speed"]) < 0.05
    assert task.last_info["agents"][1]["done_time"] < task.last_info["time"]
    env.close()


def test_the_parallel_env_passes_pettingzoo_api_and_seed_tests():
    env = parallel_env(seed=0)
    assert env.possible_agents == ["aircraft_0", "aircraft_1", "aircraft_2", "aircraft_3"]
    parallel_api_test(env, num_cycles=40)
    parallel_seed_test(lambda: parallel_env(seed=0), num_cycles=20)
    env.close()


def test_the_parallel_env_names_what_is_wrong_with_an_action_dict():
    env = parallel_env(seed=1, agents__count=2)
    env.reset(seed=4)
    with pytest.raises(InvalidActionError, match=r"lack an action for \['aircraft_1'\]"):
        env.step({"aircraft_0": np.zeros(2)})
    with pytest.raises(InvalidActionError, match="unknown aircraft.*aircraft_7"):
        env.step({"aircraft_0": np.zeros(2), "aircraft_1": np.zeros(2), "aircraft_7": np.zeros(2)})
    with pytest.raises(InvalidActionError, match="aircraft_1: action must be finite"):
        env.step({"aircraft_0": np.zeros(2), "aircraft_1": np.array([0.0, math.nan])})
    obs, rewards, terms, truncs, infos = env.step({"aircraft_0": np.zeros(2), "aircraft_1": np.zeros(2)})
    assert set(obs) == set(rewards) == set(terms) == set(truncs) == set(infos) == {"aircraft_0", "aircraft_1"}
    assert all(o.dtype == np.float32 and o.shape == env.observation_space(a).shape for a, o in obs.items())
    env.close()
    with pytest.raises(ValueError, match="has one agent"):
        parallel_env(scene="deck1")
