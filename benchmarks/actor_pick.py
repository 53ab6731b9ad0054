"""Which of a run's actors measures the run: its final weights, or those its best periodic evaluation picked?

A finished DDPG or MDDPG run without the final cloning fit leaves ``actor.npz`` (its weights at the last step) and
``actor_best.npz`` (its weights at its best evaluation on the seed-500 stream, which
``training.final_fit.shipped_actor`` ships and ``training.heldout`` measures), and with ``actor_average`` also
``actor_avg.npz``. Picking the best of a run's evaluations of 100 episodes (twenty in a 1,000,000-step run) picks
noise as well as skill. Here each run's actors play the same held-out episodes (``deck_sim.evaluation``: episode
``i`` reset with seed ``DEFAULT_SEED + i``, the episodes of ``docs/results.md``), which no pick has seen.

Prints, per run, the step the best evaluation picked and each actor's success (Wilson 95 % interval) and collisions,
and the final (and averaged) actor's success minus the picked one's, paired by episode, with its 95 % interval
(Student's t over the episodes); actors with the same weights (a run whose best evaluation was its last) play once,
a difference of zero. Then, for each of those differences, per scene and over all the runs, its mean with its 95 %
interval over the runs (Student's t) and how many runs it favours each way: the effect of the choice on a table of
runs. The machine and the load average go first.

    python benchmarks/actor_pick.py RUN [RUN ...] [--episodes 100] [--seed 100000] [--workers N]

``--seed S`` plays episodes ``S`` to ``S + episodes - 1`` instead (below the held-out ones and apart from the
periodic evaluations' that picked): a stream on which to choose a rule before the held-out episodes judge it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402
from critic_select import check_stream, play, points, rate  # noqa: E402

from deck_sim.evaluation import DEFAULT_SEED  # noqa: E402
from deck_sim.policies import LearnedPolicy, PolicyFileError  # noqa: E402

ACTORS = {"picked": "actor_best.npz", "final": "actor.npz", "averaged": "actor_avg.npz"}
"""The actors a run may leave, by the name this script prints, and their files."""


def run_actors(run: Path) -> dict[str, LearnedPolicy]:
    """The actors of a finished run that are there to choose between, by name (``ACTORS``).

    Raises:
        ValueError: the run is not finished (no ``actor.npz``), has no ``actor_best.npz``, or ends with the cloning
            fit (its final actor is the fit's, not one of its training weights).
    """
    missing = [name for name in ("actor.npz", "actor_best.npz") if not (run / name).exists()]
    if missing:
        raise ValueError(f"{run}: no {' or '.join(missing)} (a finished DDPG or MDDPG run folder has both)")
    actors = {name: LearnedPolicy.load(run / file) for name, file in ACTORS.items() if (run / file).exists()}
    if actors["final"].meta.get("polished", False):
        raise ValueError(f"{run}: its final actor is the cloning fit's, which the run ships: no pick to measure")
    return actors


def same_weights(a: LearnedPolicy, b: LearnedPolicy) -> bool:
    """Whether two actor files hold the same arrays: network, normaliser and the critic they carry (their records
    aside)."""
    return a.arrays.keys() == b.arrays.keys() and all(np.array_equal(a.arrays[k], b.arrays[k]) for k in a.arrays)


def summary(gains: dict[str, dict[str, list[float]]]) -> list[str]:
    """The lines that sum up ``gains`` (actor name -> scene -> each run's success minus the picked actor's, as
    fractions): per actor, a blank line, then per scene, and over all runs where there are several scenes, the mean
    in points with its 95 % interval over the runs and how many runs it favours each way."""
    lines = []
    for name, by_scene in gains.items():
        lines.append("")
        groups = {**by_scene, "all": [g for values in by_scene.values() for g in values]} if len(by_scene) > 1 \
            else by_scene
        for group, values in groups.items():
            ahead, behind = sum(g > 0 for g in values), sum(g < 0 for g in values)
            runs = f"{len(values)} run" + ("s" if len(values) > 1 else "")
            lines.append(f"{group}: {name} minus picked over {runs}: {points(values)} points; {name} ahead in "
                         f"{ahead}, behind in {behind}, level in {len(values) - ahead - behind}")
    return lines


def main(argv: list[str] | None = None) -> None:
    """The command: ``argv`` its arguments (default: the command line's)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished DDPG or MDDPG run folders")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per actor (default 100)")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED,
                        help=f"seed of episode 0 (default {DEFAULT_SEED}: the held-out episodes)")
    parser.add_argument("--workers", type=int, default=None, help="evaluation processes (default: the CPU count)")
    args = parser.parse_args(argv)
    if args.episodes < 2:
        parser.error(f"--episodes must be at least 2, got {args.episodes}")
    if len(set(args.runs)) != len(args.runs):
        parser.error("a run folder is given twice")
    try:
        actors = {run: run_actors(run) for run in args.runs}
    except (ValueError, PolicyFileError) as err:
        sys.exit(f"actor_pick.py: {err}")
    check_stream(parser, args.seed, args.episodes, [found["final"].meta for found in actors.values()])
    print(machine())
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (1 min)")
    where = "the held-out episodes" if args.seed == DEFAULT_SEED else "not the held-out episodes"
    print(f"{args.episodes} episodes per actor from seed {args.seed} ({where})")
    gains: dict[str, dict[str, list[float]]] = {}  # actor -> scene -> its mean minus the picked one's, by run
    for run, found in actors.items():
        scene = str(found["final"].meta["scene"])
        picked_at = int(found["picked"].meta.get("trained_steps", -1))
        final_at = int(found["final"].meta.get("trained_steps", -1))
        print(f"\n{run} ({found['final'].meta.get('algo', '?')}, scene {scene}, {final_at:,} steps; best evaluation "
              f"at step {picked_at:,})", flush=True)
        played: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for name in found:
            same = next((other for other in played if same_weights(found[name], found[other])), None)
            played[name] = played[same] if same else play(run / ACTORS[name], scene, args.episodes, args.workers,
                                                          args.seed)
            note = f" (the {same} actor's weights)" if same else ""
            print(f"  {name:<8} {rate(*played[name])}{note}", flush=True)
        for name in (n for n in found if n != "picked"):
            diff = played[name][0].astype(float) - played["picked"][0].astype(float)
            print(f"  {name} minus picked: {points(diff)} points")
            gains.setdefault(name, {}).setdefault(scene, []).append(float(diff.mean()))
    for line in summary(gains):
        print(line)
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (1 min)")


if __name__ == "__main__":
    main()
