"""Does a DDPG / MDDPG run act better when its own critic picks each action around its actor's?

For each run folder, the actor and critic of its checkpoint (``training.checkpoints.checkpoint_policy``: the pair as
the run last saved them) play the same held-out episodes (``deck_sim.evaluation``: episode ``i`` reset with seed
``DEFAULT_SEED + i``, the episodes of ``docs/results.md`` and their continuation) twice: the actor alone, and with
critic-guided selection (``deck_sim.policies.selecting``: the actor proposes a, the critic picks the best of a and
``--candidates`` fixed offsets around it, ``--spread`` action units). Both learn nothing from anyone but the reward:
the critic is the run's own.

Prints, per run, success with its Wilson 95 % interval and collisions, with and without selection, and the
difference in success paired by episode with its 95 % interval (Student's t over the episodes); then, per arm (the
runs' recipe and algorithm, and its scene where the runs span several), the mean difference over its seeds
with the 95 % interval over seeds; and where the runs form one MDDPG arm and one DDPG arm of one scene that share
seeds, the difference MDDPG - DDPG paired by seed, with and without selection. Two runs of one arm with the same
seed are refused. The machine and the load average go first.

    python benchmarks/critic_select.py RUN [RUN ...] [--episodes 100] [--candidates 64] [--spread 0.3]
        [--predictors stationary] [--averaged] [--seed 100000] [--workers N]

``--seed S`` plays episodes ``S`` to ``S + episodes - 1`` instead of the held-out ones: a stream below them and apart
from the periodic evaluations' (``check_stream``), on which to decide whether selection is to be used before the
held-out episodes judge it.

With ``--averaged`` each run plays the slow average of its actor that its checkpoint keeps (``actor_average``), with
the same critic, in place of its actor ("actor" in the output is then that average).

With ``--predictors`` (other forecasts, e.g. ``stationary``: every mover held where it is now) each MDDPG run also
plays both ways with that forecast in place of its own (``forecast_use.py``'s swap), and the difference to its own
forecast, paired by episode, says how much of each way's success the forecast carries.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402
from forecast_use import with_predictor  # noqa: E402

from deck_sim.control.prediction import PREDICTOR_NAMES  # noqa: E402
from deck_sim.evaluation import DEFAULT_SEED, TRAIN_SEED_BASE, EvalConfig, evaluate  # noqa: E402
from deck_sim.metrics import mean_interval, rate_interval  # noqa: E402
from deck_sim.policies import PolicyFileError, selecting  # noqa: E402
from training.checkpoints import CheckpointError, checkpoint_policy  # noqa: E402
from training.config import TrainConfig  # noqa: E402


def play(file: Path, scene: str, episodes: int, workers: int | None,
         seed: int = DEFAULT_SEED) -> tuple[np.ndarray, np.ndarray]:
    """Per-episode success and collision (bool arrays, by episode index) of the actor file on ``episodes``
    episodes of ``scene`` from ``seed`` (default: the held-out episodes)."""
    res = evaluate(EvalConfig(agents=(f"run={file}",), scenes=(scene,), episodes=episodes, workers=workers,
                              record="none", seed=seed))
    rows = sorted(res.episodes, key=lambda r: int(r["seed"]))
    return (np.array([r["outcome"] == "goal" for r in rows]), np.array([r["outcome"] == "collision" for r in rows]))


def check_stream(parser: argparse.ArgumentParser, seed: int, episodes: int, metas: list[dict]) -> None:
    """Refuse (``parser.error``) a ``--seed`` whose ``episodes`` episodes would reach the training seeds (as the
    evaluation harness would, before anything is played), or, for a stream other than the held-out one, reach into
    the held-out episodes or into the periodic-evaluation stream that picked an actor of the runs whose actor
    records are ``metas`` (their ``config``'s ``eval_seed`` and ``eval_episodes``)."""
    last = seed + episodes - 1
    if seed < 0 or seed + episodes > TRAIN_SEED_BASE:
        parser.error(f"--seed: episodes {seed} to {last} must lie in [0, {TRAIN_SEED_BASE:,}), below the training "
                     "seeds")
    if seed == DEFAULT_SEED:
        return
    if last >= DEFAULT_SEED:
        parser.error(f"--seed: episodes {seed} to {last} reach the held-out episodes (from {DEFAULT_SEED:,}); another "
                     "stream lies below them")
    for meta in metas:
        config = meta.get("config") or {}
        first = int(config.get("eval_seed", TrainConfig.eval_seed))
        count = int(config.get("eval_episodes", TrainConfig.eval_episodes))
        if seed <= first + count - 1 and first <= last:
            parser.error(f"--seed: episodes {seed} to {last} overlap the periodic evaluations' episodes {first} to "
                         f"{first + count - 1}, which picked the runs' best actors")


def rate(success: np.ndarray, collided: np.ndarray) -> str:
    """``success 85.0% (76.7%-90.7%), collision 15.0%``."""
    k, n = int(success.sum()), len(success)
    lo, hi = rate_interval(k, n)
    return f"success {k / n:6.1%} ({lo:.1%}-{hi:.1%}), collision {collided.mean():6.1%}"


def points(values: list[float] | np.ndarray) -> str:
    """Mean and 95 % interval in points: ``+6.0 (+1.2 to +10.8)``; no interval for one value, nor for values that
    are all equal (no spread to estimate one from: said so)."""
    m, lo, hi = mean_interval(np.asarray(values, dtype=float))
    if len(values) < 2:
        return f"{100 * m:+.1f}"
    if hi - lo < 1e-9:  # (float rounding)
        return f"{100 * m:+.1f} (each the same: no spread to give an interval)"
    return f"{100 * m:+.1f} ({100 * lo:+.1f} to {100 * hi:+.1f})"


def arm_key(meta: dict, scenes: int = 1) -> tuple[str, str]:
    """(algorithm, arm label) of an actor record: the label is the run's recipe followed by its algorithm where the
    recipe's name does not hold it (``deck2-reward mddpg``; ``reward-mddpg-with-close`` as it is), or the algorithm
    alone without a recipe, with its scene when the runs compared span ``scenes`` > 1."""
    cfg, algo = meta["config"], str(meta["algo"])
    recipe = str((cfg.get("extra") or {}).get("recipe") or "")
    label = recipe if algo in recipe.split("-") else f"{recipe} {algo}".strip()
    return algo, label + (f" on {meta['scene']}" if scenes > 1 else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="DDPG or MDDPG run folders holding checkpoint.pt")
    parser.add_argument("--episodes", type=int, default=100, help="held-out episodes per run (default 100)")
    parser.add_argument("--candidates", type=int, default=64, help="candidates around the actor's action")
    parser.add_argument("--spread", type=float, default=0.3, help="their standard deviation, action units")
    parser.add_argument("--predictors", default="",
                        help="other forecasts an MDDPG run also plays with, comma-separated (e.g. stationary)")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED,
                        help=f"seed of episode 0 (default {DEFAULT_SEED}: the held-out episodes; another stream lies "
                             "below them, apart from the periodic evaluations')")
    parser.add_argument("--averaged", action="store_true",
                        help="play each run's averaged actor (runs with actor_average) in place of its actor")
    parser.add_argument("--workers", type=int, default=None, help="evaluation processes (default: the CPU count)")
    args = parser.parse_args()
    if args.episodes < 2:
        parser.error(f"--episodes must be at least 2, got {args.episodes}")
    swaps = [p for p in args.predictors.split(",") if p]
    bad = [p for p in swaps if p not in PREDICTOR_NAMES or p == "none"]
    if bad:
        parser.error(f"--predictors: expected names of {', '.join(p for p in PREDICTOR_NAMES if p != 'none')}, "
                     f"got {bad}")
    policies = {}
    for run in args.runs:
        try:
            policies[run] = checkpoint_policy(run, averaged=args.averaged)
        except (CheckpointError, PolicyFileError, ValueError) as err:
            sys.exit(f"critic_select.py: {err}")
    check_stream(parser, args.seed, args.episodes, [p.meta for p in policies.values()])
    scenes = {str(p.meta["scene"]) for p in policies.values()}
    arm_of = {run: arm_key(policy.meta, len(scenes)) for run, policy in policies.items()}
    seen: set[tuple[str, str, int]] = set()
    for run, key in arm_of.items():
        seed = int(policies[run].meta["config"]["seed"])
        if (*key, seed) in seen:
            parser.error(f"two runs of {key[1]} with seed {seed}: give each arm's seeds once")
        seen.add((*key, seed))
    print(machine())
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (1 min)")
    print(f"selection: the actor's action and {args.candidates} candidates around it, spread {args.spread}; "
          f"{args.episodes} " + ("held-out episodes" if args.seed == DEFAULT_SEED else
                                 f"episodes from seed {args.seed} (not the held-out ones)") + " per run"
          + ("; each run's averaged actor" if args.averaged else ""))
    results: dict[Path, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, run in enumerate(args.runs):
            policy = policies[run]
            scene, step = str(policy.meta["scene"]), int(policy.meta["trained_steps"])
            plain, chosen = Path(tmp) / f"a{i}.npz", Path(tmp) / f"s{i}.npz"
            policy.save(plain)
            selecting(policy, args.candidates, args.spread).save(chosen)
            results[run] = {"actor": play(plain, scene, args.episodes, args.workers, args.seed),
                            "select": play(chosen, scene, args.episodes, args.workers, args.seed)}
            (sa, ca), (ss, cs) = results[run]["actor"], results[run]["select"]
            print(f"\n{run} ({policy.meta['algo']}, scene {scene}, checkpoint at step {step:,})")
            print(f"  actor   {rate(sa, ca)}")
            print(f"  select  {rate(ss, cs)}; minus the actor: {points(ss.astype(float) - sa.astype(float))} points",
                  flush=True)
            for predictor in (swaps if policy.predictor != "none" else []):
                for mode, file in (("actor", plain), ("select", chosen)):
                    swapped = with_predictor(file, predictor, Path(tmp) / f"{mode}{i}_{predictor}.npz")
                    sp, cp = play(swapped, scene, args.episodes, args.workers, args.seed)
                    own = results[run][mode][0]
                    print(f"  {mode:<7} with {predictor} forecasts: {rate(sp, cp)}; minus its own forecast: "
                          f"{points(sp.astype(float) - own.astype(float))} points", flush=True)
    arms: dict[tuple[str, str], dict[int, dict[str, float]]] = {}  # (algo, arm) -> seed -> success by mode
    for run, r in results.items():
        arms.setdefault(arm_of[run], {})[int(policies[run].meta["config"]["seed"])] = {
            k: float(v[0].mean()) for k, v in r.items()}
    print()
    for (_, arm), seeds in arms.items():
        gains = [s["select"] - s["actor"] for s in seeds.values()]
        print(f"{arm}: selection minus the actor over seeds {', '.join(map(str, seeds))}: {points(gains)} points")
    mddpg = [seeds for (algo, _), seeds in arms.items() if algo == "mddpg"]
    ddpg = [seeds for (algo, _), seeds in arms.items() if algo == "ddpg"]
    if len(mddpg) == 1 and len(ddpg) == 1 and len(scenes) == 1:  # (one arm of each on one scene: the ablation)
        shared = sorted(set(mddpg[0]) & set(ddpg[0]))
        for mode in ("actor", "select"):
            if shared:
                diff = [mddpg[0][s][mode] - ddpg[0][s][mode] for s in shared]
                print(f"mddpg - ddpg ({mode}), paired over seeds {', '.join(map(str, shared))}: {points(diff)} points")
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (1 min)")


if __name__ == "__main__":
    main()
