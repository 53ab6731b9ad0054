"""Training regimes: what every learned agent learnt from, named the same way in configs, actor files, ``deck-sim run``
and the results tables."""

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.agents import AGENTS, LEARNED
from deck_sim.cli import main
from deck_sim.policies import TRAINED_DIR, load_actor
from deck_sim.policies.regimes import (
    REGIMES,
    TEACHING_FIELDS,
    actor_regime,
    config_regime,
    regime_text,
)

FIELD_VALUES = {
    "demo_episodes": st.integers(0, 3),
    "expert_relabel": st.booleans(),
    "bc_weight": st.sampled_from([0.0, 0.5, 20.0]),
    "pretrain_updates": st.integers(0, 3),
    "polish_epochs": st.integers(0, 3),
    "dagger_steps": st.integers(0, 3),
}


@given(st.fixed_dictionaries(FIELD_VALUES))
def test_a_config_learns_from_the_reward_alone_exactly_when_no_teaching_field_is_on(fields):
    regime = config_regime({**fields, "num_envs": 8, "twin_critics": True, "her_ratio": 0.8})
    if any(fields.values()):
        assert regime == "oracle-teacher"
    else:
        assert regime == "reward"


def test_the_default_and_the_paper_preset_learn_from_the_reward_and_the_tuned_preset_from_the_oracle():
    pytest.importorskip("torch")
    from training.config import TrainConfig, make_config

    assert config_regime(TrainConfig().to_dict()) == "reward"
    assert config_regime(make_config("paper").to_dict()) == "reward"
    assert config_regime(make_config("tuned").to_dict()) == "oracle-teacher"
    assert set(TEACHING_FIELDS) <= set(TrainConfig().to_dict())


def test_actor_records_tell_their_regime():
    assert actor_regime({"regime": "planner", "config": {"bc_weight": 0.0}}) == "planner"  # recorded wins
    assert actor_regime({"algo": "dqn", "config": {"steps": 10}}) == "reward"
    assert actor_regime({"algo": "mddpg", "config": {"polish_epochs": 20}}) == "oracle-teacher"
    agree = {"members": [{"algo": "ddpg", "config": {}}, {"algo": "ddpg", "config": {}}]}
    assert actor_regime(agree) == "reward"
    differ = {"members": [{"algo": "ddpg", "config": {}}, {"algo": "ddpg", "config": {"bc_weight": 1.0}}]}
    assert actor_regime(differ) is None
    assert actor_regime({"format": "deck_sim.actor/1"}) is None
    assert regime_text(None) == "an unrecorded regime"
    assert all(name in regime_text(name) for name in REGIMES)


@pytest.mark.parametrize("algo", sorted(LEARNED))
def test_every_shipped_actor_records_a_regime(algo):
    for scene in ("deck1", "deck2", "square"):
        path = TRAINED_DIR / f"{scene}_{algo}.npz"
        if path.exists():
            regime = actor_regime(load_actor(path).meta)
            assert regime in REGIMES
            if AGENTS[algo].recipe in ("reward", "planner"):  # the name says the regime
                assert regime == AGENTS[algo].recipe, (scene, algo)


# a stable-baselines3 export, and the shipped MDDPG learnt by the paper's protocol
@pytest.mark.parametrize("policy", ["dqn", "mddpg-reward"])
def test_deck_sim_run_says_what_a_learned_policy_learnt_from(tmp_path, capsys, policy):
    out = tmp_path / "run"
    assert main(["run", "--scene", "deck1", "--policy", policy, "--episodes", "1", "--no-record", "--quiet",
                 "--out", str(out)]) == 0
    assert f"{policy} learnt from the reward alone (regime: reward)" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["regime"] == "reward"
    assert "regime: reward" in (out / "results.md").read_text()
    out2 = tmp_path / "zero"
    assert main(["run", "--scene", "deck1", "--policy", "zero", "--episodes", "1", "--no-record", "--quiet",
                 "--out", str(out2)]) == 0
    assert "learnt from" not in capsys.readouterr().out
    assert json.loads((out2 / "summary.json").read_text())["regime"] is None


@given(st.fixed_dictionaries(FIELD_VALUES), st.sampled_from(["full", "observation"]))
def test_a_taught_config_is_in_the_planner_regime_exactly_when_its_teacher_reads_the_observation(fields, view):
    regime = config_regime({**fields, "teacher_view": view})
    if not any(fields.values()):
        assert regime == "reward"
    else:
        assert regime == ("planner" if view == "observation" else "oracle-teacher")


def test_a_teacher_on_the_observation_needs_a_teacher_and_the_footprints_in_the_observation():
    pytest.importorskip("torch")
    from deck_sim.agents import OBSERVED_FIELDS
    from training.config import ConfigError, make_config

    with pytest.raises(ConfigError, match="teacher_view: expected one of full, observation"):
        make_config("tuned", teacher_view="oracle")
    with pytest.raises(ConfigError, match="no teaching field is on"):
        make_config("reward", teacher_view="observation", scene_overrides=dict(OBSERVED_FIELDS))
    with pytest.raises(ConfigError, match="set scene_overrides episode__static_size = true, "
                                          "episode__obstacle_shape = true"):
        make_config("tuned", teacher_view="observation", scene_overrides={"episode__mover_size": True})
    cfg = make_config("tuned", algo="ddpg", teacher_view="observation", scene_overrides=dict(OBSERVED_FIELDS))
    assert cfg.regime == "planner" and cfg.teacher_policy_view == "observation-without-forecast"
    assert make_config("tuned", algo="mddpg").teacher_policy_view == "full"


@pytest.mark.parametrize(("algo", "view"), [("mddpg", "observation"), ("ddpg", "observation-without-forecast")])
def test_the_planner_recipes_teach_each_agent_from_its_own_observation(algo, view):
    pytest.importorskip("torch")
    from training.recipes import load_recipe
    from training.runners import EnvGroup

    for name in ("deck1-planner", "deck2-planner"):
        cfg = load_recipe(name).config(algo, 0)
        assert (cfg.regime, cfg.teacher_policy_view) == ("planner", view)
    group = EnvGroup(1, None)
    spec = cfg_spec(load_recipe("deck1-planner").config(algo, 0))
    group.build(0, *spec)
    try:
        assert group.experts[0].view == view
    finally:
        group.close()


def cfg_spec(cfg):  # noqa: ANN001, ANN201
    """The environment spec a run of ``cfg`` builds its first environments from."""
    from training.runners import EnvSpec

    return EnvSpec(cfg.scene, cfg.predictor, dict(cfg.scene_overrides), cfg.expert_relabel, cfg.teacher_body,
                   cfg.teacher_policy_view)


def test_a_short_planner_regime_run_records_its_regime(tmp_path):
    pytest.importorskip("torch")
    from conftest import short_config

    from deck_sim.agents import OBSERVED_FIELDS
    from training.loop import Trainer

    cfg = short_config(algo="mddpg", teacher_view="observation", scene_overrides=dict(OBSERVED_FIELDS),
                       total_steps=60, env_worker=False)
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    assert trainer.env_spec(0) == cfg_spec(cfg)._replace(overrides=trainer.env_spec(0).overrides)
    trainer.train()
    assert json.loads((tmp_path / "run" / "config.json").read_text())["regime"] == "planner"
    assert actor_regime(load_actor(tmp_path / "run" / "actor.npz").meta) == "planner"
    assert trainer.demo_summary["success"] == 1.0  # the planner on the observation reached its demonstrated target

