"""Several aircraft at once: the multi-agent scenes, the composer task and the PettingZoo ParallelEnv."""

from __future__ import annotations

import math

import numpy as np
import pytest

import deck_sim
from deck_sim.control.planners import ScriptedPlanner
from deck_sim.metrics import summarize_team
from deck_sim.policies import PrioritisedPolicy
from deck_sim.recording import EpisodeLog
from deck_sim.rollout import run_team_episode
from deck_sim.scenes import SceneSpecError, load_scene
from deck_sim.tasks.actions import InvalidActionError
from deck_sim.tasks.multi import HANGAR_SPACING, HANGAR_X

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


def test_an_aircraft_that_is_done_leaves_the_deck_for_its_stand_with_no_reward():
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
    assert np.linalg.norm(info["done_position"] - info["target"]) <= task.spec.agent.goal_radius
    stand = np.array([HANGAR_X - HANGAR_SPACING, 0.0])
    # from the step it left, it is predicted to stand on its stand (its history is replaced, not a jump)
    np.testing.assert_allclose(task.last_info["prediction"][-1], np.repeat(stand[None], 10, 0), atol=0.5)
    for _ in range(6):
        ts = env.step([np.zeros(2), np.array([1.0, 1.0])])  # its action is ignored
        assert ts.reward[1] == 0.0 and ts.discount[1] == 0.0 and ts.discount[0] == 1.0 and not ts.last()
        assert np.linalg.norm(task.last_info["agents"][1]["position"] - stand) < 0.5  # at rest on its stand
    assert abs(task.last_info["agents"][1]["speed"]) < 0.05
    # aircraft_0 still sees it, far behind the stern, as its last dynamic obstacle
    obs = task.observation_of(0)
    me = task.last_info["agents"][0]["position"]
    np.testing.assert_allclose(me + obs["dynamic_obstacles"][-1], task.last_info["agents"][1]["position"], atol=1e-9)
    env.close()


def test_prioritised_planning_brings_four_aircraft_to_their_targets():
    env = deck_sim.load("deck1-multi", seed=None)
    env.random_state.seed(100000)
    result = run_team_episode(env, PrioritisedPolicy(env))
    assert result.all_reached and result.aircraft_collisions == 0
    assert [r.outcome for r in result.aircraft] == ["goal"] * 4
    assert result.makespan == max(r.sim_time for r in result.aircraft) <= env.task.spec.episode.time_limit
    for r, shortest in zip(result.aircraft, result.shortest, strict=True):
        assert shortest <= r.path_length <= 1.5 * shortest + 10.0
    summary = summarize_team([result])
    assert summary["goal_rate"] == summary["all_reached_rate"] == 1.0
    assert summary["path_sum_ratio"] >= 1.0
    env.close()


class _RamIntoAircraft0:
    """aircraft_0 waits, aircraft_1 drives straight at it."""

    def __init__(self, env) -> None:
        self.env = env

    def reset(self) -> None:
        pass

    def act(self, observation):
        a0, a1 = (info["position"] for info in self.env.task.last_info["agents"])
        toward = (a0 - a1) / max(np.linalg.norm(a0 - a1), 1e-9)
        return np.stack([np.zeros(2), self.env.task.action_from_world(toward, 1)])


def test_two_aircraft_that_meet_both_collide_name_each_other_and_count_once():
    env = deck_sim.load("deck1-multi", seed=5, agents__count=2, movers__tractors=0, movers__aircraft=0)
    last = []
    result = run_team_episode(env, _RamIntoAircraft0(env), on_step=lambda env, ts, actions: last.append(ts))
    spec = env.task.spec
    assert np.all(last[-1].reward <= spec.reward.collision + spec.reward.attraction_max + spec.reward.repulsion_max)
    np.testing.assert_array_equal(last[-1].discount, [0.0, 0.0])
    assert [r.outcome for r in result.aircraft] == ["collision", "collision"]
    assert [r.collision_partner for r in result.aircraft] == ["aircraft_1", "aircraft_0"]
    assert result.aircraft_collisions == 1 and math.isnan(result.makespan) and not result.all_reached
    summary = summarize_team([result])
    assert summary["collision_rate"] == 1.0 and summary["aircraft_collisions_per_episode"] == 1.0
    assert math.isnan(summary["path_sum_ratio"]) and summary["all_reached_rate"] == 0.0
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


def test_the_readme_example_runs_an_episode_to_its_end():
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = [b for b in re.findall(r"```python\n(.*?)```", readme, flags=re.S) if "parallel_env" in b]
    assert len(blocks) == 1
    scope: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), scope)  # noqa: S102 - the README's own example
    env = scope["env"]
    assert env.agents == [] and set(scope["terminations"]) | set(scope["truncations"])
    env.close()


def test_a_shipped_single_agent_actor_acts_for_every_aircraft_on_its_nearest_movers():
    from deck_sim.policies import SharedPolicy, make_policy, nearest_dynamic, policy_overrides

    overrides = policy_overrides("mddpg", "deck1")
    single = deck_sim.load("deck1", seed=0, **overrides)
    actor = make_policy("mddpg", single)
    single.close()
    env = deck_sim.load("deck1-multi", seed=2, **overrides)
    team = SharedPolicy(actor, env)
    assert team.dynamic == 5  # trained on deck 1's 5 movers; each aircraft sees 5 + 3
    ts = env.reset()
    actions = team.act(ts.observation)
    assert actions.shape == (4, 2) and np.all(np.abs(actions) <= 1.0)
    own = {k.split(":", 1)[1]: v for k, v in ts.observation.items() if k.startswith("aircraft_2:")}
    np.testing.assert_array_equal(actions[2], actor.act(nearest_dynamic(own, 5)))
    cut = nearest_dynamic(own, 5)
    assert cut["dynamic_obstacles"].shape == (5, 2) and cut["predicted"].shape[0] == 5
    np.testing.assert_array_equal(cut["dynamic_obstacles"], own["dynamic_obstacles"][:5])
    np.testing.assert_array_equal(cut["static_obstacles"], own["static_obstacles"])
    env.close()
    with pytest.raises(ValueError, match="has one agent"):
        SharedPolicy(actor, deck_sim.load("deck1", seed=0))


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["render", "--scene", "deck2-multi", "--policy", "zero", "--out", "never.mp4"],
         "deck-sim render acts for one"),
        (["eval", "--agents", "zero,scripted", "--scenes", "deck1,deck2-multi", "--episodes", "1"],
         "agents ['scripted'] plan for one"),
        (["eval", "--agents", "prioritised", "--scenes", "deck1", "--episodes", "1"],
         "agents ['prioritised'] plan for several aircraft; scene 'deck1' has one"),
    ],
)
def test_what_acts_for_one_aircraft_refuses_several_by_name(argv, named, capsys, tmp_path, monkeypatch):
    from deck_sim.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert named in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.slow
def test_the_evaluation_counts_aircraft_and_episodes_on_a_multi_aircraft_scene(tmp_path):
    import csv

    from deck_sim.evaluation import EvalConfig, evaluate, write_report

    cfg = EvalConfig(agents=("prioritised", "mddpg"), scenes=("deck1-multi",), episodes=2, backend="serial",
                     record="1", out=str(tmp_path))
    res = evaluate(cfg)
    write_report(res, tmp_path)
    rows = list(csv.DictReader(open(tmp_path / "episodes.csv", newline="")))
    assert [(r["agent"], r["episode"], r["aircraft"]) for r in rows][:5] == [
        ("prioritised", "0", "aircraft_0"), ("prioritised", "0", "aircraft_1"), ("prioritised", "0", "aircraft_2"),
        ("prioritised", "0", "aircraft_3"), ("prioritised", "1", "aircraft_0"),
    ]
    for agent in ("prioritised", "mddpg"):
        mine = [r for r in rows if r["agent"] == agent]
        s = res.summary("deck1-multi", agent)
        assert (s["episodes"], s["aircraft"]) == (2, 8)
        assert s["goal_rate"] == sum(r["outcome"] == "goal" for r in mine) / 8
        arrived = sum(all(r["outcome"] == "goal" for r in mine if r["episode"] == e) for e in ("0", "1"))
        assert s["all_reached_rate"] == arrived / 2
    text = (tmp_path / "results.md").read_text()
    assert "**Several aircraft**" in text and "| prioritised | deck1-multi | 2 | 8 |" in text
    log = EpisodeLog(tmp_path / "logs" / "deck1-multi-mddpg-0000.mcap")
    assert log.episodes[0].team


def test_deck_sim_run_acts_for_every_aircraft_and_tables_aircraft_and_teams(tmp_path, capsys):
    import csv
    import json

    from deck_sim.cli import main

    out = tmp_path / "run"
    argv = ["run", "--scene", "deck1", "--scene-set", "agents.count=2", "--policy", "prioritised", "--episodes", "2",
            "--seed", "5", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "episodes all arrived" in printed and "aircraft-aircraft collisions / episode" in printed
    with open(out / "episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["aircraft"], r["episode"]) for r in rows] == [
        ("aircraft_0", "0"), ("aircraft_1", "0"), ("aircraft_0", "1"), ("aircraft_1", "1")
    ]
    summary = json.loads((out / "summary.json").read_text())["summary"]
    assert summary["aircraft"] == 4 and summary["episodes"] == 2
    assert summary["goal_rate"] == sum(r["outcome"] == "goal" for r in rows) / 4
    episodes = {r["episode"] for r in rows}
    all_in = sum(all(r["outcome"] == "goal" for r in rows if r["episode"] == e) for e in episodes)
    assert summary["all_reached_rate"] == all_in / 2
    # the same episodes again: the same table
    assert main([*argv[:-3], "--out", str(tmp_path / "again"), "--quiet"]) == 0
    assert (tmp_path / "again" / "episodes.csv").read_text() == (out / "episodes.csv").read_text()


def test_a_shared_learned_policy_says_where_its_actor_was_trained(tmp_path, capsys):
    from deck_sim.cli import main

    argv = ["run", "--scene", "deck1", "--scene-set", "agents.count=2", "--policy", "mddpg", "--episodes", "1",
            "--out", str(tmp_path / "run"), "--quiet"]
    assert main(argv) == 0
    assert "an actor trained on deck1, acting for every aircraft" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--policy", "scripted"], "prioritised, independent"),
        (["--policy", "nope"], "cannot act for the aircraft of scene 'deck1-multi'"),
    ],
)
def test_deck_sim_run_refuses_what_several_aircraft_cannot_take(extra, named, tmp_path, capsys, monkeypatch):
    from deck_sim.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["run", "--scene", "deck1-multi", "--episodes", "1", *extra]) == 2
    assert named in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing written


def test_the_gymnasium_environment_points_a_multi_aircraft_scene_to_pettingzoo():
    from deck_sim.wrappers import DeckSimEnv

    with pytest.raises(ValueError, match="deck_sim.multiagent.parallel_env"):
        DeckSimEnv(scene="deck1-multi")


@pytest.mark.parametrize(("scene", "count"), [("deck1-multi", k) for k in range(2, 9)] + [("deck2-multi", 8)])
def test_every_aircraft_count_gets_a_layout(scene, count):
    env = deck_sim.load(scene, seed=0, agents__count=count)
    task, spec = env.task, env.task.spec
    for seed in range(5):
        layout = task.sample_layout(np.random.default_rng(seed))
        assert len(layout.agents_xy) == len(set(layout.target_sites)) == count
        gaps = np.linalg.norm(layout.agents_xy[:, None] - layout.agents_xy[None], axis=-1) + np.eye(count) * 1e9
        assert gaps.min() > 2 * spec.agent.radius
    env.reset()
    assert env.task.get_reward(env.physics).shape == (count,) and len(env.action_spec()) == count
    env.close()


def test_each_aircraft_has_its_own_observed_view():
    observed = {"episode__static_size": True, "episode__mover_size": True, "episode__obstacle_shape": True}
    env = deck_sim.load("deck1-multi", seed=4, **observed)
    env.reset()
    task = env.task
    for i in range(task.n_agents):
        view, full = task.observed_view(agent=i), task.planner_view(i)
        np.testing.assert_allclose(view.agent_xy, full.agent_xy, atol=1e-5)
        np.testing.assert_allclose(view.target_xy, full.target_xy, atol=1e-4)
        assert len(view.movers) == len(full.movers)  # the movers, then the other aircraft
    with pytest.raises(ValueError, match="aircraft 0-3, no aircraft 4"):
        task.observed_view(agent=4)
    from deck_sim.policies import IndependentPolicy

    actions = IndependentPolicy(env, view="observation").act({})
    assert actions.shape == (4, 2) and np.all(np.abs(actions) <= 1.0)
    with pytest.raises(ValueError, match="has one aircraft, no aircraft 1"):
        deck_sim.load("deck1", seed=0, **observed).task.observed_view(agent=1)
