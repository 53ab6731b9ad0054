"""benchmarks/actor_pick.py: a run's final actor against the one its best evaluation picked, on held-out episodes."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest
from conftest import short_config

from deck_sim.policies import LearnedPolicy
from training.loop import Trainer

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def actor_pick():  # noqa: ANN201
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import actor_pick

    return actor_pick


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A seconds-long DDPG run on deck 1 with an averaged actor, evaluated at steps 0, 100, 200 and 300 on one
    episode, which it never reaches: the first evaluation stays the best, so the picked actor is not the final one."""
    out = tmp_path_factory.mktemp("pick") / "run"
    cfg = short_config(algo="ddpg", total_steps=300, eval_every=100, eval_episodes=1, demo_episodes=0,
                       pretrain_updates=0, bc_weight=0.0, expert_relabel=False, actor_average=1e-3)
    trainer = Trainer(cfg, out, progress=False)
    trainer.train()
    trainer.close()
    return out


def test_the_final_and_picked_actors_play_the_same_episodes_and_their_difference_is_summed_over_runs(
        run, actor_pick, tmp_path, capsys):
    picked, final = LearnedPolicy.load(run / "actor_best.npz"), LearnedPolicy.load(run / "actor.npz")
    assert picked.meta["trained_steps"] < final.meta["trained_steps"] == 300
    assert not actor_pick.same_weights(picked, final) and actor_pick.same_weights(final, LearnedPolicy.load(
        run / "actor.npz"))
    last = tmp_path / "last"  # a run whose best evaluation was its last: one actor
    shutil.copytree(run, last)
    shutil.copy(last / "actor.npz", last / "actor_best.npz")
    actor_pick.main([str(run), str(last), "--episodes", "2", "--workers", "1"])
    out = capsys.readouterr().out
    assert f"{run} (ddpg, scene deck1, 300 steps; best evaluation at step {picked.meta['trained_steps']:,})" in out
    assert out.count("  picked   success ") == 2 and out.count("  final    success ") == 2
    assert out.count("(the picked actor's weights)") == 1
    assert "final minus picked: +0.0 (each the same: no spread to give an interval) points" in out
    assert out.count("  averaged success ") == 2 and out.count("averaged minus picked: ") == 2
    assert "\ndeck1: final minus picked over 2 runs: " in out and "\ndeck1: averaged minus picked over 2 runs: " in out
    assert "all:" not in out  # (one scene)


def test_a_run_without_both_actors_or_with_a_fitted_final_actor_is_refused_by_name(run, actor_pick, tmp_path):
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    shutil.copy(run / "actor_best.npz", unfinished / "actor_best.npz")
    with pytest.raises(SystemExit, match=f"{unfinished}: no actor.npz"):
        actor_pick.main([str(unfinished), "--episodes", "2"])
    fitted = tmp_path / "fitted"
    shutil.copytree(run, fitted)
    final = LearnedPolicy.load(fitted / "actor.npz")
    final.meta["polished"] = True
    final.save(fitted / "actor.npz")
    with pytest.raises(SystemExit, match="its final actor is the cloning fit's"):
        actor_pick.main([str(fitted), "--episodes", "2"])
    with pytest.raises(SystemExit):
        actor_pick.main([str(run), str(run)])


def test_another_stream_than_the_held_out_one_is_named_as_such(run, actor_pick, capsys):
    actor_pick.main([str(run), "--episodes", "2", "--workers", "1", "--seed", "3000"])
    assert "2 episodes per actor from seed 3000 (not the held-out episodes)" in capsys.readouterr().out
    with pytest.raises(SystemExit):  # (past the evaluation seeds' range: refused by the harness's check)
        actor_pick.main([str(run), "--episodes", "2", "--workers", "1", "--seed", "999999"])


def test_the_checkpoints_averaged_actor_with_its_critic_selects_as_deck_sim_select_writes_it(run, tmp_path, capsys):
    import numpy as np

    from deck_sim.cli import main as cli
    from training.checkpoints import checkpoint_policy

    averaged, saved = checkpoint_policy(run, averaged=True), LearnedPolicy.load(run / "actor_avg.npz")
    for key in saved.arrays:  # the average the run exported, and the critic it exported with it
        np.testing.assert_array_equal(averaged.arrays[key], saved.arrays[key], err_msg=key)
    assert averaged.meta["averaged"] == 1e-3 and averaged.meta["critic"] == saved.meta["critic"]
    assert cli(["select", str(run), "--averaged", "--out", str(tmp_path / "s.npz"), "--candidates", "4"]) == 0
    assert "the averaged actor and critic of" in capsys.readouterr().out
    chosen = LearnedPolicy.load(tmp_path / "s.npz")
    assert chosen.selects and np.array_equal(chosen.arrays["w0"], saved.arrays["w0"])
    assert cli(["select", str(run / "actor.npz"), "--averaged", "--out", str(tmp_path / "f.npz")]) != 0
    assert "--averaged takes a run folder" in capsys.readouterr().err and not (tmp_path / "f.npz").exists()
