"""Control-step speed of every scene against the raw ``mujoco.mj_step`` floor, measured in one run.

For each scene: run the composer environment with a seeded random policy (forward-biased so episodes last) and
time every ``env.step`` (resets are timed apart); right after each, time raw
``mujoco.mj_step(model, data, nstep=substeps)`` from the same starting state on the same compiled model. Prints
control steps per second, the ratio to the raw floor, the real-time factor (simulated seconds per wall second),
the machine and its load average over the last minute after each scene (other jobs on a shared machine slow
Python more than MuJoCo, so quote the load with the figures). Single-threaded (OMP/MKL threads pinned to 1).
A multi-aircraft scene (``deck1-multi``) gives every aircraft its own random walk; when its single-aircraft scene
was measured in the same run, the ratio of their median steps is printed after the table.

    python benchmarks/step_speed.py [--scenes deck1,deck2,square] [--steps 2000] [--predictor constant_velocity]
                                    [--repeat 1]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import time  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402


def bench_scene(name: str, steps: int, predictor: str, seed: int = 0) -> dict[str, float]:
    """Time ``steps`` control steps of scene ``name``, each paired with a raw step from the same state.

    Every timed ``env.step`` starts from a state copied just before it; right after, raw
    ``mj_step(nstep=substeps)`` runs from that copy on the same compiled model. Pairing the two in time keeps
    machine load from skewing their ratio.
    """
    env = deck_sim.load(name, seed=seed, episode__predictor=predictor)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    env.reset()
    reset_times = [time.perf_counter() - t0]
    m, d = env.physics.model.ptr, env.physics.data.ptr
    n_sub = env.task.n_substeps
    period = env.task.spec.episode.control_period
    snap, work = mujoco.MjData(m), mujoco.MjData(m)
    step_times, raw_times = [], []
    k = env.task.spec.agents.count
    action = np.tile([0.8, 0.0], (k, 1))
    for i in range(steps + 50):
        # a smooth random walk of actions, biased forward, so that episodes last
        action = np.clip(0.8 * action + 0.2 * rng.uniform(-1, 1, (k, 2)) + np.array([0.1, 0.0]), -1, 1)
        mujoco.mj_copyData(snap, m, d)
        t0 = time.perf_counter()
        ts = env.step(action[0] if k == 1 else action)
        dt = time.perf_counter() - t0
        mujoco.mj_copyData(work, m, snap)
        t0 = time.perf_counter()
        mujoco.mj_step(m, work, nstep=n_sub)
        raw = time.perf_counter() - t0
        if i >= 50:
            step_times.append(dt)
            raw_times.append(raw)
        if ts.last():
            t0 = time.perf_counter()
            env.reset()
            reset_times.append(time.perf_counter() - t0)
    step = float(np.median(step_times))
    floor = float(np.median(raw_times))
    mean = float(np.mean(step_times))
    return {
        "step_ms": step * 1e3,
        "mean_step_ms": mean * 1e3,
        "steps_per_s": 1.0 / step,
        "raw_ms": floor * 1e3,
        "ratio": step / floor,
        "ratio_mean": mean / float(np.mean(raw_times)),
        "realtime": period / step,
        "realtime_mean": period / mean,
        "reset_ms": float(np.median(reset_times)) * 1e3,
        "substeps": n_sub,
        "timestep": float(m.opt.timestep),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--predictor", default="constant_velocity")
    parser.add_argument("--repeat", type=int, default=1, help="measure each scene this many times (one row each)")
    args = parser.parse_args()
    print(f"machine: {machine(mujoco=mujoco.__version__)}")
    print(
        f"predictor: {args.predictor}; medians over {args.steps} control steps; raw floor = mj_step(nstep=substeps) "
        "from the same states"
    )
    print("median over steps; (mean) includes the rare steps where movers replan their routes")
    header = (
        f"{'scene':12s} {'dt':>7s} {'sub':>4s} {'step ms':>8s} {'steps/s':>8s} {'raw ms':>7s} {'x raw':>6s} "
        f"{'(mean)':>7s} {'x realtime':>10s} {'(mean)':>7s} {'reset ms':>9s} {'load':>5s}"
    )
    print(header)
    medians: dict[str, list[float]] = {}
    for name in [n for n in args.scenes.split(",") for _ in range(args.repeat)]:
        r = bench_scene(name, args.steps, args.predictor)
        medians.setdefault(name, []).append(r["step_ms"])
        print(
            f"{name:12s} {r['timestep']:7.4f} {r['substeps']:4.0f} {r['step_ms']:8.3f} {r['steps_per_s']:8.0f} "
            f"{r['raw_ms']:7.3f} {r['ratio']:6.2f} {r['ratio_mean']:7.2f} {r['realtime']:10.0f} "
            f"{r['realtime_mean']:7.0f} {r['reset_ms']:9.1f} {os.getloadavg()[0]:5.2f}"
        )
    for name, times in medians.items():
        single = name.removesuffix("-multi")
        if single != name and single in medians:
            k = deck_sim.load_scene(name).agents.count
            ratio = float(np.median(times)) / float(np.median(medians[single]))
            print(f"{name} ({k} aircraft) / {single} (one): median control step {ratio:.2f}x")


if __name__ == "__main__":
    main()
