"""Learning curves on a scene for the recipes compared in the README: plain DDPG (the paper's recipe), DDPG with the
switches that pay (current positions only), MDDPG with them (MPC prediction in the observation), and ablations.

Each arm is one ``deck-sim train`` run (``training.loop.Trainer``) in ``--out/<arm>-seed<s>``; its held-out
evaluations (``eval.csv``: seed 500 stream, never a training episode) give the curves. Prints a table of the final
held-out success, collision and timeout rates, mean reward, environment steps and training wall-clock time per
arm, with the machine; plots success and mean episode reward against environment steps and wall-clock time.

    python benchmarks/learning.py [--scene deck1] [--steps 40000] [--arms paper-ddpg,tuned-ddpg,tuned-mddpg]
                                  [--seeds 0] [--out runs/learning] [--plot docs/learning_deck1.png]

Arms: ``<preset>-<algo>`` (``paper-ddpg``, ``tuned-ddpg``, ``tuned-mddpg``, ``paper-mddpg``) or an ablation of the
tuned MDDPG recipe, ``tuned-mddpg-no-<switch>`` with switch one of ``training.config.ABLATIONS``. An arm whose
run folder already holds a finished run is read back, not retrained (delete the folder to rerun it).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from training.config import arm_config  # noqa: E402
from training.loop import Trainer  # noqa: E402


def read_eval(run: Path) -> list[dict[str, float]]:
    with open(run / "eval.csv", newline="") as f:
        # (columns added since a run was logged, such as ``polished``, are empty in its older rows)
        return [{k: float(v) if v else 0.0 for k, v in r.items()} for r in csv.DictReader(f)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="deck1")
    parser.add_argument("--steps", type=int, default=40_000)
    parser.add_argument("--arms", default="paper-ddpg,tuned-ddpg,tuned-mddpg")
    parser.add_argument("--seeds", default="0", help="comma-separated training seeds")
    parser.add_argument("--eval-every", type=int, default=5_000)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--out", default="runs/learning")
    parser.add_argument("--plot", default=None, help="PNG of the curves (default <out>/learning_<scene>.png)")
    args = parser.parse_args()
    print(machine(torch=torch.__version__))
    arms = args.arms.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    curves: dict[str, list[list[dict[str, float]]]] = {}
    for arm in arms:
        for seed in seeds:
            run = Path(args.out) / f"{args.scene}-{arm}-seed{seed}"
            if not (run / "actor.npz").exists():
                try:
                    cfg = arm_config(arm, args.scene, args.steps, seed, args.eval_every, args.eval_episodes)
                except ValueError as err:
                    raise SystemExit(str(err)) from err
                resume = (run / "checkpoint.pt").exists()
                print(f"training {arm} seed {seed} -> {run}" + (" (resuming)" if resume else ""), flush=True)
                Trainer(cfg, run, resume=resume).train()
            curves.setdefault(arm, []).append(read_eval(run))

    print(f"\nscene {args.scene}; held-out evaluation: episodes of the seed-500 stream; last evaluation of each run")
    print("| arm | seeds | steps | train time | eval episodes | success | collision | timeout | mean reward |")
    print("|---|---|---|---|---|---|---|---|---|")
    summary = {}
    for arm, runs in curves.items():
        last = [r[-1] for r in runs]
        row = {
            k: float(np.mean([x[k] for x in last]))
            for k in ("step", "wall_s", "episodes", "success", "collision", "timeout", "reward")
        }
        summary[arm] = row
        print(
            f"| {arm} | {len(runs)} | {row['step']:.0f} | {row['wall_s'] / 60:.1f} min | {row['episodes']:.0f} | "
            f"{100 * row['success']:.1f} % | {100 * row['collision']:.1f} % | {100 * row['timeout']:.1f} % | "
            f"{row['reward']:.1f} |"
        )
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"summary_{args.scene}.json").write_text(json.dumps(summary, indent=2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for arm, runs in curves.items():
        for i, every in enumerate(runs):
            kw = {"label": arm if i == 0 else None, "color": f"C{arms.index(arm)}", "marker": "o", "ms": 3}
            # the polished actor's evaluation (the final cloning fit, at the last step) is drawn as a star
            for r, style in (([x for x in every if not x.get("polished")], {}),
                             ([x for x in every if x.get("polished")], {"marker": "*", "ms": 11, "ls": "none"})):
                if not r:
                    continue
                step = [x["step"] for x in r]
                axes[0].plot(step, [100 * x["success"] for x in r], **{**kw, **style})
                axes[1].plot([x["wall_s"] / 60 for x in r], [100 * x["success"] for x in r], **{**kw, **style})
                axes[2].plot(step, [x["reward"] for x in r], **{**kw, **style})
                kw["label"] = None
    axes[0].set(xlabel="environment steps", ylabel="held-out success (%)", ylim=(-2, 102))
    axes[1].set(xlabel="training wall-clock (min, this machine)", ylabel="held-out success (%)", ylim=(-2, 102))
    axes[2].set(xlabel="environment steps", ylabel="mean episode reward (held-out)")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right")
    sizes = {int(x["episodes"]) for runs in curves.values() for r in runs for x in r}
    counts = " or ".join(str(n) for n in sorted(sizes))
    fig.suptitle(f"{args.scene}: learning curves ({counts} held-out seed-500 episodes per point)")
    fig.tight_layout()
    plot = Path(args.plot) if args.plot else Path(args.out) / f"learning_{args.scene}.png"
    plot.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot, dpi=110)
    print(f"wrote {plot}")


if __name__ == "__main__":
    main()
