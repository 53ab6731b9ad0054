"""``scripts/make_results.py``'s lead section: the reward-alone runs, seed by seed on the held-out episodes, as
means with intervals over seeds, the paired prediction ablation and the targets, read from run folders."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from deck_sim.policies import TRAINED_DIR, shipped_log_dir
from training.heldout import held_out_file
from training.recipes import load_recipe

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def make_results():
    spec = importlib.util.spec_from_file_location("make_results", ROOT / "scripts" / "make_results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(out: Path, algo: str, seed: int, success: float, turning: float, steps: int = 1_000_000,
         goal_each: list[int] | None = None, recipe: str = "deck1-reward", total: int = 1_000_000) -> None:
    """A run folder of ``recipe`` (its configuration for ``algo`` and ``seed``, ``total`` steps) whose actor's
    held-out record is already cached (no evaluation); each episode's success is the first ``success`` share of the
    100 episodes unless ``goal_each`` gives it."""
    run = out / f"{recipe}-{algo}-seed{seed}"
    run.mkdir(parents=True)
    load_recipe(recipe).run(algo, seed, total).save(run / "config.json")
    (run / "eval.csv").write_text(f"step,wall_s,episodes,success\n{steps},600.0,100,0.5\n")
    shutil.copyfile(TRAINED_DIR / f"deck1_{algo}.npz", run / "actor_best.npz")
    digest = hashlib.sha256((run / "actor_best.npz").read_bytes()).hexdigest()
    record = {"actor_sha256": digest, "episodes": 100, "seed": 100_000, "success": success, "collision": 1 - success,
              "path_ratio": 1.1, "turning_deg": turning, "selected_at_step": steps,
              "goal_each": goal_each or [int(i < round(100 * success)) for i in range(100)]}
    (run / held_out_file(100)).write_text(json.dumps(record))


def test_reward_runs_give_means_intervals_and_the_paired_ablation(tmp_path, make_results):
    for seed, (m, d) in enumerate([(0.9, 0.8), (0.92, 0.8), (0.94, 0.82)]):
        _run(tmp_path, "mddpg", seed, m, 200.0)
        _run(tmp_path, "ddpg", seed, d, 150.0)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    assert [r["seed"] for r in runs["mddpg"]] == [0, 1, 2]
    # an algorithm without run folders is read from the logs shipped beside its reward-regime actor, if any
    shipped = {a for a in ("dqn", "a2c") if (shipped_log_dir(f"{a}-reward", "deck1") / "eval.csv").exists()}
    assert set(runs) == {"mddpg", "ddpg", *shipped}
    text = "\n".join(make_results.reward_section({"deck1": runs}, {"deck1": 1_000_000}, 100, ["deck1"]))
    # MDDPG: 90, 92, 94 -> mean 92, sd 2, t(2) 4.303 -> +- 4.97
    assert "| deck1 | mddpg | 3: 0, 1, 2 (1,000,000) | 30 min | 92.0 (87.0 to 97.0) | 90, 92, 94 | 98 |" in text
    # differences 10, 12, 12 points: mean 11.3, sd 1.15, half-width 2.87; every episode MDDPG wins is one DDPG
    # lost, so the bootstrap over seeds and episodes lies above zero too
    assert "mddpg - ddpg, success paired over seeds 0, 1, 2: +11.3 points, mddpg ahead (95 % interval +8.5 to " \
           "+14.2 points over seeds; +" in text
    assert "MDDPG turns more than DDPG (200 against 150 deg" in text
    targets = "\n".join(make_results.targets(_NoShipped(), {"deck1": runs}))
    assert "on deck1: 92.0 % (mean of 3 seed(s)) against the target of 90 % and the paper's 98 %: met." in targets
    assert "MDDPG from the reward alone on deck2: no run yet" in targets
    assert "MDDPG from the reward alone on square: no run yet (no target: the paper reports the decks only" in targets
    runs["mddpg"][2]["finished"] = False  # a seed still training: no verdict yet, and the mean of the others
    assert "on deck1: 91.0 % (mean of the 2 finished seed(s) of 3) against the target of 90 % and the paper's " \
        "98 %: not decided: 3 seed(s), 2 finished" in "\n".join(make_results.targets(_NoShipped(), {"deck1": runs}))
    for r in runs["mddpg"]:
        r["finished"] = False
    assert "on deck1: no seed finished yet" in "\n".join(make_results.targets(_NoShipped(), {"deck1": runs}))


def test_a_seed_still_training_is_shown_but_left_out_of_the_comparisons(tmp_path, make_results):
    for seed, (m, d) in enumerate([(0.9, 0.8), (0.92, 0.8), (0.94, 0.3)]):
        _run(tmp_path, "mddpg", seed, m, 200.0)
        _run(tmp_path, "ddpg", seed, d, 150.0 if seed < 2 else 900.0, steps=200_000 if seed == 2 else 1_000_000)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    assert [r["finished"] for r in runs["ddpg"]] == [True, True, False]
    text = "\n".join(make_results.reward_section({"deck1": runs}, {"deck1": 1_000_000}, 100, ["deck1"]))
    row = text.split("| deck1 | ddpg |")[1].splitlines()[0]
    # the figures are the finished seeds' (a run at 200,000 steps is not the recipe's budget), the other named
    assert " 2: 0, 1 (1,000,000); seed 2 still training (last evaluated at 200,000 of 1,000,000 steps), left " \
        "out | 20 min | 80.0 (80.0 to 80.0) | 80, 80 |" in row and "900" not in row
    for r in runs["ddpg"]:  # while no seed has finished, every seed is shown
        r["finished"] = False
    row = "\n".join(make_results.reward_section({"deck1": runs}, {"deck1": 1_000_000}, 100, ["deck1"])).split(
        "| deck1 | ddpg |")[1].splitlines()[0]
    assert "3: 0, 1, 2 (200,000/1,000,000; of 1,000,000, still training)" in row and "| 80, 80, 30 |" in row
    for r, done in zip(runs["ddpg"], (True, True, False), strict=True):
        r["finished"] = done
    # seeds 0 and 1 alone: 10 and 12 points (a run at 200,000 steps is not the recipe's budget)
    assert "mddpg - ddpg, success paired over seeds 0, 1 (seed 2 still training: left out): +11.0 points" in text
    assert "MDDPG turns more than DDPG (200 against 150 deg per successful episode, means over the finished seeds)" \
        in text
    for r in runs["ddpg"]:
        r["finished"] = False
    lines = make_results.ablation_lines("deck1", runs)
    assert "- deck1: mddpg - ddpg: no seed finished for both yet (seeds 0, 1, 2 still training: left out)." in lines
    assert not any("turns" in x for x in lines)


def test_a_seed_of_the_recipe_without_an_actor_is_named_as_left_out(tmp_path, make_results):
    """A seed whose run stopped before its first evaluation (a folder without an actor), or was never started, is
    named in its row, not dropped silently (the square's reward runs ship no logs to fill it in)."""
    for seed in (0, 1):
        _run(tmp_path, "mddpg", seed, 0.6, 200.0, recipe="square-reward")
    stopped = tmp_path / "square-reward-mddpg-seed2"
    stopped.mkdir()
    load_recipe("square-reward").run("mddpg", 2).save(stopped / "config.json")
    runs = make_results.reward_runs("square", tmp_path, 100, workers=1)
    assert [r["seed"] for r in runs["mddpg"]] == [0, 1]
    row = "\n".join(make_results.reward_section({"square": runs}, {"square": 1_000_000}, 100, ["square"])).split(
        "| square | mddpg |")[1].splitlines()[0]
    assert " 2: 0, 1 (1,000,000); seed 2 with no held-out record of the recipe as it is in this checkout (not " \
        "trained here, stopped before its first evaluation, unreadable, or trained with another configuration), " \
        "left out | " in row
    lines = make_results.reward_section({"square": runs}, {"square": 1_000_000}, 100, ["square"])
    # the recipe's agents without any run, named with the command that trains them
    assert "- square: no run of `square-reward` (ddpg, dqn, a2c) with a held-out record of 100 episodes in this " \
        "checkout: `python benchmarks/learning.py --recipe square-reward --arms ddpg,dqn,a2c` trains them." in lines
    shutil.rmtree(stopped)
    (tmp_path / "square-reward-mddpg-seed1").rename(tmp_path / "elsewhere")  # seeds 1 and 2 never trained here
    runs = make_results.reward_runs("square", tmp_path, 100, workers=1)
    row = "\n".join(make_results.reward_section({"square": runs}, {"square": 1_000_000}, 100, ["square"])).split(
        "| square | mddpg |")[1].splitlines()[0]
    assert " 1: 0 (1,000,000); seeds 1, 2 with no held-out record of the recipe as it is in this checkout" in row
    assert "no held-out record" not in "\n".join(make_results.seed_table({"square": runs}, {"square": 1_000_000},
                                                                         paper=True))  # (no recipe seeds given)
    targets = "\n".join(make_results.targets(_NoShipped(), {"square": runs}))
    assert "MDDPG from the reward alone on square: 60.0 % (mean of the 1 finished seed(s) of 1; no target: the " \
        "paper reports the decks only)." in targets
    assert "on deck1" not in "\n".join(make_results.targets(_NoShipped(), {"square": runs}, ("square",)))
    runs["mddpg"] += [{**runs["mddpg"][0], "seed": k, "finished": False} for k in (1, 2)]
    assert "on square: 60.0 % (mean of the 1 finished seed(s) of 3; no target" in "\n".join(
        make_results.targets(_NoShipped(), {"square": runs}))
    for r in runs["mddpg"]:
        r["finished"] = False
    assert "on square: no seed finished yet (no target: the paper reports the decks only): 3 seed(s), 0 finished." \
        in "\n".join(make_results.targets(_NoShipped(), {"square": runs}))
    # a scene with a reward-alone recipe and no run at all is named with all of its agents
    lines = make_results.reward_section({"square": runs}, {"square": 1_000_000}, 100, ["square", "deck2"])
    assert "- deck2: no run of `deck2-reward` (mddpg, ddpg, dqn, a2c) with a held-out record of 100 episodes in " \
        "this checkout: `python scripts/train_shipped.py --scenes deck2 --algos mddpg-reward,ddpg-reward," \
        "dqn-reward,a2c-reward --redo --episodes-per-run 100` measures each seed of the shipped file (and the " \
        "shipped agent again)." in lines


def test_seeds_that_agree_by_chance_do_not_decide_the_ablation_alone(tmp_path, make_results):
    # each seed 5 points apart, so the interval over seeds has no width, but MDDPG wins 15 episodes and loses 10 on
    # each: over seeds and episodes the difference is not separated from zero
    for seed in range(3):
        ddpg = [int(i < 80) for i in range(100)]
        mddpg = [int(i < 70 or 80 <= i < 95) for i in range(100)]
        _run(tmp_path, "mddpg", seed, 0.85, 200.0, goal_each=mddpg)
        _run(tmp_path, "ddpg", seed, 0.80, 150.0, goal_each=ddpg)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    lines = [x for x in make_results.ablation_lines("deck1", runs) if "mddpg - ddpg" in x]
    assert len(lines) == 1 and ("+5.0 points, mddpg not separated (every seed +5.0 points, no spread over seeds to "
                                "give an interval; 95 % interval -") in lines[0] and \
        "over seeds and episodes, paired by episode)" in lines[0]


def test_means_equal_at_the_printed_precision_are_called_equal(tmp_path, make_results):
    _run(tmp_path, "mddpg", 0, 0.9, 150.2)
    _run(tmp_path, "ddpg", 0, 0.8, 149.9)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    runs = {algo: [r for r in recs if r["seed"] == 0] for algo, recs in runs.items()}
    runs["mddpg"][0]["path_ratio"] = 1.0484
    runs["ddpg"][0]["path_ratio"] = 1.0476  # both print as 1.048
    text = "\n".join(make_results.ablation_lines("deck1", runs))
    assert "MDDPG turns as much as DDPG (150 against 150 deg" in text
    assert "MDDPG's paths are as long as DDPG's (1.048 against 1.048 of the shortest" in text
    # the paper's direction beside ours (deck 1: MDDPG 139.80 against DDPG 139.96 deg, 328.95 against 328.97)
    assert "; the paper's MDDPG less (139.80 against 139.96 deg)." in text
    assert "; the paper's MDDPG shorter (328.95 against 328.97 Unity units)." in text
    runs["ddpg"][0]["path_ratio"] = 1.0464
    assert "MDDPG's paths are longer than DDPG's (1.048 against 1.046" in "\n".join(
        make_results.ablation_lines("deck1", runs))
    runs["mddpg"][0]["turning_deg"] = float("nan")  # (a seed without a successful episode has no turning)
    lines = make_results.ablation_lines("deck1", runs)
    assert not any("turns" in x for x in lines) and any("paths are longer" in x for x in lines)


def test_one_seed_gives_its_episodes_interval_but_no_verdict(tmp_path, make_results):
    _run(tmp_path, "mddpg", 0, 0.9, 200.0)
    _run(tmp_path, "ddpg", 0, 0.8, 150.0)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    runs = {algo: [r for r in recs if r["seed"] == 0] for algo, recs in runs.items()}  # (not the shipped seeds)
    line = make_results.ablation_lines("deck1", runs)[0]
    assert "+10.0 points, one seed, no verdict (95 % interval +" in line and "points over episodes, paired by " \
        "episode)" in line


class _NoShipped:
    """Evaluation results with no shipped agent in them."""

    def summary(self, scene: str, agent: str) -> dict:
        raise KeyError(agent)


def test_a_scene_without_reward_runs_gives_nothing(tmp_path, make_results):
    """The square has a reward-alone recipe but no run of it here or shipped; a scene without such a recipe has
    none either."""
    assert make_results.reward_runs("square", tmp_path, 100, workers=1) == {}
    assert make_results.reward_runs("deck1-multi", tmp_path, 100, workers=1) == {}


def test_shipped_reward_runs_are_read_without_their_run_folders(tmp_path, make_results):
    """Deck 1's shipped reward-alone actors stand in for their run folders: each shipped seed's held-out record
    and training log, the runs finished."""
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    assert set(runs) >= {"mddpg", "ddpg"}
    for algo in ("mddpg", "ddpg"):
        assert all(r["finished"] and r["steps"] == 1_000_000 and len(r["goal_each"]) == 100 for r in runs[algo])


def test_the_planner_regime_gets_its_own_ablation_without_the_papers_columns(tmp_path, make_results,
                                                                             monkeypatch):
    """MDDPG against DDPG in the ``planner`` regime, read from ``deck1-planner`` run folders like the reward
    regime's; the paper's columns are left out (it learnt from the reward alone), and a scene with such a recipe
    but no measured run names the command that measures its shipped agents, or trains them where none ships."""
    for seed, (m, d) in enumerate([(0.95, 0.9), (0.96, 0.9), (0.97, 0.91)]):
        _run(tmp_path, "mddpg", seed, m, 120.0, steps=160_000, recipe="deck1-planner",
             total=160_000)
        _run(tmp_path, "ddpg", seed, d, 100.0, steps=160_000, recipe="deck1-planner",
             total=160_000)
    runs = make_results.regime_runs("deck1", "planner", tmp_path, 100, workers=1, algos=("mddpg", "ddpg"))
    assert set(runs) == {"mddpg", "ddpg"} and all(r["finished"] for r in runs["mddpg"])
    text = "\n".join(make_results.regime_section({"planner": {"deck1": runs}}, {"planner": {"deck1": 160_000}}, 100,
                                                 ["deck1", "deck2", "square"]))
    assert "### planner" in text and "the paper" not in text
    header, separator = text.split("\n")[4:6]
    assert header.count("|") == separator.count("|") == 10
    assert "| deck1 | mddpg | 3: 0, 1, 2 (160,000) | 30 min | 96.0 (93.5 to 98.5) | 95, 96, 97 | " in text
    assert "paper %" not in text and "98 |" not in text.split("| deck1 | mddpg |")[1].splitlines()[0]
    assert "deck1: mddpg - ddpg, success paired over seeds 0, 1, 2: +5.7 points" in text
    assert "- deck2: no run of `deck2-planner` (mddpg, ddpg) with a held-out record of 100 episodes in this " \
        "checkout: `python scripts/train_shipped.py --scenes deck2 --algos mddpg-planner,ddpg-planner --redo " \
        "--episodes-per-run 100` measures each seed of the shipped file (and the shipped agent again)." in text
    with monkeypatch.context() as patch:  # (where no planner agent ships, the command that trains them)
        patch.setattr(make_results, "TRAINED_DIR", tmp_path / "nothing-shipped")
        text = "\n".join(make_results.regime_section({"planner": {"deck1": runs}}, {"planner": {"deck1": 160_000}},
                                                     100, ["deck1", "deck2"]))
    assert "- deck2: no run of `deck2-planner` (mddpg, ddpg) with a held-out record of 100 episodes in this " \
        "checkout: `python benchmarks/learning.py --recipe deck2-planner --arms mddpg,ddpg` trains them." in text
    assert "square-planner" not in text  # (no such recipe)
    # one arm alone is named as missing
    only = {"deck1": {"mddpg": runs["mddpg"]}}
    text = "\n".join(make_results.regime_section({"planner": only}, {"planner": {"deck1": 160_000}}, 100, ["deck1"]))
    assert "- deck1: no run of `deck1-planner` (ddpg) with a held-out record" in text
    # a regime whose agents are shipped: the seeds of the shipped files are measured; a regime no scene has is left out
    text = "\n".join(make_results.regime_section({"oracle-teacher": {}, "planner": {}},
                                                 {"oracle-teacher": {}, "planner": {}}, 50, ["deck1", "square"]))
    assert "- deck1: no run of `deck1` (mddpg, ddpg) with a held-out record of 50 episodes in this checkout: `python " \
        "scripts/train_shipped.py --scenes deck1 --algos mddpg,ddpg --redo --episodes-per-run 50` measures each " \
        "seed of the shipped file (and the shipped agent again)." in text
    text = "\n".join(make_results.regime_section({"planner": {}}, {"planner": {}}, 100, ["square"]))
    assert "###" not in text


def test_each_regimes_recipe_and_agents_come_from_the_registry_and_the_recipes(make_results):
    """A regime's recipe on a scene is the one whose MDDPG config trains in it, and its agents are the registry's
    learned agents of that recipe: the short DQN and A2C of the oracle-teacher recipe learn from the reward too, yet
    the reward regime's recipe stays the one whose MDDPG does."""
    assert make_results.regime_agents("deck1", "reward") == (
        "deck1-reward", {"mddpg": "mddpg-reward", "ddpg": "ddpg-reward", "dqn": "dqn-reward", "a2c": "a2c-reward"})
    assert make_results.regime_agents("deck2", "planner") == (
        "deck2-planner", {"mddpg": "mddpg-planner", "ddpg": "ddpg-planner"})
    recipe, agents = make_results.regime_agents("square", "oracle-teacher")
    assert recipe == "square" and agents["mddpg"] == "mddpg" and agents["ddpg"] == "ddpg"
    assert make_results.regime_agents("square", "planner") is None
    # the agents that act otherwise through the same runs are not the regime's agents, but ship that way of acting
    assert make_results.play_agent("deck2", "reward", "mddpg", "averaged-select") == "mddpg-reward-select"
    assert make_results.play_agent("deck2", "reward", "ddpg", "averaged-select") == "ddpg-reward-select"
    assert make_results.play_agent("deck2", "reward", "mddpg", "shipped") == "mddpg-reward"
    assert make_results.play_agent("deck2", "reward", "dqn", "averaged-select") is None
    assert make_results.play_agent("deck2", "planner", "mddpg", "averaged-select") is None
    # and exist only where the recipe keeps an averaged actor: deck 1's does not, so its tables do not list them
    assert make_results.made_for("mddpg-reward-select", "deck2")
    assert make_results.made_for("ddpg-reward-select", "square")
    assert not make_results.made_for("mddpg-reward-select", "deck1")
    assert make_results.made_for("mddpg-reward", "deck1") and make_results.made_for("apf", "deck1")
    rows = make_results.provenance(["deck1", "deck2"], ["mddpg-reward-select"], 100,
                                   {"deck1": ["mddpg-reward-select"], "deck2": ["mddpg-reward-select"]})
    assert [r for r in rows if "| deck1 |" in r] == []
    assert "| mddpg-reward-select | deck2 | - | no policy shipped yet: not evaluated (n/a) | - | - | 0 |" in rows


def test_the_whole_script_writes_every_section(tmp_path):
    """``scripts/make_results.py`` end to end on one episode of one reference planner: the page holds its sections
    in order, the other regimes' included (a scene without measured runs names the command that measures them)."""
    import os
    import subprocess
    import sys

    doc = tmp_path / "doc" / "results.md"
    done = subprocess.run(
        [sys.executable, "scripts/make_results.py", "--scenes", "square", "--agents", "apf", "--episodes", "1",
         "--workers", "1", "--out", str(tmp_path / "out"), "--runs", str(tmp_path / "runs"), "--doc", str(doc)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    text = doc.read_text()
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings[:5] == ["## The paper's comparison: learnt from the reward alone",
                            "## The prediction ablation in the other regimes", "## What stands behind each number",
                            "## Tables", "## Targets"]
    assert "### oracle-teacher" in text and "### planner" not in text  # (the square has no planner recipe)
    assert "- square: no run of `square` (mddpg, ddpg) with a held-out record of 1 episodes" in text
    assert "min of evaluation (process backend; the scenes' wall times summed). Do not edit" in text
    # run again reusing the scene's evaluation: the header says whose time it quotes
    again = subprocess.run(done.args + ["--reuse"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                           env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"})
    assert again.returncode == 0, again.stderr[-2000:]
    assert "summed, those of square from the run that computed them)." in doc.read_text()


def test_runs_trained_otherwise_than_the_recipe_gives_now_are_named_not_counted(tmp_path, make_results,
                                                                                 monkeypatch):
    """A run whose configuration differs from its recipe's (the recipe changed since it was trained) stays out of
    the means and the ablation, and the section names it, the fields that differ and the command that trains it
    with the recipe as it is; shipped logs of the recipe as it is stand in for it."""
    shipped: dict[str, list] = {}
    monkeypatch.setattr(make_results, "shipped_logs", lambda agent, scene: shipped.get(agent, []))
    runs_dir = tmp_path / "runs"
    for seed in (0, 1, 2):
        _run(runs_dir, "mddpg", seed, 0.9 if seed < 2 else 0.1, 200.0)
    for seed in (0, 1):
        _run(runs_dir, "ddpg", seed, 0.8 if seed == 0 else 0.7, 150.0)
    for run in (runs_dir / "deck1-reward-mddpg-seed2", runs_dir / "deck1-reward-ddpg-seed1"):
        config = json.loads((run / "config.json").read_text())
        config["scene_overrides"] = {"episode__near_steps": 4}
        (run / "config.json").write_text(json.dumps(config))
    runs = make_results.reward_runs("deck1", runs_dir, 100, workers=1)
    assert [r["seed"] for r in runs["mddpg"]] == [0, 1] and [r["seed"] for r in runs["ddpg"]] == [0]
    off = make_results.off_recipe_runs("deck1", "reward", runs_dir, runs)
    assert {a: [(r.seed, r.folder.name, r.fields, r.run_folder) for r in v] for a, v in off.items()} == {
        "mddpg": [(2, "deck1-reward-mddpg-seed2", ["scene_overrides"], True)],
        "ddpg": [(1, "deck1-reward-ddpg-seed1", ["scene_overrides"], True)]}
    text = "\n".join(make_results.reward_section({"deck1": runs}, {"deck1": 1_000_000}, 100, ["deck1"],
                                                 {"deck1": off}))
    row = text.split("| deck1 | mddpg |")[1].splitlines()[0]
    assert " 2: 0, 1 (1,000,000); seed 2 with no held-out record of the recipe as it is" in row
    assert "| 90.0 (90.0 to 90.0) | 90, 90 |" in row and ", 10 |" not in row
    # the ablation pairs the counted seeds alone: seed 0 (90 against 80), not seed 1's 70 % run of another config
    assert "deck1: mddpg - ddpg, success paired over seed 0: +10.0 points, one seed, no verdict" in text
    line = next(x for x in text.splitlines() if "left out, trained with another configuration" in x)
    assert line.startswith("- deck1: left out, trained with another configuration than `deck1-reward` gives now")
    assert f"mddpg seed 2 (other scene_overrides; in `{runs_dir}`)" in line
    assert f"ddpg seed 1 (other scene_overrides; in `{runs_dir}`)" in line
    assert ("`python scripts/train_shipped.py --scenes deck1 --algos mddpg-reward,ddpg-reward --redo` trains them "
            f"with the recipe as it is once `{runs_dir / 'deck1-reward-mddpg-seed2'}`, "
            f"`{runs_dir / 'deck1-reward-ddpg-seed1'}` are moved away.") in line
    assert "- deck1: no run of `deck1-reward` (dqn, a2c) with" in text  # (MDDPG and DDPG have counted runs)
    # an algorithm whose every seed was trained otherwise is named there, not among those without a run; shipped
    # logs are named by their folder, and need no moving
    only_off = {"mddpg": [make_results.OffRecipe(0, tmp_path / "x", ["hidden"], False)],
                "dqn": [make_results.OffRecipe(0, tmp_path / "y", ["steps"], False)]}
    lines = make_results.lacking_lines("deck1", "reward", {"ddpg": runs["ddpg"]}, ("mddpg", "ddpg", "dqn", "a2c"),
                                       100, only_off)
    assert len(lines) == 2
    assert "mddpg seed 0 (other hidden; in `deck_sim/trained/logs/deck1_mddpg-reward`)" in lines[0]
    assert "dqn seed 0 (other steps; in `deck_sim/trained/logs/deck1_dqn-reward`)" in lines[0]
    assert lines[0].endswith("--algos mddpg-reward,dqn-reward --redo` trains them with the recipe as it is.")
    assert "- deck1: no run of `deck1-reward` (a2c) with a held-out record" in lines[1]
    # logs shipped from runs of the recipe as it is stand in for the seeds whose run folder differs
    for algo, seed, success in (("mddpg", 2, 0.95), ("ddpg", 1, 0.85)):
        _run(tmp_path / "shipped", algo, seed, success, 180.0)
        shipped[f"{algo}-reward"] = [(tmp_path / "shipped" / f"deck1-reward-{algo}-seed{seed}", seed)]
    runs = make_results.reward_runs("deck1", runs_dir, 100, workers=1)
    assert [(r["seed"], r["success"]) for r in runs["mddpg"]] == [(0, 0.9), (1, 0.9), (2, 0.95)]
    assert [(r["seed"], r["success"]) for r in runs["ddpg"]] == [(0, 0.8), (1, 0.85)]
    assert make_results.off_recipe_runs("deck1", "reward", runs_dir, runs) == {}


def test_a_shipped_agent_whose_runs_the_recipe_no_longer_gives_says_so_in_its_provenance(tmp_path, make_results,
                                                                                         monkeypatch):
    """The table of what stands behind each number names, beside a shipped agent's regime, the fields in which the
    runs shipped with it differ from what its recipe gives now."""
    import deck_sim.policies

    logs = [(shutil.copytree(folder, tmp_path / f"seed{seed}"), seed)
            for folder, seed in make_results.shipped_logs("mddpg-reward", "deck1")]
    monkeypatch.setattr(deck_sim.policies, "shipped_logs", lambda agent, scene: logs)
    assert make_results.shipped_drift("deck1", "mddpg-reward") is None
    config = json.loads((logs[1][0] / "config.json").read_text())
    config["scene_overrides"] = {"episode__near_steps": 4}
    (logs[1][0] / "config.json").write_text(json.dumps(config))
    assert make_results.shipped_drift("deck1", "mddpg-reward") == \
        "trained with other scene_overrides than `deck1-reward` gives now"
    row = next(x for x in make_results.provenance(["deck1"], ["mddpg-reward"], 100, {"deck1": []})
               if x.startswith("| mddpg-reward |"))
    assert "| reward (trained with other scene_overrides than `deck1-reward` gives now) |" in row


def test_a_seed_without_a_success_has_no_path_or_turning_and_is_named(make_results):
    """Path and turning average over successful episodes: a seed with none has no value, so the mean is over the
    other seeds and the cell says how many were left out ("-" when none has one)."""
    # 1.1 and 1.3: sd 0.141, t(1) 12.706 -> +- 1.271
    assert make_results._interval([1.1, float("nan"), 1.3], 1.0, ".3f") == \
        "1.200 (-0.071 to 2.471), 1 seed without a success left out"
    assert make_results._interval([float("nan")], 1.0, ".0f") == "-"
    assert make_results._interval([250.0, float("nan")], 1.0, ".0f") == \
        "250 (one seed), 1 seed without a success left out"
    assert make_results._interval([0.5, 0.7]) == "60.0 (0.0 to 100.0)"


def test_equal_differences_over_seeds_give_no_interval_and_no_verdict_alone(tmp_path, make_results):
    # 85 - 80, 88 - 83, 85 - 80: the same 5 points up to float rounding, so no spread to estimate an interval from
    for seed, (m, d) in enumerate([(0.85, 0.80), (0.88, 0.83), (0.85, 0.80)]):
        _run(tmp_path, "mddpg", seed, m, 200.0)
        _run(tmp_path, "ddpg", seed, d, 150.0)
    runs = make_results.reward_runs("deck1", tmp_path, 100, workers=1)
    for recs in runs.values():  # (records without each episode's success: the interval over seeds alone)
        for r in recs:
            del r["goal_each"]
    line = next(x for x in make_results.ablation_lines("deck1", runs) if "mddpg - ddpg" in x)
    assert "+5.0 points, no verdict (every seed +5.0 points, no spread over seeds to give an interval)" in line
    assert "ahead" not in line


def _record(seed: int, success: float) -> dict:
    """A finished reward-alone run's held-out record as ``regime_runs`` returns it."""
    return {"seed": seed, "success": success, "collision": 1 - success, "path_ratio": 1.1, "turning_deg": 200.0,
            "steps": 1_000_000, "finished": True, "wall_s": 600.0,
            "goal_each": [int(i < round(100 * success)) for i in range(100)]}


def test_the_runs_acting_through_their_critics_get_their_own_table_and_target_line(make_results):
    selecting = {"deck2": {"mddpg": [_record(0, 0.80), _record(1, 0.82), _record(2, 0.84)],
                           "ddpg": [_record(0, 0.70), _record(1, 0.72), _record(2, 0.74)]}}
    text = "\n".join(make_results.selecting_section(selecting, {"deck2": 1_000_000}, 100, ["deck1", "deck2"]))
    assert text.startswith("### The same runs, acting through their own critics")
    assert "critic chooses among it and 64 fixed candidates around it (0.3 action units" in text
    # 80, 82, 84: mean 82, sd 2, t(2) 4.303 -> +- 4.97; the paper's 91 % beside it
    assert "| deck2 | mddpg | 3: 0, 1, 2 (1,000,000) | 30 min | 82.0 (77.0 to 87.0) | 80, 82, 84 | 91 |" in text
    assert "- deck2: mddpg - ddpg, success paired over seeds 0, 1, 2: +10.0 points" in text
    assert "- deck1: `deck1-reward` keeps no averaged actor (`actor_average`), so its runs act only as above." in text
    assert "- deck2: no finished run with an averaged actor in this checkout: `python benchmarks/learning.py " \
           "--recipe deck2-reward --arms mddpg,ddpg` trains them." in make_results.selecting_section({}, {}, 100,
                                                                                                  ["deck2"])
    # a seed whose run is still training (it has its averaged actor only when it finishes) is named as such
    two = {"deck2": {"mddpg": selecting["deck2"]["mddpg"][:2], "ddpg": selecting["deck2"]["ddpg"]}}
    text = "\n".join(make_results.selecting_section(two, {"deck2": 1_000_000}, 100, ["deck2"],
                                                     {"deck2": {"mddpg": {2: 500_000}}}))
    assert "| deck2 | mddpg | 2: 0, 1 (1,000,000); seed 2 still training (last evaluated at 500,000 of 1,000,000 " \
           "steps), left out |" in text
    plain = {"deck2": {"mddpg": [_record(0, 0.7), _record(1, 0.7), {**_record(2, 0.7), "finished": False,
                                                                      "steps": 500_000}]}}
    assert "seed 2 still training (last evaluated at 500,000" in "\n".join(
        make_results.reward_section(plain, {"deck2": 1_000_000}, 100, ["deck2"], selecting=two))
    # the reward section carries it after its own table when asked to
    assert "### The same runs" not in "\n".join(make_results.reward_section({}, {}, 100, ["deck2"]))
    assert "### The same runs" in "\n".join(make_results.reward_section({}, {}, 100, ["deck2"], selecting={}))
    # the targets: the plain runs and the same runs acting through their critics, each its own verdict
    plain = {"deck2": {"mddpg": [_record(0, 0.70), _record(1, 0.72), _record(2, 0.74)]}}
    lines = make_results.targets(_NoShipped(), plain, ("deck2",), selecting)
    assert lines[0] == ("- MDDPG from the reward alone on deck2: 72.0 % (mean of 3 seed(s)) against the target of "
                        "80 % and the paper's 91 %: not met.")
    assert lines[1] == ("- MDDPG from the reward alone on deck2, acting through its critic: 82.0 % (mean of 3 "
                        "seed(s)) against the target of 80 % and the paper's 91 %: met.")
    assert len(make_results.targets(_NoShipped(), plain, ("deck2",))) == 1  # (no such runs: no line of their own)
