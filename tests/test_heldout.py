"""``training.heldout.held_out``: a run's shipped actor on the held-out episodes of ``docs/results.md``, measured
once per actor and cached in the run folder."""

from __future__ import annotations

import json
import shutil

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
