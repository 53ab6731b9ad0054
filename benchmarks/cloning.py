"""How far does cloning the teacher go? Offline DAgger on the states a shipped actor visits.

    python benchmarks/cloning.py [--scene deck1] [--algo mddpg] [--states 160000] [--workers 2]
                                 [--variants plain,mirror,wide,sets] [--episodes 200] [--eval-seed 2000]
                                 [--data runs/cloning/deck1-mddpg.npz]

The shipped learners are DDPG agents taught by the scripted planner (DDPG from demonstrations with DAgger-style
relabelling, ``docs/training.md``); on deck 1 they stay several points below that teacher. This script measures,
in minutes rather than a training run's hour, whether the gap is the student's fit:

1. **Collect** ``--states`` states: the shipped ``--algo`` actor of ``--scene`` plays with Gaussian noise
   (``--noise``, the recipe's exploration), a share ``--teacher-share`` of the episodes driven by the teacher
   instead; every state is labelled with the teacher's action (the scripted planner on the MPC forecasts,
   ``training.envs.TEACHER_PREDICTOR``, as in training). Episodes are seeded at and above 7 x 10^6 (training
   seeds, never an evaluation stream), ``--workers`` processes. Cached in ``--data`` (delete it to collect anew).
2. **Fit** fresh actors to the labels by the cloning loss alone, with the trainer's own final fit
   (``DDPGAgent.polish``: minibatches of 256, Adam from 1e-3 annealed to 0 by a cosine; the normaliser fitted to
   the collected observations, as in training). Variants (``--variants``):
   - ``plain``: the shipped recipe's 400 x 300 network, 20 epochs (the recipe's ``polish_epochs``);
   - ``mirror``: the same, with every state also reflected about the surface's centre line (every planar y
     flipped, the absolute position mirrored, sizes kept) and the teacher's action reflected with it: the
     vehicles and the planner are mirror-symmetric, so this doubles the data without a new label;
   - ``wide``: 512 x 512 x 512, 40 epochs: does more capacity fit the teacher better, and does that pay?
   - ``sets``: the set actor (``actor_arch = "sets"``: one shared encoder of 128 x 128 per set of obstacles,
     max-pooled, under the 400 x 300 head), 20 epochs: does reading every mover with the same weights pay?
3. **Evaluate** the shipped actor, each fitted actor, the ensemble of the fitted actors (mean action) and that
   ensemble with the shipped actor (a shipped ensemble joins by its actors, each weighing one in the mean) on
   ``--episodes`` held-out episodes of ``deck_sim.load(scene,
   seed=--eval-seed)`` (2000: neither the training-time selection stream, 500, nor the shipped figures', 1000).

Prints one row per policy (success, collision, timeout, the fit's final training loss and time) and the machine.
Long work (on deck 1, beside two training runs: 808 s to collect 160,000 states on 2 cores, then fits of 143 s
(plain) to 737 s (wide)): a benchmark, never a test.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import multiprocessing as mp  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.metrics import summarize  # noqa: E402
from deck_sim.policies import (  # noqa: E402
    EnsemblePolicy,
    LearnedPolicy,
    Policy,
    ScriptedPolicy,
    load_actor,
    shipped_policy_path,
)
from deck_sim.rollout import run_episode  # noqa: E402
from training.config import TrainConfig  # noqa: E402
from training.ddpg import DDPGAgent  # noqa: E402
from training.envs import TEACHER_PREDICTOR  # noqa: E402

COLLECT_SEED = 7_000_000
VARIANTS = {
    "plain": {"hidden": (400, 300), "epochs": 20, "mirror": False},
    "mirror": {"hidden": (400, 300), "epochs": 20, "mirror": True},
    "wide": {"hidden": (512, 512, 512), "epochs": 40, "mirror": False},
    "sets": {"hidden": (400, 300), "epochs": 20, "mirror": False, "arch": "sets"},
}
PLANAR_Y_KEYS = {
    "target", "static_obstacles", "dynamic_obstacles", "predicted", "velocity", "static_nearest",
    "dynamic_nearest", "target_near", "static_near", "dynamic_near", "predicted_near",
}


def mirror_map(keys: tuple[str, ...], shapes: dict[str, tuple[int, ...]], bounds: np.ndarray) -> tuple:
    """The reflection of flat observations about the surface's centre line y = (ymin + ymax) / 2.

    Returns ``(index, sign, shift)`` with ``mirrored = x[..., index] * sign + shift``: every planar vector's y
    flips (relative vectors, velocity, the heading's sine, the movers' headings), the absolute position's y is
    mirrored, sizes stay, and the near field's distances to the two long edges swap. A key it does not know
    raises ``KeyError``.
    """
    index, sign, shift, start = [], [], [], 0
    centre = 0.5 * (float(bounds[0][1]) + float(bounds[1][1]))
    for k in keys:
        n = int(np.prod(shapes[k]))
        idx = np.arange(start, start + n)
        sgn, sh = np.ones(n), np.zeros(n)
        if k in PLANAR_Y_KEYS or k in ("heading", "dynamic_heading"):
            sgn[1::2] = -1.0
        elif k == "position":
            sgn[1], sh[1] = -1.0, 2.0 * centre
        elif k == "edge_near":  # x - xmin, xmax - x, y - ymin, ymax - y: the y edges swap
            idx = idx[[0, 1, 3, 2]]
        elif k != "dynamic_size":
            raise KeyError(f"observation {k!r}: no known reflection")
        index.append(idx)
        sign.append(sgn)
        shift.append(sh)
        start += n
    return np.concatenate(index), np.concatenate(sign), np.concatenate(shift)


def _collect(job: tuple[str, str, int, int, float, float]) -> tuple[np.ndarray, np.ndarray, int]:
    """One worker's states: (observations (n, dim) float32, teacher actions (n, 2) float32, episodes)."""
    scene, algo, seed, states, noise, teacher_share = job
    actor = load_actor(shipped_policy_path(algo, scene))  # one actor, or the shipped ensemble
    overrides = {**actor.scene_overrides, "episode__predictor": TEACHER_PREDICTOR}
    env = deck_sim.load(scene, seed=seed, **overrides)
    teacher = ScriptedPolicy(env)
    rng = np.random.default_rng(seed)
    xs, ys, episodes = [], [], 0
    while len(xs) < states:
        ts = env.reset()
        teacher.reset()
        by_teacher = rng.random() < teacher_share
        while not ts.last():
            obs = {k: np.asarray(v, dtype=np.float32) for k, v in ts.observation.items()}  # as training sees it
            x = actor.flatten(obs)
            label = np.clip(teacher.act(obs), -1.0, 1.0)
            xs.append(x.astype(np.float32))
            ys.append(label.astype(np.float32))
            a = label if by_teacher else np.clip(actor.act_flat(x) + noise * rng.standard_normal(2), -1.0, 1.0)
            ts = env.step(a)
        episodes += 1
    return np.asarray(xs), np.asarray(ys), episodes


@dataclass
class Fitted:
    """A fitted actor and how its fit went."""

    policy: LearnedPolicy
    loss: float
    seconds: float


def fit(name: str, x: np.ndarray, y: np.ndarray, meta: dict, bounds: np.ndarray, seed: int) -> Fitted:
    """A fresh actor fitted to (x, y) by ``DDPGAgent.polish`` with variant ``name``'s network and epochs."""
    v = VARIANTS[name]
    cfg = TrainConfig(
        hidden=tuple(v["hidden"]), obs_norm=True, batch_size=256, polish_lr=1e-3, seed=seed,
        actor_arch=v.get("arch", "mlp"),
    )
    shapes = {k: tuple(meta["observation_shapes"][k]) for k in meta["observation_keys"]}
    agent = DDPGAgent(x.shape[1], 2, cfg, shapes=shapes)
    agent.norm.update(x)  # the normaliser sees the collected observations, never the reflected ones
    if v["mirror"]:
        index, sign, shift = mirror_map(tuple(meta["observation_keys"]), meta["observation_shapes"], bounds)
        x = np.concatenate([x, (x[:, index] * sign + shift).astype(np.float32)])
        y = np.concatenate([y, y * np.array([1.0, -1.0], dtype=np.float32)])
    t0 = time.perf_counter()
    losses = agent.polish(x, y, v["epochs"], torch.Generator().manual_seed(seed))
    arrays = agent.export_actor()
    policy = LearnedPolicy(arrays, {**meta, **agent.actor_meta(), "polished": True}, source=f"<{name}>")
    return Fitted(policy, losses[-1], time.perf_counter() - t0)


def evaluate(scene: str, policy: Policy, overrides: dict, episodes: int, seed: int) -> dict:
    """Outcome rates of ``policy`` over ``episodes`` consecutive episodes of ``deck_sim.load(scene, seed=seed)``."""
    env = deck_sim.load(scene, seed=seed, **overrides)
    results = [run_episode(env, policy, k) for k in range(episodes)]
    return summarize(results)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="deck1")
    parser.add_argument("--algo", default="mddpg", choices=("mddpg", "ddpg"))
    parser.add_argument("--states", type=int, default=160_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--noise", type=float, default=0.1, help="std of the actor's exploration noise")
    parser.add_argument("--teacher-share", type=float, default=0.15, help="share of episodes the teacher drives")
    parser.add_argument("--variants", default="plain,mirror,wide")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--eval-seed", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0, help="seeds the fits")
    parser.add_argument("--data", default=None, help="cache of the collected states (default runs/cloning/...)")
    args = parser.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown or not variants:
        parser.error(f"--variants: expected some of {', '.join(VARIANTS)}, got {args.variants!r}")
    torch.set_num_threads(1)
    print(machine(mujoco=mujoco.__version__, torch=torch.__version__))
    shipped = load_actor(shipped_policy_path(args.algo, args.scene))
    actors = shipped.members if isinstance(shipped, EnsemblePolicy) else [shipped]  # the shipped file's actors
    overrides = shipped.scene_overrides
    bounds = deck_sim.load(args.scene, seed=0).task.arena.bounds

    if "mirror" in variants:  # a key without a known reflection fails now, not after the first fits
        mirror_map(shipped.keys, shipped.shapes, bounds)
    # the cache is keyed on what the states depend on: the actor file and the collection settings
    actor_id = hashlib.sha256(shipped_policy_path(args.algo, args.scene).read_bytes()).hexdigest()[:10]
    name = f"{args.scene}-{args.algo}-{actor_id}-{args.states}-noise{args.noise}-teacher{args.teacher_share}.npz"
    data = Path(args.data or f"runs/cloning/{name}")
    if data.exists():
        with np.load(data) as d:
            x, y = d["x"], d["y"]
        print(f"states: {len(x)} from {data}")
    else:
        t0 = time.perf_counter()
        per = -(-args.states // args.workers)
        jobs = [
            (args.scene, args.algo, COLLECT_SEED + i * 1_000_000, per, args.noise, args.teacher_share)
            for i in range(args.workers)
        ]
        with mp.get_context("fork").Pool(args.workers) as pool:
            parts = pool.map(_collect, jobs)
        x = np.concatenate([p[0] for p in parts])
        y = np.concatenate([p[1] for p in parts])
        data.parent.mkdir(parents=True, exist_ok=True)
        tmp = data.with_name(data.name + ".tmp.npz")
        np.savez_compressed(tmp, x=x, y=y)
        tmp.replace(data)
        print(
            f"states: {len(x)} from {sum(p[2] for p in parts)} episodes in {time.perf_counter() - t0:.0f} s "
            f"(noise {args.noise}, teacher share {args.teacher_share}), saved to {data}"
        )

    fitted = {name: fit(name, x, y, actors[0].meta, bounds, args.seed) for name in variants}
    rows: list[tuple[str, Policy, Fitted | None]] = [(f"shipped {args.algo}", shipped, None)]
    rows += [(name, f.policy, f) for name, f in fitted.items()]
    if len(fitted) > 1:
        rows.append(("ensemble of the fits", EnsemblePolicy([f.policy for f in fitted.values()]), None))
    fits_and_shipped = EnsemblePolicy([*actors, *(f.policy for f in fitted.values())])
    rows.append(("ensemble of the fits + shipped", fits_and_shipped, None))
    print(f"\n{args.scene}, {args.episodes} episodes of deck_sim.load({args.scene!r}, seed={args.eval_seed})")
    print(f"{'policy':32s} {'success':>8s} {'collision':>9s} {'timeout':>8s} {'fit loss':>9s} {'fit s':>6s}")
    for label, policy, f in rows:
        s = evaluate(args.scene, policy, overrides, args.episodes, args.eval_seed)
        loss, secs = ("", "") if f is None else (f"{f.loss:.4f}", f"{f.seconds:.0f}")
        print(
            f"{label:32s} {100 * s['goal_rate']:7.1f}% {100 * s['collision_rate']:8.1f}% "
            f"{100 * s['timeout_rate']:7.1f}% {loss:>9s} {secs:>6s}",
            flush=True,
        )


if __name__ == "__main__":
    main()
