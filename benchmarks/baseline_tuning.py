"""Tune the DQN and A2C baselines at equal budget before their long runs: a small grid of each algorithm's own
hyperparameters over a reward-alone recipe, every variant with the same steps, seeds and held-out evaluations.

Each variant is the recipe's ``[sb3]`` run (``training/recipes/<recipe>.toml``: its observation, normalisation,
evaluation stream and, for A2C, its 8 environments), every field the grid varies at its default (``grid_base``),
with the fields of ``VARIANTS`` over it, trained by
``training.baselines.train_baseline`` in ``--out/<recipe>-<algo>-<variant>-seed<s>``. A folder with a finished run
is read back, one with a model is resumed, so the grid can be run in pieces. Prints, per variant, the mean over
seeds of the last and of the best periodic evaluation (``eval.csv``: the seed-500 stream, ``--eval-episodes``
episodes), the 95 % interval of the last over seeds, collisions, timeouts and the mean reward, best first, with the
machine; and writes ``--out/tuning_<recipe>.json``. The winner's fields go into the recipe's ``[sb3.dqn]`` or
``[sb3.a2c]`` table for the long runs (``python benchmarks/learning.py --recipe <recipe> --arms dqn,a2c``).

    python benchmarks/baseline_tuning.py [--recipe deck1-reward] [--algos dqn,a2c] [--variants recipe,lr3e-4]
                                         [--steps 300000] [--seeds 0,1] [--eval-every 50000]
                                         [--eval-episodes 100] [--out runs/tuning] [--jobs 2] [--no-train]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402
from learning import hear_ctrl_c, read_eval, train_runs  # noqa: E402

from deck_sim.metrics import mean_interval  # noqa: E402
from training.baseline_config import BASELINE_CONFIGS  # noqa: E402
from training.config import ConfigError  # noqa: E402
from training.recipes import load_recipe  # noqa: E402

VARIANTS: dict[str, dict[str, dict[str, Any]]] = {
    # DQN (training.baseline_config.DQNConfig): learning rate, target network period, exploration schedule, update
    # frequency, experience from 8 environments at once, DDPG's batch of 256 transitions and its 400 x 300 layers, and
    # the two fields that helped most at once
    "dqn": {
        "recipe": {},
        "lr3e-4": {"learning_rate": 3e-4},
        "target500": {"target_update_interval": 500},
        "explore0.1": {"exploration_fraction": 0.1},
        "freq1": {"train_freq": 1},
        "envs8": {"num_envs": 8},
        "batch256": {"batch_size": 256},
        "net400x300": {"net_arch": (400, 300)},
        "explore0.1-batch256": {"exploration_fraction": 0.1, "batch_size": 256},
    },
    # A2C (training.baseline_config.A2CConfig): rollout length, entropy bonus, learning rate, GAE, DDPG's 400 x 300
    # layers, and the two fields that helped most at once
    "a2c": {
        "recipe": {},
        "nsteps5": {"n_steps": 5},
        "nsteps64": {"n_steps": 64},
        "ent0.01": {"ent_coef": 0.01},
        "lr3e-4": {"learning_rate": 3e-4},
        "gae0.95": {"gae_lambda": 0.95},
        "net400x300": {"net_arch": (400, 300)},
        "lr3e-4-ent0.01": {"learning_rate": 3e-4, "ent_coef": 0.01},
    },
}
"""The grid: per algorithm, each variant's fields over ``grid_base`` (``recipe``: none, the base as it is)."""


def grid_base(algo: str) -> dict[str, Any]:
    """Every field that ``algo``'s grid varies, at its config's default (``training.baseline_config``): the grid
    starts from the untuned configuration even where the recipe has since taken a winner's fields, so that its runs
    and its report stay the same; the recipe's other fields (budget, evaluations, A2C's environments) stay."""
    default = BASELINE_CONFIGS[algo]()
    return {name: getattr(default, name) for fields in VARIANTS[algo].values() for name in fields}


def run_folder(out: Path, recipe: str, algo: str, variant: str, seed: int) -> Path:
    """Where one run of the grid lives."""
    return out / f"{recipe}-{algo}-{variant}-seed{seed}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recipe", default="deck1-reward", help="a reward-alone recipe with an [sb3] table")
    parser.add_argument("--algos", default="dqn,a2c")
    parser.add_argument("--variants", default=None, help="comma-separated variant names (default: all of each algo)")
    parser.add_argument("--steps", type=int, default=300_000,
                        help="environment steps per run (default: as each run of the reward preset's switches)")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--eval-every", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--out", default="runs/tuning")
    parser.add_argument("--jobs", type=int, default=1, help="runs trained at once, each in its own process "
                        "(Ctrl-C stops every run at its last step with the model saved; run again to resume)")
    parser.add_argument("--no-train", action="store_true", help="report the runs as they stand; train nothing")
    args = parser.parse_args()
    hear_ctrl_c()
    try:
        recipe = load_recipe(args.recipe)
        algos = args.algos.split(",")
        for algo in algos:
            if algo not in VARIANTS:
                raise ConfigError(f"--algos: {algo!r} is not tuned here; expected some of {', '.join(VARIANTS)}")
            recipe.seeds(algo)  # (a recipe without [sb3] is refused by name)
        seeds = [int(s) for s in args.seeds.split(",")]
    except (ConfigError, ValueError) as err:
        raise SystemExit(str(err)) from err
    if args.jobs < 1:
        raise SystemExit(f"--jobs must be at least 1, got {args.jobs}")
    wanted = args.variants.split(",") if args.variants else None
    unknown = sorted(set(wanted or ()) - {v for a in algos for v in VARIANTS[a]})
    if unknown:
        raise SystemExit(f"--variants: unknown {', '.join(unknown)}; the grid: "
                         + "; ".join(f"{a}: {', '.join(VARIANTS[a])}" for a in algos))
    print(machine(torch=torch.__version__))
    out = Path(args.out)
    to_train = []
    for algo in algos:
        for variant, fields in VARIANTS[algo].items():
            for seed in seeds if wanted is None or variant in wanted else ():
                run = run_folder(out, recipe.name, algo, variant, seed)
                if not (run / "actor.npz").exists() and not args.no_train:
                    cfg = recipe.run(algo, seed, args.steps, eval_every=args.eval_every,
                                     eval_episodes=args.eval_episodes, **{**grid_base(algo), **fields})
                    to_train.append((f"{algo} {variant}", seed, run, cfg, (run / "model.zip").exists()))
    train_runs(to_train, args.jobs)
    report: dict[str, dict[str, Any]] = {}
    for algo in algos:
        rows = []
        for variant, fields in VARIANTS[algo].items():
            if wanted is not None and variant not in wanted:
                continue
            last, best = [], []
            for seed in seeds:
                run = run_folder(out, recipe.name, algo, variant, seed)
                if not (run / "eval.csv").exists() or not read_eval(run):
                    print(f"{run}: no evaluation yet, left out", flush=True)
                    continue
                evals = read_eval(run)
                last.append(evals[-1])
                best.append(max(e["success"] for e in evals))
            if not last:
                continue
            m, lo, hi = mean_interval([e["success"] for e in last])
            row = {
                "fields": fields,
                "seeds": len(last),
                "steps": float(np.mean([e["step"] for e in last])),
                "success": m,
                "success_lo": lo,
                "success_hi": hi,
                "best": float(np.mean(best)),
                "collision": float(np.mean([e["collision"] for e in last])),
                "timeout": float(np.mean([e["timeout"] for e in last])),
                "reward": float(np.mean([e["reward"] for e in last])),
            }
            rows.append((variant, row))
        rows.sort(key=lambda r: -r[1]["success"])
        print(f"\n{algo} on recipe {recipe.name}: {args.steps:,} steps per run; seed-500 evaluations of "
              f"{args.eval_episodes} episodes; best first")
        print("| variant | fields | seeds | steps | success, last | 95 % over seeds | success, best | collision | "
              "timeout | mean reward |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for variant, row in rows:
            spread = (f"{max(0.0, 100 * row['success_lo']):.1f} to {min(100.0, 100 * row['success_hi']):.1f} %"
                      if row["seeds"] > 1 else "one seed")
            fields = ", ".join(f"{k}={v}" for k, v in row["fields"].items()) or "(the recipe's)"
            print(f"| {variant} | {fields} | {row['seeds']} | {row['steps']:.0f} | {100 * row['success']:.1f} % | "
                  f"{spread} | {100 * row['best']:.1f} % | {100 * row['collision']:.1f} % | "
                  f"{100 * row['timeout']:.1f} % | {row['reward']:.1f} |")
        report[algo] = dict(rows)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"tuning_{recipe.name}.json"
    path.write_text(json.dumps(report, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
