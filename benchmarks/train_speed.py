"""Training throughput: environment plus update steps per second, deck_sim's DDPG against stable-baselines3's DDPG.

Both learn on the same environment (the scene's Gymnasium adapter, MPC prediction in the observation), with the
same networks (2 x 256, ReLU), batch 256, Adam, gamma, tau, Gaussian noise and one gradient update per environment
step after the same number of random steps. Ours runs twice: with its environment in a worker process (the
physics overlaps the updates on a second core; the default of the tuned preset) and inline (one core, like SB3).
Each agent is timed over the steps after its warm-up; they alternate in rounds within one run so that machine
load falls on all, and the ratios of their medians are printed with the machine. Single-threaded torch.

    python benchmarks/train_speed.py [--scene deck1] [--steps 1500] [--warmup 300] [--rounds 3]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from training.config import make_config  # noqa: E402
from training.loop import Trainer  # noqa: E402


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
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, tmp, progress=False)
        trainer.train(stop_at=warmup)
        t0 = time.perf_counter()
        trainer.train(stop_at=warmup + steps)
        rate = steps / (time.perf_counter() - t0)
        trainer.close()
        return rate


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="deck1")
    parser.add_argument("--steps", type=int, default=1500, help="timed steps per measurement")
    parser.add_argument("--warmup", type=int, default=300, help="random steps before the first update")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    import stable_baselines3

    print(machine(torch=torch.__version__, sb3=stable_baselines3.__version__))
    print(
        f"scene {args.scene}, predictor mpc, 2x256 networks, batch 256, 1 update per env step, "
        f"{args.steps} timed steps after {args.warmup} random ones, {args.rounds} rounds"
    )
    a, c, b = [], [], []
    for r in range(args.rounds):
        a.append(ours(args.scene, args.steps, args.warmup, seed=r, worker=True))
        c.append(ours(args.scene, args.steps, args.warmup, seed=r, worker=False))
        b.append(sb3(args.scene, args.steps, args.warmup, seed=r))
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
    print(f"load average while it ran: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} cores")

if __name__ == "__main__":
    main()
