"""Critic-guided action selection: actor files of DDPG / MDDPG runs carry their critic, which the numpy policy
runs as the run's torch critic does; a selecting policy takes the best-rated candidate around its actor's action;
``deck-sim select`` writes one from an actor file or a run folder's checkpoint; broken records are refused by
name; ``benchmarks/critic_select.py`` compares a run's actor with and without selection, and
``benchmarks/forecast_reads.py`` its critic and actor on the run's buffer."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_steps, short_config

import deck_sim
from deck_sim.cli import main as cli
from deck_sim.policies import (
    SELECT_OFFSETS,
    EnsemblePolicy,
    LearnedPolicy,
    PolicyFileError,
    load_actor,
    selecting,
    shipped_policy_path,
)
from training.checkpoints import checkpoint_policy, load_run_agent
from training.loop import Trainer

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A seconds-long MDDPG run on deck 1 with twin critics and a checkpoint, trained once for the module."""
    out = tmp_path_factory.mktemp("select") / "run"
    cfg = short_config(algo="mddpg", total_steps=300, demo_episodes=0, pretrain_updates=0, bc_weight=0.0,
                       expert_relabel=False, twin_critics=True, policy_delay=2, twin_min_weight=0.75)
    trainer = Trainer(cfg, out, progress=False)
    trainer.train()
    trainer.close()
    return out


def test_the_exported_actor_carries_its_critic_which_numpy_rates_as_torch_does(run):
    policy = LearnedPolicy.load(run / "actor.npz")
    assert policy.meta["critic"] == {"heads": 2, "twin_min_weight": 0.75} and not policy.selects
    _, _, agent = load_run_agent(run)
    x = np.stack([policy.flatten(o) for o in run_steps(deck_sim.load("deck1", seed=2, **policy.scene_overrides),
                                                        6, seed=2)[0]])
    actions = np.random.default_rng(0).uniform(-1, 1, (len(x), 5, 2))
    with torch.no_grad():
        xs = agent.norm(torch.from_numpy(x.astype(np.float32)))
        heads = torch.stack(agent.critic(xs[:, None].expand(-1, 5, -1).reshape(-1, xs.shape[1]),
                                         torch.from_numpy(actions.reshape(-1, 2).astype(np.float32))))
        expected = agent.combine_heads(heads).reshape(len(x), 5).numpy()
    np.testing.assert_allclose(policy.q_values(x, actions), expected, rtol=1e-4, atol=1e-4)
    # the actor alone acts as before: a file without selection plays its actor's action
    np.testing.assert_allclose(policy.act_flat(x), agent.act(x.astype(np.float32)), rtol=1e-4, atol=1e-5)


def test_a_selecting_policy_takes_the_best_rated_candidate_around_its_actors_action(run, tmp_path):
    base = LearnedPolicy.load(run / "actor.npz")
    chosen = selecting(base, candidates=16, spread=0.4, seed=3)
    assert chosen.selects and chosen.meta["select"] == {"candidates": 16, "spread": 0.4, "seed": 3}
    x = np.stack([base.flatten(o) for o in run_steps(deck_sim.load("deck1", seed=4, **base.scene_overrides),
                                                      8, seed=4)[0]])
    proposal = base.act_flat(x)
    offsets = 0.4 * np.random.default_rng(3).standard_normal((16, 2))
    cand = np.concatenate([proposal[:, None], np.clip(proposal[:, None] + offsets, -1, 1)], axis=1)
    q = base.q_values(x, cand)
    expected = cand[np.arange(len(x)), q.argmax(axis=1)]
    np.testing.assert_allclose(chosen.act_flat(x), expected, atol=1e-6)
    assert np.any(np.abs(expected - proposal).max(axis=1) > 1e-6)  # (some state's best is not the actor's own)
    assert np.all(chosen.q_values(x, chosen.act_flat(x)[:, None])[:, 0] >= q[:, 0] - 1e-9)  # never below the actor's
    # the file round-trips, and plays an episode through the public rollout
    path = chosen.save(tmp_path / "chosen.npz")
    again = load_actor(path)
    np.testing.assert_array_equal(again.act_flat(x), chosen.act_flat(x))
    env = deck_sim.load("deck1", seed=1, **again.scene_overrides)
    ts = env.reset()
    for _ in range(5):
        action = again.act(ts.observation)
        assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
        ts = env.step(action)


def test_selection_records_that_cannot_serve_are_refused_by_name(run):
    base = LearnedPolicy.load(run / "actor.npz")
    chosen = selecting(base, candidates=4)
    without_critic = {k: v for k, v in chosen.arrays.items() if not k.startswith("critic.")}
    meta = {k: v for k, v in chosen.meta.items() if k != "critic"}
    with pytest.raises(PolicyFileError, match=r"meta\['select'\] asks to select actions by the critic, but the file "
                                              r"carries none"):
        LearnedPolicy(without_critic, meta)
    with pytest.raises(PolicyFileError, match=r"select.offsets has shape \(3, 2\), meta\['select'\] asks for 4"):
        LearnedPolicy({**chosen.arrays, SELECT_OFFSETS: chosen.arrays[SELECT_OFFSETS][:3]}, chosen.meta)
    bad = dict(chosen.arrays)
    bad["critic.q1.w0"] = bad["critic.q1.w0"][:, :-1]
    with pytest.raises(PolicyFileError, match="critic head 1: layer 0 has weight"):
        LearnedPolicy(bad, chosen.meta)
    with pytest.raises(PolicyFileError,
                       match=r"arrays \['critic.q0.b0'.*are critic layers, but meta\['critic'\] names 0 heads"):
        LearnedPolicy({k: v for k, v in base.arrays.items()},
                      {k: v for k, v in base.meta.items() if k != "critic"})  # (critic layers no record names)
    with pytest.raises(PolicyFileError, match=r"'select'\]\['spread'\] is -0.5"):
        LearnedPolicy(chosen.arrays, {**chosen.meta, "select": {**chosen.meta["select"], "spread": -0.5}})
    with pytest.raises(PolicyFileError, match=r"twin_min_weight'\] is 1.5"):
        LearnedPolicy(base.arrays, {**base.meta, "critic": {"heads": 2, "twin_min_weight": 1.5}})
    with pytest.raises(PolicyFileError, match="NaN or infinite"):
        LearnedPolicy({**chosen.arrays, SELECT_OFFSETS: np.full((4, 2), np.nan, np.float32)}, chosen.meta)
    with pytest.raises(PolicyFileError, match="carries no critic to select actions by"):
        selecting(LearnedPolicy(without_critic, {k: v for k, v in base.meta.items() if k != "critic"}))
    with pytest.raises(PolicyFileError, match="selection by the critic is for one actor"):
        selecting(load_actor(shipped_policy_path("mddpg", "deck1")))
    with pytest.raises(ValueError, match="positive spread"):
        selecting(base, spread=0.0)


def test_deck_sim_select_writes_a_selecting_actor_from_a_file_or_a_run_folder(run, tmp_path, capsys):
    assert cli(["select", str(run / "actor.npz"), "--out", str(tmp_path / "a.npz"), "--candidates", "8"]) == 0
    assert "selecting each action by its critic among the actor's and 8 candidates" in capsys.readouterr().out
    assert load_actor(tmp_path / "a.npz").meta["select"]["candidates"] == 8
    assert cli(["select", str(run), "--out", str(tmp_path / "b.npz")]) == 0
    assert "the actor and critic of" in capsys.readouterr().out
    from_checkpoint = load_actor(tmp_path / "b.npz")
    assert from_checkpoint.selects and from_checkpoint.meta["trained_steps"] == checkpoint_policy(run).meta[
        "trained_steps"]
    # the final actor.npz is the checkpoint's actor: the same weights
    np.testing.assert_array_equal(from_checkpoint.arrays["w0"], LearnedPolicy.load(run / "actor.npz").arrays["w0"])
    assert cli(["select", str(run), "--averaged", "--out", str(tmp_path / "d.npz")]) != 0
    assert "keeps no averaged actor (actor_average is 0.0)" in capsys.readouterr().err
    assert cli(["select", str(shipped_policy_path("mddpg", "deck1")), "--out", str(tmp_path / "c.npz")]) != 0
    assert "selection by the critic is for one actor" in capsys.readouterr().err
    assert not (tmp_path / "c.npz").exists()


def test_the_benchmark_compares_a_runs_actor_with_and_without_selection(run):
    done = subprocess.run(
        [sys.executable, "benchmarks/critic_select.py", str(run), "--episodes", "2", "--candidates", "4",
         "--predictors", "stationary", "--workers", "1", "--seed", "3000"],
        cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}, capture_output=True,
        text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "2 episodes from seed 3000 (not the held-out ones) per run" in out
    assert "  actor   success " in out and "  select  success " in out and "minus the actor:" in out
    assert "\nmddpg: selection minus the actor over seeds 0:" in out  # (a run without a recipe: its algorithm)
    assert "  actor   with stationary forecasts: success " in out and "  select  with stationary forecasts: " in out
    assert out.count("minus its own forecast:") == 2


def test_forecast_reads_compares_a_runs_critic_and_actor_on_its_own_buffer(run, tmp_path):
    done = subprocess.run(
        [sys.executable, "benchmarks/forecast_reads.py", str(run), str(tmp_path / "empty"), "--samples", "60",
         "--actions", "16", "--near", "1000"],
        cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}, capture_output=True,
        text=True, timeout=300,
    )
    assert done.returncode == 1
    assert f"{tmp_path / 'empty'}: no checkpoint.pt" in done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| run | 300 |")]
    assert [r.split("|")[3].strip() for r in rows] == ["all", "encounters"]
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    assert len(cells) == 13 and int(cells[3]) == 60
    critic_shift, critic_cost, actor_shift, _, spread, heads_shift, heads_cost, n_critic, n_actor = map(
        float, cells[4:13])
    assert 0.0 <= n_critic <= 2 * np.sqrt(2) and 0.0 <= n_actor <= 2 * np.sqrt(2)
    assert 0.0 <= critic_shift <= 2 * np.sqrt(2) and critic_cost >= 0.0 and actor_shift >= 0.0 and spread >= 0.0
    assert 0.0 <= heads_shift <= 2 * np.sqrt(2) and heads_cost >= 0.0
    assert 0 <= int(rows[1].strip("|").split("|")[3]) <= 60


def test_an_ensemble_of_selecting_members_averages_their_selected_actions_and_claims_no_critic_of_its_own(run,
                                                                                                         tmp_path):
    base = LearnedPolicy.load(run / "actor.npz")
    members = [selecting(base, candidates=8, spread=0.3, seed=1), base]
    ensemble = EnsemblePolicy(members)
    assert "critic" not in ensemble.meta and "select" not in ensemble.meta
    assert ensemble.meta["members"][0]["select"]["candidates"] == 8
    x = np.stack([base.flatten(o) for o in run_steps(deck_sim.load("deck1", seed=6, **base.scene_overrides),
                                                      4, seed=6)[0]])
    expected = (members[0].act_flat(x) + base.act_flat(x)) / 2
    np.testing.assert_allclose(ensemble.act_flat(x), expected, atol=1e-12)
    again = load_actor(ensemble.save(tmp_path / "e.npz"))
    np.testing.assert_allclose(again.act_flat(x), expected, atol=1e-12)


@pytest.mark.parametrize(("recipe", "scenes", "label"), [
    ("deck2-reward", 1, "deck2-reward ddpg"),  # (a recipe that trains several algorithms: both arms apart)
    ("reward-ddpg-with-close", 1, "reward-ddpg-with-close"),
    (None, 1, "ddpg"),
    ("deck2-reward", 2, "deck2-reward ddpg on deck2"),
])
def test_an_arm_is_labelled_by_its_recipe_and_algorithm(recipe, scenes, label, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    from critic_select import arm_key

    meta = {"algo": "ddpg", "scene": "deck2", "config": {"extra": {"recipe": recipe} if recipe else {}}}
    assert arm_key(meta, scenes) == ("ddpg", label)
    assert arm_key({**meta, "algo": "mddpg"}, scenes)[1] != label  # (MDDPG's arm of the same recipe differs)
