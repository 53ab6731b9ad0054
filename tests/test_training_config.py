"""The training configuration: errors that name the field, the cloning weight's schedule, the recipes
(presets, ablations, additions joined by ``+``) and the shipped recipes they name."""

from __future__ import annotations

import re

import pytest

from training.config import ConfigError, TrainConfig, make_config, train_episode_seed


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="algo"):
        make_config("tuned", algo="ppo")
    with pytest.raises(ConfigError, match="gamma"):
        make_config("paper", gamma=1.5)
    with pytest.raises(ConfigError, match="unknown training config field"):
        make_config("paper", learning_rate=1e-3)
    with pytest.raises(ConfigError, match="preset"):
        make_config("fast")
    assert train_episode_seed(0, 0, 0) >= 1_000_000  # training episodes never use the evaluation seeds


def test_scene_overrides_are_checked_with_the_algorithms_predictor():
    from training.config import arm_config

    assert arm_config("reward-mddpg-with-approach", "deck1", 1000, 0).scene_overrides == {
        "episode__predicted_approach": True
    }
    with pytest.raises(ConfigError, match=r"scene_overrides .*predicted_approach: is read from the forecast: it "
                                          r"needs a predictor"):
        arm_config("reward-ddpg-with-approach", "deck1", 1000, 0)  # (DDPG observes no forecast)
    assert arm_config("reward-mddpg-with-close+nearforecast", "deck1", 1000, 0).scene_overrides == {
        "episode__near_steps": 4, "episode__near_obstacles": True, "episode__predicted_near": True
    }
    with pytest.raises(ConfigError, match=r"predicted_near: needs a near field: set \[episode\].near_steps > 0"):
        arm_config("reward-mddpg-with-nearforecast", "deck1", 1000, 0)
    with pytest.raises(ConfigError, match=r"predicted_near: is read from the forecast: it needs a predictor"):
        arm_config("reward-ddpg-with-close+nearforecast", "deck1", 1000, 0)
    with pytest.raises(ConfigError, match=r"scene_overrides: episode__predictor is the algorithm's \(ddpg: none\)"):
        make_config("reward", algo="ddpg", scene_overrides={"episode__predictor": "mpc"})
    with pytest.raises(ConfigError, match=r"scene 'deck1' with scene_overrides .*horizon"):
        make_config("reward", algo="mddpg", scene_overrides={"episode__horizon": 0})


def test_the_curriculum_switch_starts_each_scene_small():
    from deck_sim.scenes import load_scene
    from training.config import arm_config
    from training.envs import stage_overrides

    for scene in ("deck1", "deck2", "square"):
        cfg = arm_config("reward-mddpg-with-curriculum", scene, 1000, 0)
        first, second = (stage_overrides(scene, stage) for stage in cfg.curriculum)
        m = load_scene(scene).movers
        movers = [sum(o[f"movers__{k}"] for k in ("tractors", "aircraft", "pedestrians")) for o in (first, second)]
        assert movers == [2, min(5, m.tractors + m.aircraft + m.pedestrians)], scene
        assert first["agent__max_target_distance"] == 100.0 and second["agent__max_target_distance"] == 150.0
        spec = load_scene(scene)
        assert not set(first["agent__target_sites"]) & set(m.spots)  # (a mover may stand on its spot)
        assert set(first["agent__target_sites"]) == {*spec.agent.target_sites, *spec.agent.start_sites}
        for stage in (first, second):  # every stage's scene is valid (the config's validation loads them too)
            load_scene(scene, **stage)
        assert [s.until for s in cfg.curriculum] == [0.1, 0.25]


def test_the_forecast_is_mddpgs_and_named_when_wrong():
    from training.config import arm_config

    assert make_config("reward").predictor == "mpc"
    assert arm_config("reward-mddpg-with-oracle", "deck1", 1000, 0).predictor == "oracle"
    assert arm_config("reward-mddpg-with-cvforecast", "deck1", 1000, 0).predictor == "constant_velocity"
    with pytest.raises(ConfigError, match="forecast: expected one of constant_velocity, stationary, oracle, mpc, "
                                          "got 'none'"):
        make_config("reward", forecast="none")
    with pytest.raises(ConfigError, match="forecast: expected one of"):
        make_config("reward", forecast="kalman")
    with pytest.raises(ConfigError, match="forecast: ddpg observes no forecast, got forecast = 'oracle'"):
        arm_config("reward-ddpg-with-oracle", "deck1", 1000, 0)
    assert TrainConfig.from_dict({"algo": "ddpg"}).predictor == "none"  # (a saved config without the field)
    with pytest.raises(ConfigError, match="forecast: a teacher plans on the MPC forecast"):
        arm_config("tuned-mddpg-with-oracle", "deck1", 1000, 0)


def test_the_cloning_weight_falls_on_its_schedule_and_resumes_with_the_step():
    from training.config import arm_config, bc_weight_at

    cfg = arm_config("tuned-mddpg-with-decay", "deck1", steps=10_000, seed=0)
    assert (cfg.bc_weight, cfg.bc_weight_final, cfg.bc_decay) == (20.0, 2.0, 1.0)
    assert [bc_weight_at(cfg, s) for s in (0, 5_000, 10_000, 20_000)] == [20.0, 11.0, 2.0, 2.0]
    assert bc_weight_at(make_config(), 5_000) == 20.0  # no final weight: constant
    half = make_config(bc_weight=10.0, bc_weight_final=0.0, bc_decay=0.5, total_steps=1_000)
    assert bc_weight_at(half, 250) == 5.0 and bc_weight_at(half, 600) == 0.0
    with pytest.raises(ConfigError, match="bc_weight_final"):
        make_config(bc_weight_final=-1.0)
    with pytest.raises(ConfigError, match="bc_decay"):
        make_config(bc_decay=1.5)
    with pytest.raises(ConfigError, match="bc_weight_final: the cloning term is off"):
        make_config(bc_weight=0.0, bc_weight_final=2.0)
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg  # saved with the run


def test_recipe_switches_combine_with_plus_and_merge_scene_overrides():
    from training.config import arm_config

    cfg = arm_config("tuned-mddpg-with-data+size+shape", "deck1", steps=10_000, seed=0)
    assert (cfg.num_envs, cfg.updates_per_step) == (8, 0.125)
    assert cfg.scene_overrides == {"episode__mover_size": True, "episode__obstacle_shape": True}
    assert arm_config("tuned-ddpg-with-data", "deck1", steps=10_000, seed=0).num_envs == 8
    near = arm_config("tuned-mddpg-with-data+polish+near", "square", steps=10_000, seed=0)
    assert near.scene_overrides == {"episode__near_steps": 4} and near.polish_epochs == 20
    ego = arm_config("tuned-ddpg-with-data+polish+size+ego", "deck1", steps=10_000, seed=0)
    assert ego.scene_overrides == {"episode__mover_size": True, "episode__frame": "agent"}
    close = arm_config("tuned-mddpg-with-data+polish+near+sets+close", "square", steps=10_000, seed=0)
    assert close.scene_overrides == {"episode__near_steps": 4, "episode__near_obstacles": True}
    assert close.actor_arch == "sets"
    assert arm_config("tuned-ddpg-with-data+body", "deck1", steps=10_000, seed=0).teacher_body
    assert not arm_config("tuned-ddpg-with-data", "deck1", steps=10_000, seed=0).teacher_body
    from training.recipes import load_recipe

    benchmark_names = {  # the recipe files' configurations, as benchmarks/learning.py names them
        "deck1": "tuned-{algo}-with-data+polish+size+sets+body+dagger",
        "deck2": "tuned-{algo}-with-data+polish+size+sets+close",
        "square": "tuned-{algo}-with-data+polish+near+sets+close",
    }
    for scene, name in benchmark_names.items():
        recipe = load_recipe(scene)
        for algo in ("mddpg", "ddpg"):  # (the shipped seeds: tests/test_recipes.py)
            assert recipe.steps(algo) == 160_000
            from_file = recipe.config(algo, 0).to_dict()
            named = arm_config(name.format(algo=algo), scene, 160_000, 0, 20_000, 100).to_dict()
            assert {**from_file, "extra": None} == {**named, "extra": None}, (scene, algo)
    deck1 = load_recipe("deck1").config("ddpg", 0)
    assert (deck1.actor_arch, deck1.polish_epochs, deck1.scene_overrides) == ("sets", 20, {"episode__mover_size": True})
    assert deck1.teacher_body and deck1.dagger_steps == 40_000
    for bad in ("tuned-mddpg-with-data+nope", "tuned-mddpg-with-data+data", "tuned-mddpg-no-data"):
        with pytest.raises(ConfigError, match="unknown switch"):
            arm_config(bad, "deck1", steps=10_000, seed=0)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("batch_size=abc", "batch_size: expected an integer, got 'abc'"),
        ("twin_critics=maybe", "twin_critics: expected true or false, got 'maybe'"),
        ("hidden=[256,\"wide\"]", "hidden\\[1\\]: expected an integer"),
        ("actor_lr=true", "actor_lr: expected a number, got True"),
        ("wings=2", "unknown training config field\\(s\\): wings"),
        ("seed=3", "use --seed"),
    ],
)
def test_set_is_type_checked_with_exit_code_2_and_no_run_folder(tmp_path, capsys, item, message):
    from deck_sim.cli import main

    out = tmp_path / "run"
    assert main(["train", "--algo", "mddpg", "--set", item, "--out", str(out), "--quiet"]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not out.exists()


def test_from_dict_reads_json_kinds_as_their_field_types():
    cfg = TrainConfig.from_dict({"actor_lr": 1, "hidden": [64, 32], "bc_weight_final": None,
                                 "curriculum": [{"until": 1, "max_target_distance": 30, "movers": 2}]})
    assert isinstance(cfg.actor_lr, float) and cfg.hidden == (64, 32) and cfg.bc_weight_final is None
    assert cfg.curriculum[0].max_target_distance == 30.0
    with pytest.raises(ConfigError, match=r"curriculum\[0\]: expected the fields until, max_target_distance, movers"):
        TrainConfig.from_dict({"curriculum": [{"until": 1}]})


def test_train_help_lists_every_config_field(capsys):
    import dataclasses

    from deck_sim.cli import main

    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = capsys.readouterr().out
    for f in dataclasses.fields(TrainConfig):
        assert f"  {f.name} (" in text, f.name
    assert "twin_critics (bool, default false)" in text
