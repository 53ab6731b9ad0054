"""Training throughput: environment steps per second of a shipped recipe on each backend, and deck_sim's DDPG
against stable-baselines3's DDPG.

Recipe (``--parts recipe``): the MDDPG config of ``load_recipe(--recipe)`` (its networks, environments, update
ratio, planner labels and scene fields) with ``--demos`` demonstration episodes, no pre-training, evaluations or
checkpoints, and its first update at step ``--warmup``; each backend and worker count of ``--backends`` and
``--workers`` (``local`` with 0 workers steps inline) and each learner arithmetic of ``--precisions``
(``TrainConfig.learner_precision``) runs the loop to ``--warmup`` steps, then is timed over the next ``--steps``, the
full loop (acting, stepping, planner labels, updates, replay) included. The variants alternate
in rounds so that machine load falls on all; the medians and their ratios to the first variant are printed.

SB3 (``--parts sb3``): both learn on the same environment (the scene's Gymnasium adapter, MPC prediction in the
observation), with the same networks (2 x 256, ReLU), batch 256, Adam, gamma, tau, Gaussian noise and one gradient
update per environment step after the same number of random steps. Ours runs twice: with its environment in a worker
process (the physics overlaps the updates on a second core) and inline (one core, like SB3). Single-threaded torch.

    python benchmarks/train_speed.py [--parts recipe,sb3] [--recipe deck1] [--backends local,ray] [--workers 1,2]
        [--precisions float32,bfloat16] [--steps 1600] [--warmup 400] [--rounds 2] [--scene deck1]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

import argparse  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from training.config import TrainConfig, make_config  # noqa: E402
from training.loop import Trainer  # noqa: E402
from training.recipes import load_recipe  # noqa: E402


def recipe_config(recipe: str, warmup: int, demos: int, seed: int, precision: str | None = None) -> TrainConfig:
    """The recipe's MDDPG config, trimmed to a timed window: ``demos`` demonstrations, no pre-training,
    evaluations or checkpoints, the first update at ``warmup`` steps; ``precision`` replaces the recipe's
    ``learner_precision`` when given."""
    extra = {} if precision is None else {"learner_precision": precision}
    return load_recipe(recipe).config(
        "mddpg",
        seed,
        demo_episodes=demos,
        pretrain_updates=0,
        learning_starts=warmup,
        eval_every=0,
        checkpoint_every=0,
        log_every=10**9,
        polish_epochs=0,
        dagger_steps=0,
        **extra,
    )


def timed(cfg: TrainConfig, warmup: int, steps: int, **runner: object) -> float:
    """Environment steps per second of ``cfg``'s loop over ``steps`` steps after ``warmup`` (``runner``: the
    ``Trainer``'s backend and workers)."""
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, tmp, progress=False, **runner)
        try:
            trainer.train(stop_at=warmup)
            start, t0 = trainer.step, time.perf_counter()
            trainer.train(stop_at=warmup + steps)
            return (trainer.step - start) / (time.perf_counter() - t0)
        finally:
            trainer.close()


def recipe_part(args: argparse.Namespace) -> None:
    precisions = args.precisions.split(",") if args.precisions else [None]
    variants = [(b, int(w), p) for b in args.backends.split(",") for w in args.workers.split(",") for p in precisions]
    skipped = [v for v in variants if v[0] == "ray" and v[1] == 0]
    if skipped:
        print("ray with 0 workers skipped: the ray backend acts in at least 1 worker (local 0 steps inline)")
        variants = [v for v in variants if v not in skipped]
    if any(b == "ray" for b, _, _ in variants):
        import ray

        ray.init(num_cpus=max(w for _, w, _ in variants), include_dashboard=False, log_to_driver=False)
    configs = {p: recipe_config(args.recipe, args.warmup, args.demos, seed=0, precision=p) for p in precisions}
    cfg = configs[precisions[0]]
    print(
        f"recipe {args.recipe} (mddpg): {cfg.num_envs} environments, {cfg.updates_per_step} updates per step, "
        f"actor {cfg.actor_arch}, {args.demos} demonstrations, first update at {args.warmup} steps, "
        f"learner {'/'.join(c.learner_precision for c in configs.values())}, {args.steps} timed steps, "
        f"{args.rounds} rounds"
    )

    def name(variant: tuple[str, int, str | None]) -> str:
        backend, workers, precision = variant
        inline = " (inline)" if not workers else ""
        return f"{backend} {workers} workers{inline}, {configs[precision].learner_precision} learner"

    rates: dict[tuple[str, int, str | None], list[float]] = {v: [] for v in variants}
    for r in range(args.rounds):
        for variant in variants:
            backend, workers, precision = variant
            rate = timed(configs[precision], args.warmup, args.steps, backend=backend, workers=workers)
            rates[variant].append(rate)
            print(f"round {r}: {name(variant)}: {rate:.1f} env steps/s (load {os.getloadavg()[0]:.1f})", flush=True)
    first = statistics.median(rates[variants[0]])
    for variant, values in rates.items():
        m = statistics.median(values)
        print(f"median: {name(variant)}: {m:.1f} env steps/s, {m / first:.2f}x {name(variants[0])}")


def ours(scene: str, steps: int, warmup: int, seed: int, worker: bool) -> float:
    """Steps per second of deck_sim's trainer after ``warmup`` random steps (paper preset: 1 env, 1 update/step),
    its environment stepped in a worker process (overlapping the updates) or inline."""
    cfg = make_config(
        "paper",
        scene=scene,
        seed=seed,
        total_steps=warmup + steps + 1000,
        learning_starts=warmup,
        batch_size=256,
        hidden=(256, 256),
        eval_every=0,
        checkpoint_every=0,
        log_every=10**9,
        eval_episodes=1,
        env_worker=worker,
    )
    return timed(cfg, warmup, steps)


def sb3(scene: str, steps: int, warmup: int, seed: int) -> float:
    """Steps per second of SB3's DDPG on the same environment, same networks and update ratio."""
    from stable_baselines3 import DDPG
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.noise import NormalActionNoise

    from deck_sim.wrappers import DeckSimEnv

    env = DeckSimEnv(scene, episode__predictor="mpc")
    model = DDPG(
        "MlpPolicy",
        env,
        learning_rate=3e-4,
        buffer_size=warmup + steps + 10,
        learning_starts=warmup,
        batch_size=256,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        seed=seed,
        verbose=0,
        action_noise=NormalActionNoise(np.zeros(2), 0.3 * np.ones(2)),
        policy_kwargs={"net_arch": [256, 256]},
    )

    class Clock(BaseCallback):
        t_start = 0.0

        def _on_step(self) -> bool:
            if self.num_timesteps == warmup:
                Clock.t_start = time.perf_counter()
            return True

    model.learn(total_timesteps=warmup + steps, callback=Clock())
    return steps / (time.perf_counter() - Clock.t_start)


def sb3_part(args: argparse.Namespace) -> None:
    warmup = args.warmup
    print(
        f"scene {args.scene}, predictor mpc, 2x256 networks, batch 256, 1 update per env step, "
        f"{args.steps} timed steps after {warmup} random ones, {args.rounds} rounds"
    )
    a, c, b = [], [], []
    for r in range(args.rounds):
        a.append(ours(args.scene, args.steps, warmup, seed=r, worker=True))
        c.append(ours(args.scene, args.steps, warmup, seed=r, worker=False))
        b.append(sb3(args.scene, args.steps, warmup, seed=r))
        print(
            f"round {r}: deck_sim DDPG {a[-1]:.1f} steps/s (env worker), {c[-1]:.1f} (inline); "
            f"SB3 DDPG {b[-1]:.1f} steps/s; ratios {a[-1] / b[-1]:.2f}x, {c[-1] / b[-1]:.2f}x",
            flush=True,
        )
    ma, mc, mb = statistics.median(a), statistics.median(c), statistics.median(b)
    print(
        f"median: deck_sim DDPG {ma:.1f} steps/s with its env worker ({ma / mb:.2f}x SB3, target >= 1.2x), "
        f"{mc:.1f} inline ({mc / mb:.2f}x); SB3 DDPG {mb:.1f} steps/s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", default="recipe,sb3", help="recipe and/or sb3 (comma-separated)")
    parser.add_argument("--recipe", default="deck1", help="the shipped recipe of the recipe part")
    parser.add_argument("--backends", default="local", help="backends of the recipe part: local and/or ray")
    parser.add_argument("--workers", default="1,2", help="worker counts of the recipe part (local 0: inline)")
    parser.add_argument(
        "--precisions", default="", help="learner arithmetics of the recipe part, e.g. float32,bfloat16 (default: "
        "the recipe's)"
    )
    parser.add_argument("--demos", type=int, default=4, help="demonstration episodes of the recipe part")
    parser.add_argument("--scene", default="deck1", help="the scene of the SB3 part")
    parser.add_argument("--steps", type=int, default=1600, help="timed environment steps per measurement")
    parser.add_argument("--warmup", type=int, default=400, help="steps before the first update")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    parts = args.parts.split(",")
    versions = {"torch": torch.__version__}
    if "sb3" in parts:
        import stable_baselines3

        versions["sb3"] = stable_baselines3.__version__
    if "ray" in args.backends:
        import ray

        versions["ray"] = ray.__version__
    print(machine(**versions))
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} cores")
    if "recipe" in parts:
        recipe_part(args)
    if "sb3" in parts:
        sb3_part(args)
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
