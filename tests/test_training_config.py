"""The training configuration: errors that name the field, the cloning weight's schedule, the recipes
(presets, ablations, additions joined by ``+``) and the shipped recipes they name."""

from __future__ import annotations

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
    from training.config import SHIPPED_RECIPES, shipped_arm

    for scene in SHIPPED_RECIPES:  # every shipped recipe is a valid arm
        arm = shipped_arm(scene, "ddpg")
        assert arm_config(arm.recipe, scene, arm.steps, 0, arm.eval_every, arm.eval_episodes).algo == "ddpg"
    assert shipped_arm("deck1", "mddpg")[:4] == (
        "tuned-mddpg-with-data+polish+size+sets+body+dagger", 160_000, 20_000, 100
    )
    deck1 = arm_config(shipped_arm("deck1", "ddpg").recipe, "deck1", 160_000, 0)
    assert (deck1.actor_arch, deck1.polish_epochs, deck1.scene_overrides) == ("sets", 20, {"episode__mover_size": True})
    assert deck1.teacher_body and deck1.dagger_steps == 40_000
    assert shipped_arm("deck2", "ddpg")[:2] == ("tuned-ddpg-with-data+polish+size+sets+close", 160_000)
    for deck in ("deck1", "deck2", "square"):  # two seeds' actors averaged, MDDPG and DDPG alike
        assert shipped_arm(deck, "ddpg").seeds == shipped_arm(deck, "mddpg").seeds == (0, 1)
    assert shipped_arm("square", "mddpg") == (
        "tuned-mddpg-with-data+polish+near+sets+close", 160_000, 20_000, 100, (0, 1)
    )
    for bad in ("tuned-mddpg-with-data+nope", "tuned-mddpg-with-data+data", "tuned-mddpg-no-data"):
        with pytest.raises(ConfigError, match="unknown switch"):
            arm_config(bad, "deck1", steps=10_000, seed=0)
