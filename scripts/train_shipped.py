"""Train the MDDPG policies shipped in ``deck_sim/trained/`` and measure them on held-out episodes.

For each scene: one ``deck-sim train --algo mddpg --preset tuned`` run (``training.loop.Trainer``) in
``--out/<scene>-tuned-mddpg-seed<seed>`` (the folder ``benchmarks/learning.py`` reads for that arm), resumed if a
checkpoint is there; the actor with the best periodic held-out
evaluation (seed-500 stream) is then measured on ``--episodes`` further held-out episodes, the stream of
``deck-sim run --scene <scene> --policy mddpg --seed 1000`` (never a training, demonstration or selection
episode), and copied to ``deck_sim/trained/<scene>_mddpg.npz`` (weights only, a few hundred KiB). The figures go to
``deck_sim/trained/README.md``, written by this script, never by hand.

Long work: run it in the background (``nohup python scripts/train_shipped.py > train.log &``), never in tests.

    python scripts/train_shipped.py [--scenes deck1,deck2,square] [--steps 60000] [--seed 0] [--episodes 200]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.metrics import summarize  # noqa: E402
from deck_sim.policies import TRAINED_DIR, LearnedPolicy  # noqa: E402
from deck_sim.rollout import run_episode  # noqa: E402
from training.config import TrainConfig, arm_config  # noqa: E402
from training.loop import Trainer  # noqa: E402

HELD_OUT_SEED = 1000


def held_out(actor: Path, scene: str, episodes: int) -> dict[str, float]:
    """The actor on ``episodes`` consecutive episodes of ``deck_sim.load(scene, seed=1000)``."""
    policy = LearnedPolicy.load(actor)
    env = deck_sim.load(scene, seed=HELD_OUT_SEED, episode__predictor=policy.predictor)
    return summarize([run_episode(env, policy, episode=k) for k in range(episodes)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--steps", type=int, default=60_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=200, help="held-out episodes per scene (seed 1000)")
    parser.add_argument("--out", default="runs/learning", help="run folders (shared with benchmarks/learning.py)")
    parser.add_argument(
        "--evaluate-only",
        action="store_true",
        help="measure the shipped files again (no training)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="TrainConfig overrides")
    args = parser.parse_args()
    fields = {}
    for item in args.set:
        k, _, v = item.partition("=")
        fields[k] = json.loads(v)
    TRAINED_DIR.mkdir(exist_ok=True)
    report_path = TRAINED_DIR / "results.json"
    for scene in args.scenes.split(","):
        run = Path(args.out) / f"{scene}-tuned-mddpg-seed{args.seed}"  # benchmarks/learning.py's folder for it
        cfg = TrainConfig.from_dict({**arm_config("tuned-mddpg", scene, args.steps, args.seed).to_dict(), **fields})
        dest = TRAINED_DIR / f"{scene}_mddpg.npz"
        if args.evaluate_only:
            if not dest.exists():
                raise SystemExit(f"--evaluate-only: no shipped policy {dest}")
        elif not (run / "actor.npz").exists():
            resume = (run / "checkpoint.pt").exists()
            print(
                f"training mddpg on {scene} ({args.steps} steps) in {run}" + (" (resuming)" if resume else ""),
                flush=True,
            )
            Trainer(cfg, run, resume=resume).train()
        if not args.evaluate_only:
            shutil.copyfile(run / "actor_best.npz", dest)
        t0 = time.perf_counter()
        summary = held_out(dest, scene, args.episodes)
        meta = LearnedPolicy.load(dest).meta
        wall = _train_wall(run) if (run / "eval.csv").exists() else float("nan")
        # read just before writing: another scene's run may have finished meanwhile
        report = json.loads(report_path.read_text()) if report_path.exists() else {}
        report[scene] = {
            "episodes": args.episodes,
            "held_out_seed": HELD_OUT_SEED,
            "success": summary["goal_rate"],
            "collision": summary["collision_rate"],
            "timeout": summary["timeout_rate"],
            "off_surface": summary["off_surface_rate"],
            "mean_reward": summary["mean_reward"],
            "path_ratio": summary["path_ratio"],
            "turning_angle_deg": summary["turning_angle_deg"],
            "train_steps": int(meta["config"]["total_steps"]),
            "selected_at_step": int(meta["trained_steps"]),
            "git_commit": str(meta.get("git_commit", "")),
            "train_wall_s": wall,
            "seed": args.seed,
            "file_kib": dest.stat().st_size / 1024,
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        }
        print(
            f"{scene}: held-out success {100 * summary['goal_rate']:.1f} % over {args.episodes} episodes "
            f"(evaluated in {time.perf_counter() - t0:.0f} s); wrote {dest}",
            flush=True,
        )
        report_path.write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
        write_readme(report)


def _train_wall(run: Path) -> float:
    import csv

    with open(run / "eval.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return float(rows[-1]["wall_s"]) if rows else float("nan")


def write_readme(report: dict[str, dict]) -> None:
    lines = [
        "# Shipped policies",
        "",
        "MDDPG actors (weights only, `deck_sim.policies.LearnedPolicy`), written by `python scripts/train_shipped.py`;",
        "this page is written by that script too. Held-out: consecutive episodes of `deck_sim.load(scene, seed=1000)`,",
        "the stream of `deck-sim run --scene <scene> --policy mddpg --seed 1000` (never a training, demonstration or",
        "model-selection episode).",
        "",
        "| scene | held-out episodes | success | collision | timeout | left the deck | mean reward | path / straight |"
        " turning angle | training steps | training time |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, r in sorted(report.items()):
        lines.append(
            f"| {scene} | {r['episodes']} | {100 * r['success']:.1f} % | {100 * r['collision']:.1f} % | "
            f"{100 * r['timeout']:.1f} % | {100 * r['off_surface']:.1f} % | {r['mean_reward']:.1f} | "
            f"{r['path_ratio']:.3f} | {r['turning_angle_deg']:.1f} deg | {r['train_steps']} | "
            f"{r['train_wall_s'] / 60:.0f} min |"
        )
    (TRAINED_DIR / "README.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
