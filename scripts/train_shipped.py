"""Train the policies shipped in ``deck_sim/trained/`` and measure them on held-out episodes.

For each scene and agent (``--algos``, default all four learned agents of the paper):

- ``mddpg`` and ``ddpg``: one ``training.loop.Trainer`` run of the scene's recipe in
  ``training.config.SHIPPED_RECIPES`` (``arm_config(recipe, ...)``; on the decks
  ``tuned-<algo>-with-data+polish+size``, 160,000 steps on deck 1 and 320,000 on deck 2) in
  ``--out/<scene>-<recipe>-seed<seed>`` (the folder ``benchmarks/learning.py`` writes for that arm). DDPG is
  MDDPG without prediction (predictor ``none``), same recipe and budget.
- ``dqn`` and ``a2c``: stable-baselines3 through ``training.baselines.train_baseline`` in
  ``--out/<scene>-<algo>-seed<seed>``, held-out evaluation every 10,000 steps on 50 episodes; the networks are
  exported to numpy (``training.baselines.export_sb3``), so the shipped files need neither stable-baselines3 nor
  ``training``.

MDDPG and DDPG of a scene train for the same number of environment steps (``SHIPPED_RECIPES``); DQN and A2C
for ``SB3_STEPS[scene]`` (the budget of the first shipped actors: 40,000 steps on deck 1 and the square, 60,000
on deck 2). The decks' DDPG recipe runs 160,000 steps (deck 1; deck 2 twice that) in about the wall-clock time
its first recipe took for 40,000, by collecting four transitions per update instead of two. ``--steps`` sets one
budget for every agent.

A run folder that already holds a checkpoint is resumed; one with a final ``actor.npz`` is not trained again. The
shipped actor (``shipped_actor``: the final actor of a recipe that ends with the cloning fit, else the one with the
best periodic held-out evaluation on the seed-500 stream) is then measured on ``--episodes`` further
held-out episodes, the stream of ``deck-sim run --scene <scene> --policy <algo> --seed 1000`` (never a training,
demonstration or selection episode), and copied to ``deck_sim/trained/<scene>_<algo>.npz`` (weights only, a few
hundred KiB). The figures go to ``deck_sim/trained/results.json`` (``{scene: {algo: figures}}``) and
``deck_sim/trained/README.md``, written by this script, never by hand, as is the table between the
``README_MARKERS`` of the project's README; the run's held-out evaluation log and
config go to ``deck_sim/trained/logs/<scene>_<algo>/`` (the learning curves of ``docs/results.md``). An agent
already shipped and measured is skipped unless ``--redo`` (or ``--evaluate-only``, which measures the shipped files
again without training).

Order: agents whose runs are finished first, then the cheap SB3 runs, then the DDPG runs, so the files land
incrementally; each is shipped as soon as it is measured. Several copies may run at once on disjoint work
(``results.json`` is updated under a file lock).

Long work: run it in the background (``nohup nice -n 10 python scripts/train_shipped.py > train.log 2>&1 &``),
never in tests.

    python scripts/train_shipped.py [--scenes deck1,deck2,square] [--algos mddpg,ddpg,dqn,a2c] [--steps N]
                                    [--seed 0] [--episodes 200] [--redo | --evaluate-only]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import csv  # noqa: E402
import fcntl  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.metrics import summarize  # noqa: E402
from deck_sim.policies import SHIPPED_ALGOS, TRAINED_DIR, LearnedPolicy, shipped_log_dir  # noqa: E402
from deck_sim.rollout import run_episode  # noqa: E402
from training.config import shipped_arm  # noqa: E402
from training.loop import shipped_actor  # noqa: E402

HELD_OUT_SEED = 1000
SB3_STEPS = {"deck1": 40_000, "deck2": 60_000, "square": 40_000}
"""Training steps of the shipped DQN and A2C agents of a scene (MDDPG and DDPG: ``SHIPPED_RECIPES``)."""
SB3_EVAL_EVERY, SB3_EVAL_EPISODES = 10_000, 50
LABELS = {"mddpg": "MDDPG", "ddpg": "DDPG (no prediction)", "dqn": "DQN", "a2c": "A2C"}
PROJECT_README = Path(__file__).resolve().parents[1] / "README.md"
README_MARKERS = ("<!-- shipped-table: start (written by scripts/train_shipped.py) -->", "<!-- shipped-table: end -->")
"""The project README's shipped-policies table lies between these two lines; ``write_readme`` rewrites it from
``results.json`` (``tests/test_baseline_export.py`` checks the two agree)."""


def held_out(actor: Path, scene: str, episodes: int) -> dict[str, float]:
    """The actor on ``episodes`` consecutive episodes of ``deck_sim.load(scene, seed=1000)``."""
    policy = LearnedPolicy.load(actor)
    env = deck_sim.load(scene, seed=HELD_OUT_SEED, **policy.scene_overrides)  # its predictor and observation
    return summarize([run_episode(env, policy, episode=k) for k in range(episodes)])


def ship_logs(run: Path, scene: str, algo: str) -> Path:
    """Copy the run's held-out evaluation log (``eval.csv``) and ``config.json`` to ``deck_sim/trained/logs/
    <scene>_<algo>/`` beside the shipped actor (a few KiB), so that ``scripts/make_results.py`` draws its learning
    curve on a checkout without the run folder."""
    logs = shipped_log_dir(algo, scene)
    if not (run / "eval.csv").exists():
        return logs
    logs.mkdir(parents=True, exist_ok=True)
    for name in ("eval.csv", "config.json"):
        (logs / name).unlink(missing_ok=True)  # nothing of an earlier shipped run may stay beside the new log
        if (run / name).exists():
            shutil.copyfile(run / name, logs / name)
    return logs


def run_folder(out: Path, scene: str, algo: str, seed: int) -> Path:
    """Where the run behind ``deck_sim/trained/<scene>_<algo>.npz`` lives."""
    if algo in ("mddpg", "ddpg"):
        return out / f"{scene}-{shipped_arm(scene, algo).recipe}-seed{seed}"  # benchmarks/learning.py's folder
    return out / f"{scene}-{algo}-seed{seed}"


def default_steps(scene: str, algo: str) -> int:
    return shipped_arm(scene, algo).steps if algo in ("mddpg", "ddpg") else SB3_STEPS.get(scene, 60_000)


def train(run: Path, scene: str, algo: str, steps: int, seed: int, fields: dict[str, Any]) -> None:
    """Train (or resume) the run unless it has finished (a final ``actor.npz``)."""
    if (run / "actor.npz").exists():
        return
    if algo in ("mddpg", "ddpg"):
        from training.config import TrainConfig, arm_config
        from training.loop import Trainer

        arm = shipped_arm(scene, algo)
        base = arm_config(arm.recipe, scene, steps, seed, eval_every=arm.eval_every, eval_episodes=arm.eval_episodes)
        cfg = TrainConfig.from_dict({**base.to_dict(), **fields})
        resume = (run / "checkpoint.pt").exists()
        print(f"training {algo} on {scene} ({steps} steps) in {run}" + (" (resuming)" if resume else ""), flush=True)
        Trainer(cfg, run, resume=resume, progress=False).train()
    else:
        from training.baselines import train_baseline

        resume = (run / "model.zip").exists()
        print(f"training {algo} on {scene} ({steps} steps) in {run}" + (" (resuming)" if resume else ""), flush=True)
        train_baseline(algo, scene, steps, seed, run, resume=resume, progress=False, eval_every=SB3_EVAL_EVERY,
                       eval_episodes=SB3_EVAL_EPISODES)


@contextlib.contextmanager
def locked_report() -> Iterator[dict[str, dict[str, dict]]]:
    """``results.json`` read and written under an exclusive lock (other copies of this script may run)."""
    path = TRAINED_DIR / "results.json"
    with open(Path(tempfile.gettempdir()) / "deck_sim_train_shipped.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        report = read_report(path)
        yield report
        write_atomic(path, json.dumps(report, indent=2, sort_keys=True) + "\n")
        write_readme(report)


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` in one step (a reader sees the old file or the new one, never half), keeping
    the file's permissions; the temporary file is removed if writing fails."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        if path.exists():
            shutil.copymode(path, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def shipped_records(report: dict[str, dict[str, dict]]) -> Iterator[tuple[str, str, dict]]:
    """``(scene, algo, record)`` in the tables' order: scenes by name, agents as in ``SHIPPED_ALGOS``."""
    order = {a: i for i, a in enumerate(SHIPPED_ALGOS)}
    for scene in sorted(report):
        for algo in sorted(report[scene], key=lambda a: order.get(a, len(order))):
            yield scene, algo, report[scene][algo]


def read_report(path: Path) -> dict[str, dict[str, dict]]:
    """``{scene: {algo: figures}}``; an older file with one MDDPG record per scene is read as such."""
    report = json.loads(path.read_text()) if path.exists() else {}
    return {scene: ({"mddpg": r} if "success" in r else r) for scene, r in report.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--algos", default=",".join(SHIPPED_ALGOS), help="agents to ship (mddpg,ddpg,dqn,a2c)")
    parser.add_argument("--steps", type=int, default=None,
                        help="training steps for every agent (default: SHIPPED_RECIPES, SB3_STEPS)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=200, help="held-out episodes per agent (seed 1000)")
    parser.add_argument("--out", default="runs/learning", help="run folders (shared with benchmarks/learning.py)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--evaluate-only", action="store_true", help="measure the shipped files again (no training)")
    mode.add_argument("--redo", action="store_true", help="copy and measure again agents already shipped")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="TrainConfig overrides (MDDPG and DDPG runs)")
    args = parser.parse_args()
    fields = {}
    for item in args.set:
        k, _, v = item.partition("=")
        fields[k] = json.loads(v)
    algos = args.algos.split(",")
    unknown = sorted(set(algos) - set(SHIPPED_ALGOS))
    if unknown:
        raise SystemExit(f"unknown agents {unknown}; expected some of {', '.join(SHIPPED_ALGOS)}")
    TRAINED_DIR.mkdir(exist_ok=True)
    out = Path(args.out)
    shipped = read_report(TRAINED_DIR / "results.json")
    work = []
    for scene in args.scenes.split(","):
        for algo in algos:
            dest = TRAINED_DIR / f"{scene}_{algo}.npz"
            if not (args.evaluate_only or args.redo) and dest.exists() and algo in shipped.get(scene, {}):
                print(f"{scene} {algo}: shipped and measured already ({dest}; --redo to measure again)", flush=True)
                continue
            run = run_folder(out, scene, algo, args.seed)
            cost = 0 if args.evaluate_only or (run / "actor.npz").exists() else 1 if algo in ("dqn", "a2c") else 2
            work.append((cost, len(work), scene, algo, run, dest))
    for _, _, scene, algo, run, dest in sorted(work):
        steps = args.steps if args.steps is not None else default_steps(scene, algo)
        if args.evaluate_only:
            if not dest.exists():
                raise SystemExit(f"--evaluate-only: no shipped policy {dest}")
        else:
            train(run, scene, algo, steps, args.seed, fields)
            tmp = dest.with_name(dest.name + ".tmp")
            shutil.copyfile(shipped_actor(run), tmp)
            os.replace(tmp, dest)
            ship_logs(run, scene, algo)
        t0 = time.perf_counter()
        summary = held_out(dest, scene, args.episodes)
        meta = LearnedPolicy.load(dest).meta
        # the training time from the log shipped with the actor (a run folder may hold a newer, unshipped run),
        # else from the run's log, else as last recorded (``--evaluate-only`` without the run folder keeps it)
        log = next((d for d in (shipped_log_dir(algo, scene), run) if (d / "eval.csv").exists()), None)
        wall = _train_wall(log) if log else float(shipped.get(scene, {}).get(algo, {}).get("train_wall_s", "nan"))
        record = {
            "algo": algo,
            "episodes": args.episodes,
            "held_out_seed": HELD_OUT_SEED,
            "success": summary["goal_rate"],
            "collision": summary["collision_rate"],
            "timeout": summary["timeout_rate"],
            "off_surface": summary["off_surface_rate"],
            "mean_reward": summary["mean_reward"],
            "path_ratio": summary["path_ratio"],
            "turning_angle_deg": summary["turning_angle_deg"],
            "predictor": str(meta.get("predictor", "none")),
            "recipe": shipped_arm(scene, algo).recipe if algo in ("mddpg", "ddpg") else f"stable-baselines3 {algo}",
            "train_steps": int(meta["config"]["total_steps"]),
            "selected_at_step": int(meta["trained_steps"]),
            "git_commit": str(meta.get("git_commit", "")),
            "train_wall_s": wall,
            "seed": args.seed,
            "file_kib": dest.stat().st_size / 1024,
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        }
        with locked_report() as report:  # read just before writing: another run may have finished meanwhile
            report.setdefault(scene, {})[algo] = record
        print(
            f"{scene} {algo}: held-out success {100 * summary['goal_rate']:.1f} % over {args.episodes} episodes "
            f"(evaluated in {time.perf_counter() - t0:.0f} s); wrote {dest}",
            flush=True,
        )


def _train_wall(run: Path) -> float:
    with open(run / "eval.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return float(rows[-1]["wall_s"]) if rows else float("nan")


def write_readme(report: dict[str, dict[str, dict]]) -> None:
    lines = [
        "# Shipped policies",
        "",
        "Weights-only actors (`deck_sim.policies.LearnedPolicy`, numpy alone), written by",
        "`python scripts/train_shipped.py`; this page is written by that script too. MDDPG and DDPG are",
        "`training.loop.Trainer` runs of the recipe in the table (`training.config.SHIPPED_RECIPES`; DDPG: the same",
        "agent, recipe and budget without the MPC prediction); DQN and A2C are stable-baselines3 runs",
        "(`training.baselines`) exported to numpy. A run that ends with the cloning fit (`polish`) ships its final,",
        "fitted actor (`training.loop.shipped_actor`); any other run, and any file shipped before that rule, the",
        "actor of its best periodic evaluation (seed-500 episodes): the column `actor` says which. Held-out:",
        "consecutive episodes of",
        "`deck_sim.load(scene, seed=1000)`, the stream of `deck-sim run --scene <scene> --policy <agent> --seed 1000`",
        "(never a training, demonstration or model-selection episode). Training time: wall-clock of the run,",
        "periodic evaluations included, while other work shared the machine; `machine` in `results.json` names",
        "the machine of the held-out measurement, which `--evaluate-only` repeats without training.",
        "",
        "| scene | agent | recipe | actor | held-out episodes | success | collision | timeout | left the deck |"
        " mean reward | path / straight | turning angle | training steps | training time |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, algo, r in shipped_records(report):
        # (records from before the recipe was written down: the first recipe of each kind of agent)
        recipe = r.get("recipe") or (f"tuned-{algo}" if algo in ("mddpg", "ddpg") else f"stable-baselines3 {algo}")
        # which actor the file is: its own record says
        polished = LearnedPolicy.load(TRAINED_DIR / f"{scene}_{algo}.npz").meta.get("polished", False)
        actor = "final, fitted" if polished else f"best evaluation ({r['selected_at_step']} steps)"
        lines.append(
            f"| {scene} | {LABELS.get(algo, algo)} | {recipe} | {actor} | {r['episodes']} | "
            f"{100 * r['success']:.1f} % | "
            f"{100 * r['collision']:.1f} % | {100 * r['timeout']:.1f} % | {100 * r['off_surface']:.1f} % | "
            f"{r['mean_reward']:.1f} | {r['path_ratio']:.3f} | {r['turning_angle_deg']:.1f} deg | "
            f"{r['train_steps']} | {r['train_wall_s'] / 60:.0f} min |"
        )
    write_atomic(TRAINED_DIR / "README.md", "\n".join(lines) + "\n")
    write_project_table(report)


def project_table(report: dict[str, dict[str, dict]]) -> list[str]:
    """The project README's shipped-policies table: held-out rates, training steps and wall-clock minutes."""
    lines = [
        "| scene | agent | success | collision | timeout | left the deck / square | training steps |"
        " training time (under load) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene, algo, r in shipped_records(report):
        lines.append(
            f"| {scene} | {LABELS.get(algo, algo)} | {100 * r['success']:.1f} % | {100 * r['collision']:.1f} % | "
            f"{100 * r['timeout']:.1f} % | {100 * r['off_surface']:.1f} % | {r['train_steps']:,} | "
            f"{r['train_wall_s'] / 60:.0f} min |"
        )
    return lines


def write_project_table(report: dict[str, dict[str, dict]], path: Path = PROJECT_README) -> bool:
    """Rewrite the table between ``README_MARKERS`` in ``path`` (atomically); without both markers, in order,
    leave the file alone, say so and return False (``results.json`` and ``deck_sim/trained/README.md`` are written
    either way)."""
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    if [text.count(m) for m in README_MARKERS] != [1, 1]:
        print(f"warning: {path} does not hold each shipped-table marker {README_MARKERS} exactly once; its table "
              "was not updated", flush=True)
        return False
    start = text.index(README_MARKERS[0]) + len(README_MARKERS[0])
    end = text.find(README_MARKERS[1], start)
    if end < 0:
        print(f"warning: {path}: the shipped-table end marker comes before its start; its table was not updated",
              flush=True)
        return False
    write_atomic(path, text[:start] + "\n" + "\n".join(project_table(report)) + "\n" + text[end:])
    return True


if __name__ == "__main__":
    main()
