"""Evaluation throughput: episodes of deck 2 with the shipped MDDPG policy, serial against a process pool.

    python benchmarks/eval_speed.py [--episodes 100] [--workers 2] [--scene deck2] [--agent mddpg] [--ray]

Both runs play the same seeded episodes (``deck_sim.evaluation``, no logs); the script checks that their results are
identical, then prints the wall time of each, the speed-up and the parallel efficiency (serial time / (workers x
parallel time)). Every run starts cold: the pool's time includes building the environment and policy (once, in the
parent, which the forked workers inherit) and starting its workers. Targets: at most 60 s for 100 episodes with
2 workers, efficiency at least 0.8. ``--ray`` adds a local Ray run.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mujoco  # noqa: E402
from common import machine  # noqa: E402

from deck_sim.evaluation import EvalConfig, clear_worker_cache, evaluate, same_results  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scene", default="deck2")
    parser.add_argument("--agent", default="mddpg")
    parser.add_argument("--chunk", type=int, default=5)
    parser.add_argument("--ray", action="store_true", help="also time a local Ray run")
    args = parser.parse_args()
    print(machine(mujoco=mujoco.__version__))
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    base = dict(agents=(args.agent,), scenes=(args.scene,), episodes=args.episodes, chunk=args.chunk, record="none")
    clear_worker_cache()
    t0 = time.perf_counter()
    serial = evaluate(EvalConfig(backend="serial", **base))
    t_serial = time.perf_counter() - t0
    steps = sum(r["steps"] for r in serial.episodes)
    rate = serial.summary(args.scene, args.agent)["goal_rate"]
    print(
        f"serial:        {args.episodes} episodes ({steps} control steps, success {100 * rate:.1f} %) in "
        f"{t_serial:.1f} s, {1000 * t_serial / steps:.2f} ms a step"
    )
    runs = [("process pool", "process")] + ([("ray", "ray")] if args.ray else [])
    for label, backend in runs:
        clear_worker_cache()  # each run builds its environment and policy once, as the serial one did
        t0 = time.perf_counter()
        par = evaluate(EvalConfig(backend=backend, workers=args.workers, **base))
        t_par = time.perf_counter() - t0
        same = same_results(par.episodes, serial.episodes)
        eff = t_serial / (args.workers * t_par)
        print(
            f"{label + ':':14s} {args.episodes} episodes with {args.workers} workers in {t_par:.1f} s: "
            f"speed-up {t_serial / t_par:.2f}x, efficiency {eff:.2f}; results identical to serial: {same}"
        )
        if not same:
            raise SystemExit(f"{label} results differ from the serial run")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
