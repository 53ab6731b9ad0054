"""Learning curves on a scene for the recipes compared in the README: plain DDPG (the paper's recipe), DDPG with the
switches that pay (current positions only), MDDPG with them (MPC prediction in the observation), and ablations.

Each arm is one ``deck-sim train`` run (``training.loop.Trainer``) in ``--out/<arm>-seed<s>``; its held-out
evaluations (``eval.csv``: seed 500 stream, never a training episode) give the curves. Prints a table of the final
held-out success, collision and timeout rates, mean reward, environment steps and training wall-clock time per
arm, with the machine; plots success and mean episode reward against environment steps and wall-clock time.

    python benchmarks/learning.py [--scene deck1] [--steps 40000] [--arms paper-ddpg,tuned-ddpg,tuned-mddpg]
                                  [--seeds 0] [--out runs/learning] [--jobs 1] [--plot docs/learning_deck1.png]

Arms: ``<preset>-<algo>`` (``paper-ddpg``, ``tuned-ddpg``, ``tuned-mddpg``, ``paper-mddpg``) or an ablation of the
tuned MDDPG recipe, ``tuned-mddpg-no-<switch>`` with switch one of ``training.config.ABLATIONS``. With ``--recipe
NAME`` the arms are training algorithms (default all the recipe trains: ``mddpg,ddpg,dqn,a2c``) of that recipe file
(``training.recipes``), with its steps, seeds and evaluations unless given (DQN and A2C: its ``[sb3]`` table), in
``--out/<recipe>-<algo>-seed<s>``: the folders of ``scripts/train_shipped.py``, so one set of runs serves both. An
arm whose run folder already holds a finished run is read back, not retrained (delete the folder to rerun it); one
with a checkpoint is resumed. ``--no-train`` reports the runs as they stand (an unfinished run by its latest
evaluation) and trains nothing. ``--jobs N`` trains up to N runs at once, each in its own process with its progress
in ``<run folder>.log``; a run's numbers do not depend on it.

The seed-500 stream also picks each run's best actor, which flatters it; so with ``--recipe`` (or ``--held-out N``)
a second table measures the actor each run ships on the held-out episodes of ``docs/results.md`` (seeds 100000
+ i; ``training.heldout``, cached in the run folder as ``heldout_<N>.json``), with success, collisions, path ratio and
turning angle: the figures the regimes and the paper's tables are compared by.

With ``--shipped`` (recipe mode) a seed whose run folder holds no evaluation and no checkpoint is read from the
logs shipped beside the recipe's agent in ``deck_sim/trained`` (``deck_sim.policies.shipped_logs``: ``eval.csv``,
``config.json`` and the cached ``heldout_<N>.json``) when that run was trained with the configuration this command
would train, not trained again: the tables of runs that finished on other machines, once
``scripts/train_shipped.py`` shipped them.

Beside each arm's mean over seeds, each table gives the 95 % interval of its success over seeds (Student's t, clipped
to 0-100 %). For every pair of arms that differ only in ``mddpg`` against ``ddpg`` (the prediction ablation), and
for each neighbour pair of the paper's ranking MDDPG > DDPG > DQN > A2C in recipe mode, it prints the difference of
their success, paired by seed, with its 95 % interval over the seeds both have; on the held-out episodes also the
interval of a bootstrap over seeds and episodes, every run playing the same episodes
(``deck_sim.metrics.paired_bootstrap_interval``), which carries the episodes' sampling noise that the interval over
a few seeds' means can miss.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import multiprocessing.connection  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from multiprocessing import resource_tracker  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from deck_sim.evaluation import DEFAULT_SEED  # noqa: E402
from deck_sim.metrics import mean_interval, paired_bootstrap_interval  # noqa: E402
from training.config import ConfigError, arm_config  # noqa: E402
from training.loop import Trainer  # noqa: E402
from training.recipes import config_differences, load_recipe  # noqa: E402


def read_eval(run: Path) -> list[dict[str, float]]:
    with open(run / "eval.csv", newline="") as f:
        # (columns added since a run was logged, such as ``polished``, are empty in its older rows)
        return [{k: float(v) if v else 0.0 for k, v in r.items()} for r in csv.DictReader(f)]


def main(argv: list[str] | None = None) -> None:
    """The command: ``argv`` its arguments (default: the command line's)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=None, help="the scene (default deck1, or the recipe's)")
    parser.add_argument("--recipe", default=None, help="arms are training algorithms of this recipe file")
    parser.add_argument("--steps", type=int, default=None, help="environment steps per run (default 40000, or "
                        "the recipe's)")
    parser.add_argument("--arms", default=None,
                        help="comma-separated (default paper-ddpg,tuned-ddpg,tuned-mddpg; with --recipe every "
                             "algorithm it trains: mddpg,ddpg, and dqn,a2c where it has an [sb3] table)")
    parser.add_argument("--seeds", default=None, help="comma-separated training seeds (default 0, or the recipe's)")
    parser.add_argument("--eval-every", type=int, default=None, help="default 5000, or the recipe's")
    parser.add_argument("--eval-episodes", type=int, default=None, help="default 50, or the recipe's")
    parser.add_argument("--out", default="runs/learning")
    parser.add_argument("--no-train", action="store_true", help="report the runs as they stand; train nothing")
    parser.add_argument("--held-out", type=int, default=None,
                        help="also measure each run's shipped actor on this many held-out episodes of "
                             "docs/results.md, cached in the run folder (default 100 with --recipe, else 0)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="train up to this many runs at once, each in its own process with its progress in "
                             "<run folder>.log (default 1: one after another, progress here)")
    parser.add_argument("--plot", default=None, help="PNG of the curves (default <out>/learning_<scene>.png)")
    parser.add_argument("--shipped", action="store_true",
                        help="with --recipe: read a seed whose run folder is not here from the logs shipped beside "
                             "the recipe's agent in deck_sim/trained (same configuration), rather than train it")
    args = parser.parse_args(argv)
    hear_ctrl_c()
    if args.jobs < 1:
        raise SystemExit(f"--jobs must be at least 1, got {args.jobs}")
    try:
        recipe = load_recipe(args.recipe) if args.recipe else None
    except ConfigError as err:
        raise SystemExit(str(err)) from err
    if args.shipped and recipe is None:
        raise SystemExit("--shipped reads the logs shipped with a recipe's agents: give --recipe")
    if recipe is not None and args.scene not in (None, recipe.scene):
        raise SystemExit(f"--recipe {recipe.name} trains on {recipe.scene}; drop --scene {args.scene}")
    scene = recipe.scene if recipe is not None else (args.scene or "deck1")
    if args.held_out is None:
        args.held_out = 100 if recipe is not None else 0
    print(machine(torch=torch.__version__))
    arms = (args.arms or (",".join(recipe.algos) if recipe else "paper-ddpg,tuned-ddpg,tuned-mddpg")).split(",")
    if recipe is not None and not set(arms) <= set(recipe.algos):
        raise SystemExit(f"--arms with --recipe {recipe.name}: training algorithms, some of {', '.join(recipe.algos)}")
    seeds_given = [int(s) for s in args.seeds.split(",")] if args.seeds else None
    curves: dict[str, list[list[dict[str, float]]]] = {}
    seeds_of: dict[str, list[int]] = {}
    runs_of: dict[str, list[tuple[int, Path]]] = {}
    unfinished = []
    prefix = recipe.name if recipe else scene
    planned = [(arm, seed, Path(args.out) / f"{prefix}-{arm}-seed{seed}")
               for arm in arms for seed in (seeds_given or (list(recipe.seeds(arm)) if recipe else [0]))]
    to_train = []
    source = (shipped_sources(recipe, planned, lambda arm, seed: run_config(recipe, arm, scene, seed, args))
              if args.shipped else {})
    for arm, seed, run in planned:
        if (arm, seed) in source:
            print(f"{run.name}: read from the shipped logs {source[arm, seed]}", flush=True)
            continue
        if not (run / "actor.npz").exists() and not args.no_train:
            try:
                cfg = run_config(recipe, arm, scene, seed, args)
            except ValueError as err:
                raise SystemExit(str(err)) from err
            resume = (run / ("model.zip" if isinstance(cfg, dict) else "checkpoint.pt")).exists()
            to_train.append((arm, seed, run, cfg, resume))
    train_runs(to_train, args.jobs)
    for arm, seed, run in planned:
        run = source.get((arm, seed), run)
        if not (run / "eval.csv").exists() or not read_eval(run):
            print(f"{run}: no evaluation yet, left out", flush=True)
            continue
        if not (run / "actor.npz").exists() and (arm, seed) not in source:  # (only finished runs are shipped)
            unfinished.append(f"{run.name} (at step {read_eval(run)[-1]['step']:.0f})")
        curves.setdefault(arm, []).append(read_eval(run))
        seeds_of.setdefault(arm, []).append(seed)
        runs_of.setdefault(arm, []).append((seed, run))

    name = f"recipe {recipe.name}" if recipe else f"scene {scene}"
    print(f"\n{name}; periodic evaluation: episodes of the seed-500 stream (which also picks each run's best actor); "
          "last evaluation of each run")
    if unfinished:
        print(f"unfinished runs, reported at their latest evaluation: {', '.join(unfinished)}")
    print("| arm | seeds | steps | train time | eval episodes | success | success, 95 % over seeds | collision | "
          "timeout | mean reward |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    summary = {}
    for arm, runs in curves.items():
        last = [r[-1] for r in runs]
        row = {
            k: float(np.mean([x[k] for x in last]))
            for k in ("step", "wall_s", "episodes", "success", "collision", "timeout", "reward")
        }
        _, lo, hi = mean_interval([x["success"] for x in last])
        row.update(success_lo=lo, success_hi=hi, seeds=seeds_of[arm], success_each=[x["success"] for x in last])
        summary[arm] = row
        spread = f"{max(0.0, 100 * lo):.1f} to {min(100.0, 100 * hi):.1f} %" if len(runs) > 1 else "one seed"
        print(
            f"| {arm} | {len(runs)} | {row['step']:.0f} | {row['wall_s'] / 60:.1f} min | {row['episodes']:.0f} | "
            f"{100 * row['success']:.1f} % | {spread} | {100 * row['collision']:.1f} % | "
            f"{100 * row['timeout']:.1f} % | {row['reward']:.1f} |"
        )
    print_differences(summary, arms)
    if args.held_out:
        try:
            held = held_out_table(runs_of, args.held_out, set(source.values()))
        except KeyboardInterrupt:  # (each run's record is cached once measured: the next command goes on from there)
            print("\nstopped during the held-out measurement: run the command again to go on (the runs measured "
                  "so far are cached)", flush=True)
            raise SystemExit(130) from None
        print_differences(held, arms)
        for arm, row in held.items():
            summary[arm]["held_out"] = row
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"summary_{recipe.name if recipe else scene}.json").write_text(json.dumps(summary, indent=2))

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
    if axes[0].get_legend_handles_labels()[0]:  # (no legend for arms with no evaluation yet)
        axes[0].legend(loc="lower right")
    sizes = {int(x["episodes"]) for runs in curves.values() for r in runs for x in r}
    counts = " or ".join(str(n) for n in sorted(sizes))
    fig.suptitle(f"{name}: learning curves ({counts} held-out seed-500 episodes per point)")
    fig.tight_layout()
    plot = Path(args.plot) if args.plot else Path(args.out) / f"learning_{recipe.name if recipe else scene}.png"
    plot.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    print(f"wrote {plot}")


def shipped_sources(recipe: object, planned: list[tuple[str, int, Path]], plan: Callable[[str, int], object]
                    ) -> dict[tuple[str, int], Path]:
    """For ``--shipped``: the planned runs (arm, seed, run folder) to read from the logs shipped beside the
    recipe's agent in ``deck_sim/trained`` (``deck_sim.policies.shipped_logs``), each ``(arm, seed)`` with its
    logs folder: those whose run folder holds no evaluation and no checkpoint and whose shipped run was trained
    with ``plan(arm, seed)``, the configuration this command would train (``training.recipes.config_differences``)."""
    from deck_sim.agents import AGENTS, LEARNED, recipe_name, training_algo
    from deck_sim.policies import shipped_logs

    scene = recipe.scene
    logs: dict[str, dict[int, Path]] = {}
    for agent in LEARNED:  # (an agent acting otherwise than its runs' shipped actor: the same runs, not read)
        if recipe_name(agent, scene) == recipe.name and not AGENTS[agent].play:
            logs[training_algo(agent)] = {s: f for f, s in shipped_logs(agent, scene) if s is not None}
    found = {}
    for arm, seed, run in planned:
        folder = logs.get(arm, {}).get(seed)
        here = any((run / name).exists() for name in ("eval.csv", "checkpoint.pt", "model.zip"))
        if folder is None or here:
            continue
        differ = config_differences(folder, plan(arm, seed))
        if differ:
            print(f"{run.name}: the shipped run {folder} was trained with other {', '.join(differ)}; not read",
                  flush=True)
            continue
        found[arm, seed] = folder
    return found


class TrainingError(RuntimeError):
    """A run could not be trained (a bad config or checkpoint); the message names the run folder."""


def starting(arm: str, seed: int, run: Path, resume: bool) -> str:
    """The line that announces a run's training: its arm, seed and folder, and whether it resumes."""
    return f"training {arm} seed {seed} -> {run}" + (" (resuming)" if resume else "")


def train_one(cfg: object, run: Path, resume: bool, log: Path | None = None) -> bool:
    """Train (or resume from its checkpoint) one run in ``run``: a ``TrainConfig`` with ``training.loop.Trainer``,
    a dict with ``training.baselines.train_baseline`` (DQN, A2C). With ``log``, this process's standard output and
    error (the progress report) are appended to that file, as in each process of ``--jobs``. Returns whether
    Ctrl-C stopped it (even at its last step, with its actor written)."""
    if log is not None:
        stream = open(log, "a", buffering=1)  # noqa: SIM115 (held for the process's life)
        os.dup2(stream.fileno(), 1)
        os.dup2(stream.fileno(), 2)
        sys.stdout = sys.stderr = stream
        print(f"{run.name}: " + ("resuming" if resume else "starting"), flush=True)
    from training.checkpoints import CheckpointError

    try:
        if isinstance(cfg, dict):  # DQN, A2C: stable-baselines3
            from training.baselines import train_baseline

            return bool(train_baseline(**cfg, out=run, resume=resume)["stopped"])
        return bool(Trainer(cfg, run, resume=resume).train()["stopped"])
    except (ConfigError, CheckpointError) as err:
        raise TrainingError(f"{run}: {err}") from err


def _train_job(cfg: object, run: Path, resume: bool, log: Path) -> None:
    """One ``--jobs`` process: ``train_one`` with its output in ``log``, exit code 1 on a ``TrainingError``. A
    Ctrl-C that reaches it outside the trainer's loop (which stops at a checkpoint) ends it as a stopped run too:
    what it had written (checkpoints are written atomically) is where running the command again resumes."""
    try:
        # (started with SIGINT blocked, so that a Ctrl-C while this interpreter imports waits here to be taken)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        train_one(cfg, run, resume, log)
    except TrainingError as err:
        print(err, file=sys.stderr, flush=True)
        raise SystemExit(1) from err
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # (nothing is left to stop)
        print(f"{run.name}: interrupted outside the training loop; running the command again resumes it from its "
              "last checkpoint, if it has one", flush=True)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def hear_ctrl_c() -> None:
    """Make Ctrl-C (SIGINT) raise ``KeyboardInterrupt`` in this process whatever disposition it inherited: a
    script's background job starts with SIGINT ignored. The trainer stops at its checkpoint on SIGINT either way,
    so the command around it must hear it too, in every phase (demonstrations, final fit, held-out measurement),
    or a Ctrl-C sent to the group would stop the running runs and leave it starting the next ones. Called once, by
    each script's ``main``, before ``train_runs``."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def train_runs(to_train: list[tuple[str, int, Path, object, bool]], jobs: int) -> None:
    """Train the runs of ``to_train`` (arm, seed, run folder, config, resume) in order: in up to ``jobs`` processes
    at once (``train_in_parallel``) or, with one job, here one after another. A run that ends unfinished (Ctrl-C
    stopped it at its checkpoint) ends the command with code 130 before the next one starts. The caller has made
    this process hear Ctrl-C (``hear_ctrl_c``)."""
    if jobs > 1 and len(to_train) > 1:
        train_in_parallel(to_train, jobs)
        return
    for arm, seed, run, cfg, resume in to_train:
        print(starting(arm, seed, run, resume), flush=True)
        try:
            stopped = train_one(cfg, run, resume)
        except TrainingError as err:
            raise SystemExit(str(err)) from err
        except KeyboardInterrupt:  # (outside the trainer's loop: its demonstrations, its final fit)
            stopped = True
        if stopped or not (run / "actor.npz").exists():
            print(f"stopped after {run.name} finished: run the command again to go on" if (run / "actor.npz").exists()
                  else f"stopped {run.name}, unfinished: run the command again to resume it", flush=True)
            raise SystemExit(130)


def train_in_parallel(to_train: list[tuple[str, int, Path, object, bool]], jobs: int, report_every: float = 300.0
                      ) -> None:
    """Train the runs of ``to_train`` (arm, seed, run folder, config, resume) in up to ``jobs`` processes at once,
    in order, each run's progress appended to ``<run folder>.log`` beside it. Prints each start and end, and every
    ``report_every`` seconds each running run's latest progress line. Ctrl-C reaches every run, which stops at its
    next checkpoint (running the command again resumes it); this waits for them, then exits with code 130. A run
    whose process ends without its final actor (it was interrupted) is reported as stopped, not finished. Exits
    naming each run that failed, and its log, once the others have finished."""
    ctx = multiprocessing.get_context("spawn")  # (fresh interpreters: no torch state forked into the runs)
    # multiprocessing's resource tracker, started with the first process, unblocks SIGINT as it starts itself:
    # started first, it leaves the block below to every run
    resource_tracker.ensure_running()
    pending = list(to_train)
    running: list[tuple[multiprocessing.process.BaseProcess, Path, Path, float]] = []
    failed: list[str] = []
    print(f"training {len(pending)} runs, {jobs} at a time; each run's progress in <run folder>.log", flush=True)
    try:
        while pending or running:
            while pending and len(running) < jobs:
                arm, seed, run, cfg, resume = pending.pop(0)
                run.parent.mkdir(parents=True, exist_ok=True)
                log = run.parent / f"{run.name}.log"
                proc = ctx.Process(target=_train_job, args=(cfg, run, resume, log), name=run.name)
                # SIGINT blocked while the process starts: it inherits the block, so a Ctrl-C during its imports
                # stays pending until ``_train_job`` can take it, and this process takes its own once the new
                # run is among those it waits for
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
                try:
                    proc.start()
                    running.append((proc, run, log, time.monotonic()))
                    print(f"{starting(arm, seed, run, resume)}, log {log}", flush=True)
                finally:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
            ready = multiprocessing.connection.wait([p.sentinel for p, *_ in running], timeout=report_every)
            if not ready:
                for _, run, log, _ in running:
                    print(f"  {run.name}: {last_line(log)}", flush=True)
            for item in [r for r in running if r[0].sentinel in ready]:
                _report_end(*item, failed)
                running.remove(item)
    except KeyboardInterrupt:
        print("interrupted: waiting for the running runs to stop at their checkpoints (run the command again to "
              "resume them)", flush=True)
        if threading.current_thread() is threading.main_thread():  # (a second Ctrl-C would only lose the report)
            signal.signal(signal.SIGINT, lambda *_: print("still waiting for the runs to reach their checkpoints",
                                                          flush=True))
        for item in running:
            _report_end(*item, failed)
        raise SystemExit(130) from None
    if failed:
        raise SystemExit("runs that failed: " + "; ".join(failed))


def _report_end(proc: multiprocessing.process.BaseProcess, run: Path, log: Path, start: float, failed: list[str]
                ) -> None:
    """Wait for one ``--jobs`` process and print how its run ended: finished (its final actor is there), stopped
    (it ended cleanly without one: interrupted at a checkpoint) or failed (added to ``failed``)."""
    proc.join()
    minutes = (time.monotonic() - start) / 60
    if proc.exitcode == 0 and (run / "actor.npz").exists():
        print(f"finished {run.name} in {minutes:.1f} min", flush=True)
    elif proc.exitcode == 0:
        print(f"stopped {run.name} after {minutes:.1f} min, unfinished (run again to resume): {last_line(log)}",
              flush=True)
    else:
        failed.append(f"{run} (exit code {proc.exitcode}; see {log})")
        print(f"FAILED {run.name} after {minutes:.1f} min: {last_line(log)}", flush=True)


def last_line(log: Path) -> str:
    """The last non-empty line of a run's log (its latest progress report), or a note that it has none yet."""
    try:
        lines = [x for x in log.read_text(errors="replace").splitlines() if x.strip()]
    except OSError:
        lines = []
    return lines[-1].strip() if lines else "(no output yet)"


def run_config(recipe: object, arm: str, scene: str, seed: int, args: argparse.Namespace) -> object:
    """What one run trains with: with a recipe, its ``TrainConfig`` for ``mddpg`` or ``ddpg`` and the keyword
    arguments of ``training.baselines.train_baseline`` for ``dqn`` or ``a2c`` (``--steps``, ``--eval-every`` and
    ``--eval-episodes`` over it when given); else the named arm's ``TrainConfig`` (``training.config.arm_config``)."""
    if recipe is None:
        return arm_config(arm, scene, args.steps or 40_000, seed, args.eval_every or 5_000, args.eval_episodes or 50)
    given = {"eval_every": args.eval_every, "eval_episodes": args.eval_episodes}
    if arm not in ("dqn", "a2c"):  # (MDDPG and DDPG checkpoint where they evaluate)
        given["checkpoint_every"] = args.eval_every
    return recipe.run(arm, seed, args.steps, **{k: v for k, v in given.items() if v is not None})


def print_differences(summary: dict[str, dict], arms: list[str]) -> None:
    """For each pair of ``ablation_pairs``, the difference of success paired by seed, with its 95 % interval over
    the seeds both arms have (``summary[arm]``: ``seeds`` and ``success_each``); with ``goal_each`` (each seed's
    per-episode successes on the same episodes) also the bootstrap interval over seeds and episodes."""
    for with_prediction, without in ablation_pairs(arms):
        if with_prediction not in summary or without not in summary:
            continue  # (an arm with no evaluation yet)
        a, b = summary[with_prediction], summary[without]
        both = [s for s in a["seeds"] if s in b["seeds"]]
        if not both:
            continue
        diff = [a["success_each"][a["seeds"].index(s)] - b["success_each"][b["seeds"].index(s)] for s in both]
        m, lo, hi = mean_interval(diff)
        spread = ("one seed" if len(both) == 1 else
                  f"every seed {100 * m:+.1f} points, no spread over seeds to give an interval" if hi - lo < 1e-9 else
                  f"95 % interval {max(-100.0, 100 * lo):+.1f} to {min(100.0, 100 * hi):+.1f} points")
        if "goal_each" in a and "goal_each" in b:
            _, blo, bhi = paired_bootstrap_interval(
                np.array([a["goal_each"][a["seeds"].index(s)] for s in both]),
                np.array([b["goal_each"][b["seeds"].index(s)] for s in both]),
            )
            over = "seeds and episodes" if len(both) > 1 else "its episodes"
            spread += f"; over {over}, paired by episode, {100 * blo:+.1f} to {100 * bhi:+.1f} points"
        print(f"{with_prediction} - {without}: success {100 * m:+.1f} points, paired over seeds "
              f"{', '.join(map(str, both))} ({spread})")


def held_out_table(runs_of: dict[str, list[tuple[int, Path]]], episodes: int, shipped: set[Path] = frozenset()
                   ) -> dict[str, dict]:
    """Print and return each arm's runs measured on ``episodes`` held-out episodes of ``docs/results.md``
    (``training.heldout.held_out``: the actor each run ships, evaluated once and cached in the run folder; for the
    logs ``shipped`` beside an actor of ``deck_sim/trained``, which hold no actor, their cached record): the
    mean success over seeds with its 95 % interval over seeds, each seed's, collisions, path ratio and turning."""
    from training.heldout import HeldOutError, held_out, held_out_file, shipped_held_out

    whose = "the episodes of docs/results.md" if episodes == 100 else "docs/results.md's 100 and their continuation"
    if episodes < 100:
        whose = f"the first {episodes} of docs/results.md's episodes"
    print(f"\nheld-out evaluation: {episodes} episodes, seeds {DEFAULT_SEED}-{DEFAULT_SEED + episodes - 1} ({whose}), "
          "the actor each run ships (its best seed-500 evaluation, or its final fit)")
    print("| arm | seeds | actor at step | success | success, 95 % over seeds | each seed | collision | "
          "path / shortest | turning deg |")
    print("|---|---|---|---|---|---|---|---|---|")
    table = {}
    for arm, runs in runs_of.items():
        records, seeds = [], []
        for seed, run in runs:
            if run in shipped:
                record = shipped_held_out(run, episodes)
                if record is None:
                    print(f"{run}: no shipped {held_out_file(episodes)} of these episodes; left out", flush=True)
                    continue
                records.append(record)
                seeds.append(seed)
                continue
            try:
                records.append(held_out(run, episodes, per_episode=True))
                seeds.append(seed)
            except HeldOutError as err:
                print(f"{err}; left out", flush=True)
        if not records:
            continue
        each = [r["success"] for r in records]
        m, lo, hi = mean_interval(each)
        row = {"seeds": seeds, "success_each": each, "success": m, "success_lo": lo, "success_hi": hi,
               "selected_at_step": [r["selected_at_step"] for r in records],
               "goal_each": [r["goal_each"] for r in records]}
        for k in ("collision", "timeout", "path_ratio", "turning_deg", "reward"):
            row[k] = float(np.nanmean([r[k] for r in records]))
        table[arm] = row
        spread = f"{max(0.0, 100 * lo):.1f} to {min(100.0, 100 * hi):.1f} %" if len(records) > 1 else "one seed"
        print(f"| {arm} | {', '.join(map(str, seeds))} | {', '.join(str(s) for s in row['selected_at_step'])} | "
              f"{100 * m:.1f} % | {spread} | {', '.join(f'{100 * x:.0f}' for x in each)} | "
              f"{100 * row['collision']:.1f} % | {row['path_ratio']:.3f} | {row['turning_deg']:.0f} |")
    return table


PAPER_ORDER = ("mddpg", "ddpg", "dqn", "a2c")
"""The paper's ranking of the four learned agents, best first."""


def ablation_pairs(arms: list[str]) -> list[tuple[str, str]]:
    """The pairs of arms whose success difference is printed: those that differ only in ``mddpg`` against ``ddpg``
    (``reward-mddpg``, ``reward-ddpg``: the prediction ablation), and the neighbours in the paper's ranking
    (``PAPER_ORDER``) among a recipe's training algorithms."""
    ranked = [a for a in PAPER_ORDER if a in arms]
    pairs = list(zip(ranked, ranked[1:], strict=False)) if len(ranked) > 1 else []
    for arm in arms:
        parts = arm.split("-")
        if "mddpg" in parts:
            i = parts.index("mddpg")
            other = "-".join([*parts[:i], "ddpg", *parts[i + 1:]])
            if other in arms and (arm, other) not in pairs:
                pairs.append((arm, other))
    return pairs


if __name__ == "__main__":
    main()
