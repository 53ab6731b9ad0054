"""Shared-parameter training of several aircraft (``training.team``): one buffer holds every taxiing aircraft's
transitions and nothing of an aircraft that is done, a stopped and resumed run equals an unbroken one, the exported
actor acts for every aircraft, the regimes are named as for one aircraft, and what several aircraft cannot take
is refused by name."""

from __future__ import annotations

import pytest
from conftest import short_config as _short
from training_runs import assert_same_run

import deck_sim
from deck_sim.policies import LearnedPolicy, SharedPolicy
from deck_sim.rollout import run_team_episode
from training.config import ConfigError
from training.loop import Trainer
from training.team import TeamTrainer, make_trainer


def _team(**fields):  # noqa: ANN003, ANN201
    """A seconds-long shared run on deck1-multi with two aircraft (two environments), ``fields`` on top."""
    base = dict(scene="deck1-multi", scene_overrides={"agents__count": 2}, total_steps=160, demo_episodes=0,
                pretrain_updates=0, learning_starts=40)
    base.update(fields)
    return _short(**base)


def _crowded(**fields):  # noqa: ANN003, ANN201
    """Two environments of four aircraft acting at random for their first 120 of 480 transitions, in 20 s episodes (seed
    2): some aircraft collide while the others taxi on, and episodes end and start again within the run."""
    base = dict(scene_overrides={"agents__count": 4, "episode__time_limit": 20.0}, total_steps=480, seed=2,
                learning_starts=120)
    base.update(fields)
    return _team(**base)


@pytest.mark.slow
def test_every_taxiing_aircraft_and_no_done_one_gives_a_transition(tmp_path):
    trainer = make_trainer(_crowded(), tmp_path / "run", progress=False)
    assert isinstance(trainer, TeamTrainer) and trainer.k == 4
    trainer.train(stop_at=1)  # the run's start and its first step
    taxiing = [trainer.step]
    while trainer.step < 480:
        taxiing.append(sum(int(s.live.sum()) for s in trainer.slots))
        before = trainer.buffer.size
        trainer.collect()
        assert trainer.buffer.size - before == taxiing[-1] == trainer.collected
    assert trainer.step == trainer.buffer.size == sum(taxiing)
    assert max(taxiing) == 8 and min(taxiing) < 8  # two environments of four, some done before their episode's end
    terminated = trainer.buffer.terminated[: trainer.buffer.size]
    # every aircraft done before the time limit ends with one terminal transition; the time limit ends none
    done = sum(r[0] != "timeout" for r in trainer.stats.recent)
    assert terminated.sum() == done > 0
    assert trainer.stats.episodes == 8 and all(s.episode == 1 for s in trainer.slots)  # each ended and began anew
    labels = trainer.buffer.labelled[: trainer.buffer.size]
    assert labels.all()  # the tuned recipe: the prioritised planner labels every aircraft's step
    trainer.close()


@pytest.mark.slow
def test_a_stopped_and_resumed_team_run_equals_an_unbroken_one(tmp_path):
    whole = TeamTrainer(_crowded(), tmp_path / "whole", progress=False)
    whole.train()
    first = TeamTrainer(_crowded(), tmp_path / "broken", progress=False)
    first.train(stop_at=100)
    # stopped inside an episode in which some aircraft are done and others taxi on
    assert any(0 < s.live.sum() < 4 and len(s.actions) > 0 for s in first.slots)
    first.close()
    resumed = TeamTrainer(_crowded(), tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
    whole.close()
    resumed.close()


@pytest.mark.slow
def test_the_shared_actor_records_its_regime_and_acts_for_every_aircraft(tmp_path):
    cfg = _team(algo="ddpg", total_steps=80, demo_episodes=1, pretrain_updates=5,
                eval_every=80, eval_episodes=1)
    trainer = TeamTrainer(cfg, tmp_path / "run", progress=False)
    out = trainer.train()
    trainer.close()
    assert out["demonstrations"]["transitions"] > 0
    policy = LearnedPolicy.load(tmp_path / "run" / "actor.npz")
    assert policy.meta["regime"] == "oracle-teacher" and policy.meta["scene"] == "deck1-multi"
    assert "predicted" not in policy.meta["observation_keys"]  # DDPG: taught on the forecasts it does not see
    env = deck_sim.load("deck1-multi", seed=3, agents__count=2, episode__predictor="none")
    result = run_team_episode(env, SharedPolicy(policy, env))
    assert len(result.aircraft) == 2
    rows = (tmp_path / "run" / "eval.csv").read_text().splitlines()
    assert rows[0].startswith("step,") and len(rows) >= 2


@pytest.mark.slow
def test_the_planner_regime_teaches_each_aircraft_from_its_own_observation(tmp_path):
    from deck_sim.policies import IndependentPolicy

    observed = {"agents__count": 2, "episode__static_size": True, "episode__mover_size": True,
                "episode__obstacle_shape": True}
    fields = dict(teacher_view="observation", scene_overrides=observed, total_steps=60, demo_episodes=1,
                  pretrain_updates=5)
    ddpg = TeamTrainer(_team(algo="ddpg", **fields), tmp_path / "ddpg", progress=False)
    assert ddpg.envs.teachers[0].view == "observation-without-forecast"  # DDPG's teacher sees no forecast either
    ddpg.close()
    cfg = _team(algo="mddpg", **fields)
    assert cfg.regime == "planner"
    trainer = TeamTrainer(cfg, tmp_path / "run", progress=False)
    teacher = trainer.envs.teachers[0]
    assert isinstance(teacher, IndependentPolicy) and teacher.view == "observation"
    out = trainer.train()
    trainer.close()
    assert out["demonstrations"]["transitions"] > 0
    assert trainer.buffer.labelled[: trainer.buffer.size].all()
    assert LearnedPolicy.load(tmp_path / "run" / "actor.npz").meta["regime"] == "planner"


def test_reward_regime_team_configs_name_their_regime():
    assert _team(demo_episodes=0, expert_relabel=False, bc_weight=0.0, pretrain_updates=0).regime == "reward"
    assert _team().regime == "oracle-teacher"


@pytest.mark.parametrize(
    ("fields", "kwargs", "named"),
    [
        ({"scene": "deck1", "scene_overrides": {}}, {}, "has one aircraft"),
        ({"curriculum": ({"until": 0.5, "max_target_distance": 30.0, "movers": 1},)}, {}, "curriculum"),
        ({"her_ratio": 0.5}, {}, "hindsight"),
        ({"n_step": 3}, {}, "n-step"),
        ({}, {"backend": "ray"}, "--backend ray"),
        ({}, {"workers": 1}, "--workers"),
    ],
)
def test_what_several_aircraft_cannot_take_is_refused_by_name(tmp_path, fields, kwargs, named):
    with pytest.raises(ConfigError, match=named):
        TeamTrainer(_team(**fields), tmp_path / "run", progress=False, **kwargs)
    assert not (tmp_path / "run").exists()  # nothing written


def test_the_single_aircraft_loop_refuses_a_scene_of_several_before_writing(tmp_path):
    with pytest.raises(ConfigError, match="puts several aircraft on the deck: train it with training.team.TeamTrainer"):
        Trainer(_team(), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_make_trainer_keeps_one_aircraft_on_the_single_agent_loop(tmp_path):
    trainer = make_trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), tmp_path / "run",
                           progress=False)
    assert type(trainer) is Trainer
    trainer.close()
