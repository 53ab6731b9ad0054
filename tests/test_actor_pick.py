"""benchmarks/actor_pick.py: a run's final actor against the one its best evaluation picked, on held-out episodes."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from conftest import short_config

from deck_sim.policies import LearnedPolicy
from training.loop import Trainer

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def actor_pick():  # noqa: ANN201
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(ROOT / "benchmarks"))
        import actor_pick

        yield actor_pick


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
    assert not actor_pick.same_weights(picked, final)
    last = tmp_path / "last"  # a run whose best evaluation was its last: one actor
    shutil.copytree(run, last)
    shutil.copy(last / "actor.npz", last / "actor_best.npz")
    actor_pick.main([str(run), str(last), "--episodes", "2", "--workers", "1"])
    out = capsys.readouterr().out
    assert f"{run} (ddpg, scene deck1, 300 steps; best evaluation at step {picked.meta['trained_steps']:,})" in out
    assert out.count("  picked   success ") == 2 and out.count("  final    success ") == 2
    assert out.count("(the picked actor's weights)") == 1  # (the copied final actor: the same arrays, played once)
    assert "final minus picked: +0.0 (each the same: no spread to give an interval) points" in out
    assert out.count("  averaged success ") == 2 and out.count("averaged minus picked: ") == 2
    assert "\ndeck1: final minus picked over 2 runs: " in out and "\ndeck1: averaged minus picked over 2 runs: " in out
    assert "all:" not in out  # (one scene)


def test_a_run_without_both_actors_or_with_a_fitted_final_actor_is_refused_by_name(run, actor_pick, tmp_path,
                                                                                    capsys):
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    shutil.copy(run / "actor_best.npz", unfinished / "actor_best.npz")
    with pytest.raises(SystemExit, match=re.escape(f"{unfinished}: no actor.npz")):
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
    assert "a run folder is given twice" in capsys.readouterr().err


def test_another_stream_than_the_held_out_one_is_named_as_such(run, actor_pick, capsys):
    actor_pick.main([str(run), "--episodes", "2", "--workers", "1", "--seed", "3000"])
    assert "2 episodes per actor from seed 3000 (not the held-out episodes)" in capsys.readouterr().out
    refusals = {"999999": "below the training seeds", "99999": "reach the held-out episodes",
                "499": "overlap the periodic evaluations' episodes 500 to 500"}  # (the run evaluates on 1 episode)
    for seed, why in refusals.items():
        with pytest.raises(SystemExit):
            actor_pick.main([str(run), "--episodes", "2", "--workers", "1", "--seed", seed])
        assert why in capsys.readouterr().err, seed


def test_the_summary_gives_each_scenes_mean_over_runs_with_its_interval_and_the_runs_each_way(actor_pick):
    # deck 1: +25 and -25 points (t(1) = 12.706: half-width 12.706 x 35.36 / sqrt(2) = 317.7); the square level;
    # all three: sd 25 points, t(2) = 4.303, half-width 62.1
    lines = actor_pick.summary({"final": {"deck1": [0.25, -0.25], "square": [0.0]}, "averaged": {"deck2": [0.1]}})
    assert lines == [
        "",
        "deck1: final minus picked over 2 runs: +0.0 (-317.7 to +317.7) points; final ahead in 1, behind in 1, "
        "level in 0",
        "square: final minus picked over 1 run: +0.0 points; final ahead in 0, behind in 0, level in 1",
        "all: final minus picked over 3 runs: +0.0 (-62.1 to +62.1) points; final ahead in 1, behind in 1, level in 1",
        "",
        "deck2: averaged minus picked over 1 run: +10.0 points; averaged ahead in 1, behind in 0, level in 0",
    ]
