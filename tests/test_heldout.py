"""``training.heldout.held_out``: a run's shipped actor on the held-out episodes of ``docs/results.md``, measured
once per actor and cached in the run folder."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from deck_sim.evaluation import DEFAULT_SEED, EvalConfig, evaluate
from deck_sim.policies import TRAINED_DIR
from training.heldout import HeldOutError, goal_each, held_out, held_out_file


def _run(tmp_path, actor: str = "deck1_ddpg.npz"):
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    (run / "config.json").write_text(json.dumps({"scene": "deck1", "seed": 0}))
    shutil.copyfile(TRAINED_DIR / actor, run / "actor_best.npz")
    return run


def _direct(run):
    return evaluate(EvalConfig(agents=(f"x={run / 'actor_best.npz'}",), scenes=("deck1",), episodes=2,
                               backend="serial", record="none"))


def test_held_out_matches_deck_sim_eval_and_is_cached_per_actor(tmp_path):
    run = _run(tmp_path)
    first = held_out(run, episodes=2, workers=1)
    res = _direct(run)
    direct = res.summary("deck1", "x")
    assert first["success"] == direct["goal_rate"] and first["collision"] == direct["collision_rate"]
    assert first["episodes"] == 2 and first["seed"] == DEFAULT_SEED and first["scene"] == "deck1"
    # each episode's success, in episode order, for paired comparisons
    outcomes = [r["outcome"] for r in sorted(res.episodes, key=lambda r: r["episode"])]
    assert first["goal_each"] == [int(o == "goal") for o in outcomes]
    assert json.loads((run / held_out_file(2)).read_text())["actor_sha256"] == first["actor_sha256"]
    # the same actor again: the cached record, not a new evaluation (same wall time to the bit)
    assert held_out(run, episodes=2, workers=1) == first
    # another actor in the folder: measured again
    shutil.copyfile(TRAINED_DIR / "deck1_mddpg.npz", run / "actor_best.npz")
    assert held_out(run, episodes=2, workers=1)["actor_sha256"] != first["actor_sha256"]


def test_a_folder_without_config_or_actor_is_refused_by_name(tmp_path):
    with pytest.raises(HeldOutError, match="not a training run folder"):
        held_out(tmp_path, episodes=1)
    run = _run(tmp_path)
    (run / "actor_best.npz").unlink()
    with pytest.raises(HeldOutError, match="no actor to measure yet"):
        held_out(run, episodes=1)


def test_a_record_without_per_episode_successes_is_measured_again_only_when_they_are_asked_for(tmp_path):
    run = _run(tmp_path)
    first = held_out(run, episodes=2, workers=1)
    old = {k: v for k, v in first.items() if k != "goal_each"}  # a record written before goal_each was kept
    (run / held_out_file(2)).write_text(json.dumps(old))
    assert held_out(run, episodes=2, workers=1) == old  # the summary figures: the cache serves
    again = held_out(run, episodes=2, workers=1, per_episode=True)
    assert again["goal_each"] == first["goal_each"] and again["success"] == first["success"]
    assert "goal_each" in json.loads((run / held_out_file(2)).read_text())


def test_goal_each_gives_each_episode_the_share_of_its_aircraft_at_their_targets():
    rows = [{"episode": e, "aircraft": k, "outcome": o}
            for e, k, o in [(1, "a", "goal"), (0, "a", "goal"), (0, "b", "collision"), (1, "b", "goal")]]
    assert goal_each(rows, 2) == [0.5, 1]
    assert goal_each([{"episode": 0, "outcome": "timeout"}], 1) == [0]
    with pytest.raises(HeldOutError, match="1 distinct episodes, expected 0 to 1"):
        goal_each(rows[:1], 2)


@pytest.fixture(scope="module")
def averaged_run(tmp_path_factory):
    """A seconds-long DDPG run on deck 1 that keeps the slow average of its actor (``actor_avg.npz``, with its
    critic)."""
    from conftest import short_config

    from training.loop import Trainer

    out = tmp_path_factory.mktemp("averaged") / "run"
    cfg = short_config(algo="ddpg", total_steps=120, eval_every=0, demo_episodes=0, pretrain_updates=0,
                       bc_weight=0.0, expert_relabel=False, actor_average=1e-3)
    trainer = Trainer(cfg, out, progress=False)
    trainer.train()
    trainer.close()
    return out


def test_the_averaged_actor_choosing_by_its_critic_is_measured_and_cached_apart(averaged_run, tmp_path):
    from deck_sim.policies import LearnedPolicy
    from training.final_fit import AVERAGED_SELECT_FILE, SELECT_CANDIDATES, SELECT_SPREAD

    run = tmp_path / "run"
    shutil.copytree(averaged_run, run)
    shipped = held_out(run, episodes=2, workers=1)
    chosen = held_out(run, episodes=2, workers=1, play="averaged-select")
    assert shipped["play"] == "shipped" and chosen["play"] == "averaged-select"
    assert chosen["actor"] == AVERAGED_SELECT_FILE and chosen["actor_sha256"] != shipped["actor_sha256"]
    # the averaged actor's own weights and critic, selecting among its fixed candidates
    avg, sel = LearnedPolicy.load(run / "actor_avg.npz"), LearnedPolicy.load(run / AVERAGED_SELECT_FILE)
    assert sel.selects and not avg.selects
    assert sel.meta["select"] == {"candidates": SELECT_CANDIDATES, "spread": SELECT_SPREAD, "seed": 0}
    assert all((sel.arrays[k] == v).all() for k, v in avg.arrays.items())
    direct = evaluate(EvalConfig(agents=(f"x={run / AVERAGED_SELECT_FILE}",), scenes=("deck1",), episodes=2,
                                 backend="serial", record="none"))
    assert chosen["goal_each"] == [int(r["outcome"] == "goal")
                                   for r in sorted(direct.episodes, key=lambda r: r["episode"])]
    assert chosen["reward"] == direct.summary("deck1", "x")["reward"]
    # each play its own cache: both read back without evaluating
    assert (run / held_out_file(2)).exists() and (run / held_out_file(2, "averaged-select")).exists()
    for play, record in (("averaged-select", chosen), ("shipped", shipped)):  # (the same wall time to the bit)
        cached = held_out(run, episodes=2, workers=1, play=play)
        assert (cached["wall_s"], cached["actor_sha256"]) == (record["wall_s"], record["actor_sha256"])
    # a newer averaged actor: the selecting file is written again from it, and measured again
    other = LearnedPolicy.load(run / "actor_avg.npz")
    other.arrays["w0"] = other.arrays["w0"] * 0.5
    import os
    import time

    other.save(run / "actor_avg.npz")
    later = time.time() + 5
    os.utime(run / "actor_avg.npz", (later, later))
    again = held_out(run, episodes=2, workers=1, play="averaged-select")
    assert again["actor_sha256"] != chosen["actor_sha256"]
    assert (LearnedPolicy.load(run / AVERAGED_SELECT_FILE).arrays["w0"] == other.arrays["w0"]).all()


def test_a_run_without_an_averaged_actor_or_an_unknown_play_is_refused_by_name(tmp_path):
    run = _run(tmp_path)
    with pytest.raises(HeldOutError, match="no averaged actor to measure .*actor_average = 0"):
        held_out(run, episodes=1, play="averaged-select")
    with pytest.raises(ValueError, match="unknown play 'final'; expected one of shipped, averaged-select"):
        held_out(run, episodes=1, play="final")


def test_an_averaged_actor_saved_without_its_critic_takes_the_checkpoints_and_only_if_it_is_the_same_actor(
        averaged_run, tmp_path):
    from deck_sim.policies import SELECT_OFFSETS, LearnedPolicy
    from training.final_fit import played_actor

    run = tmp_path / "run"
    shutil.copytree(averaged_run, run)
    full = LearnedPolicy.load(run / "actor_avg.npz")
    bare = LearnedPolicy({k: v for k, v in full.arrays.items() if not k.startswith("critic.")},
                         {k: v for k, v in full.meta.items() if k != "critic"})
    bare.save(run / "actor_avg.npz")  # as a run older than the critic's export wrote it
    chosen = LearnedPolicy.load(played_actor(run, "averaged-select"))
    assert chosen.selects and chosen.meta["critic"] == full.meta["critic"]
    assert set(chosen.arrays) == {*full.arrays, SELECT_OFFSETS}
    assert all(np.array_equal(chosen.arrays[k], v) for k, v in full.arrays.items())
    # another actor than the checkpoint's: its critic is not this actor's, refused by name
    (run / "actor_avg_select.npz").unlink()
    other = LearnedPolicy({k: v * 0.5 if k == "w0" else v for k, v in bare.arrays.items()}, bare.meta)
    other.save(run / "actor_avg.npz")
    with pytest.raises(ValueError, match="carries no critic, and the checkpoint's averaged actor .* is not the same"):
        played_actor(run, "averaged-select")


def test_the_selecting_file_follows_its_averaged_actor_and_the_selections_settings(averaged_run, tmp_path,
                                                                                   monkeypatch):
    import training.final_fit as final_fit
    from deck_sim.policies import LearnedPolicy
    from training.heldout import shipped_held_out

    run = tmp_path / "run"
    shutil.copytree(averaged_run, run)
    path = final_fit.played_actor(run, "averaged-select")
    first = LearnedPolicy.load(path).meta
    assert first["select"] == final_fit.play_settings("averaged-select") and "averaged_sha256" in first
    before = path.read_bytes()
    assert final_fit.played_actor(run, "averaged-select").read_bytes() == before  # (up to date: not written again)
    monkeypatch.setattr(final_fit, "SELECT_CANDIDATES", 8)  # other settings: made again, and old records refused
    assert LearnedPolicy.load(final_fit.played_actor(run, "averaged-select")).meta["select"]["candidates"] == 8
    record = {"episodes": 2, "seed": DEFAULT_SEED, "goal_each": [1, 0], "play": "averaged-select",
              "play_settings": {"candidates": 64, "spread": 0.3, "seed": 0}}
    (run / held_out_file(2, "averaged-select")).write_text(json.dumps(record))
    assert shipped_held_out(run, 2, "averaged-select") is None
    (run / held_out_file(2, "averaged-select")).write_text(json.dumps({**record, "play_settings": {
        "candidates": 8, "spread": 0.3, "seed": 0}}))
    assert shipped_held_out(run, 2, "averaged-select")["goal_each"] == [1, 0]
    assert shipped_held_out(run, 2) is None  # (another play's record is not the shipped actor's)
    (run / "actor_avg.npz").unlink()  # its averaged actor gone: the file made of it goes too
    assert not final_fit.played_actor(run, "averaged-select").exists()
    with pytest.raises(HeldOutError, match="no averaged actor to measure"):
        held_out(run, episodes=1, play="averaged-select")


def test_every_agents_way_of_acting_is_a_play():
    from deck_sim.agents import AGENTS
    from training.final_fit import PLAYS

    plays = {a.name: a.play for a in AGENTS.values() if a.play}
    assert plays == {"mddpg-reward-select": "averaged-select", "ddpg-reward-select": "averaged-select"}
    assert set(plays.values()) <= set(PLAYS) and all(AGENTS[a].trainer == "ddpg" for a in plays)
