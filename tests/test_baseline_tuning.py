"""``benchmarks/baseline_tuning.py``'s report: each variant's mean success over seeds, best first, read from run
folders without training (``--no-train``), and a bad grid refused by name."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEADER = "step,wall_s,episodes,success,collision,timeout,reward\n"
ENV = {**os.environ, "MUJOCO_GL": "disable"}


def _run(out: Path, name: str, successes: list[float]) -> None:
    run = out / name
    run.mkdir(parents=True)
    rows = [f"{50_000 * (i + 1)},60.0,100,{s},{1 - s},0.0,{100 * s}\n" for i, s in enumerate(successes)]
    (run / "eval.csv").write_text(HEADER + "".join(rows))
    (run / "actor.npz").write_bytes(b"")  # a finished run (the report reads eval.csv only)


def test_the_grid_is_reported_best_first_with_intervals_over_seeds(tmp_path):
    for seed, (base, fast) in enumerate([(0.2, 0.4), (0.3, 0.6)]):
        _run(tmp_path, f"deck1-reward-dqn-recipe-seed{seed}", [0.5, base])
        _run(tmp_path, f"deck1-reward-dqn-lr3e-4-seed{seed}", [0.1, fast])
    done = subprocess.run(
        [sys.executable, "benchmarks/baseline_tuning.py", "--algos", "dqn", "--variants", "recipe,lr3e-4",
         "--no-train", "--out", str(tmp_path)],
        cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    table = done.stdout.split("| variant |")[1].splitlines()
    # lr3e-4: last 40 and 60 -> 50 +- 12.706 * 7.07 = 89.8 (clipped); best of each run = the last
    assert table[2].startswith("| lr3e-4 | learning_rate=0.0003 | 2 | 100000 | 50.0 % | 0.0 to 100.0 % | 50.0 % |")
    # the recipe's own: last 20 and 30, but its best evaluations were 50 and 50
    assert table[3].startswith("| recipe | (the recipe's) | 2 | 100000 | 25.0 % | 0.0 to 88.5 % | 50.0 % |")
    report = json.loads((tmp_path / "tuning_deck1-reward.json").read_text())
    assert list(report["dqn"]) == ["lr3e-4", "recipe"]


def test_an_unknown_variant_or_a_recipe_without_baselines_is_refused(tmp_path):
    for args, message in ((["--variants", "lr9"], "--variants: unknown lr9"),
                          (["--recipe", "deck1-planner"], "trains MDDPG and DDPG only")):
        done = subprocess.run([sys.executable, "benchmarks/baseline_tuning.py", "--no-train", "--out", str(tmp_path),
                               *args], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=300)
        assert done.returncode != 0 and message in done.stderr, done.stderr


def test_the_grid_starts_from_the_untuned_configuration_whatever_the_recipe_has_taken_since():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import baseline_tuning

    from training.baseline_config import A2CConfig, DQNConfig
    from training.recipes import load_recipe

    recipe = load_recipe("deck1-reward")
    tuned = recipe.run("dqn", 0, 300_000)
    base = recipe.run("dqn", 0, 300_000, **baseline_tuning.grid_base("dqn"))
    assert tuned["batch_size"] != DQNConfig().batch_size  # the recipe took a winner's fields ...
    for name in ("batch_size", "exploration_fraction", "learning_rate", "net_arch", "num_envs"):
        assert base[name] == getattr(DQNConfig(), name), name  # ... the grid's base did not
    a2c = recipe.run("a2c", 0, 300_000, **baseline_tuning.grid_base("a2c"))
    assert a2c["num_envs"] == 8  # a field the A2C grid does not vary stays the recipe's
    assert (a2c["learning_rate"], a2c["ent_coef"]) == (A2CConfig().learning_rate, A2CConfig().ent_coef)
    assert a2c["eval_episodes"] == tuned["eval_episodes"] == 100
