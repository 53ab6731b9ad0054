"""Where two agents' turning angles differ: the same held-out episodes, the turning split by speed.

The turning angle of ``deck_sim.metrics.turning_angle`` sums the absolute change of direction between consecutive
path segments (positions one decision apart, segments shorter than 5 cm dropped). A vehicle that creeps or stops and
starts again lays short segments whose directions wander, so waiting adds turning although the path does not bend.
This benchmark plays every agent on the same episodes (episode i reset with seed ``--seed + i`` as
``deck_sim.evaluation`` resets it: by default the episodes of docs/results.md) and prints, over the episodes that
all agents reach, the mean and median turning, the part of it between segments slower than ``--slow`` m/s (either
segment of the pair), the share of decisions spent below that speed, the action swing (the mean change of direction
between consecutive commanded displacements of at least a tenth of the full step, degrees per decision: how much the
actor's command itself swings), and the episodes where the first two agents differ most.

    python benchmarks/turning.py [--scene deck1] [--agents mddpg,ddpg] [--episodes 100] [--seed 100000]
                                 [--slow 1.0]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import math  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.evaluation import DEFAULT_SEED, episode_seed  # noqa: E402
from deck_sim.policies import make_policy, policy_overrides  # noqa: E402
from deck_sim.rollout import run_episode  # noqa: E402

MIN_SEGMENT = 0.05
"""Metres: the shortest segment ``deck_sim.metrics.turning_angle`` keeps."""


def turning_split(xy: np.ndarray, period: float, slow: float) -> tuple[float, float]:
    """(turning, turning where either segment is slower than ``slow`` m/s) of a path sampled every ``period``
    seconds, radians; the segments and the sum are ``deck_sim.metrics.turning_angle``'s."""
    kept, gaps = [xy[0]], [0]
    for i, p in enumerate(xy[1:], start=1):
        if math.hypot(*(p - kept[-1])) >= MIN_SEGMENT:
            kept.append(p)
            gaps.append(i)
    if len(kept) < 3:
        return 0.0, 0.0
    seg = np.diff(np.asarray(kept), axis=0)
    speed = np.hypot(seg[:, 0], seg[:, 1]) / (np.diff(gaps) * period)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    change = np.abs((np.diff(heading) + np.pi) % (2.0 * np.pi) - np.pi)
    slow_pair = np.minimum(speed[1:], speed[:-1]) < slow
    return float(change.sum()), float(change[slow_pair].sum())


def play(agent: str, scene: str, episodes: int, seed: int) -> list[dict]:
    """Every episode of ``agent``: its outcome, path (positions after reset and each decision) and speeds."""
    env = deck_sim.load(scene, seed=seed, **policy_overrides(agent, scene))
    policy = make_policy(agent, env, seed=seed)
    out = []
    for k in range(episodes):
        xy, speed, actions = [], [], []

        def on_step(env, ts, action, xy=xy, speed=speed, actions=actions) -> None:  # noqa: ANN001, ARG001
            info = env.task.last_info
            xy.append(info["position"].copy())
            speed.append(info["speed"])
            if action is not None:
                actions.append(np.array(action, dtype=float))

        env.random_state.seed(episode_seed(seed, k))  # as deck_sim.evaluation resets its episode k
        result = run_episode(env, policy, episode=k, on_step=on_step)
        out.append({"outcome": result.outcome, "xy": np.asarray(xy), "speed": np.asarray(speed),
                    "action": np.asarray(actions).reshape(-1, 2)})
    env.close()
    return out


def action_swing(actions: np.ndarray, least: float = 0.1) -> float:
    """Mean change of direction between consecutive actions (commanded displacements), radians, over the pairs where
    both ask for at least ``least`` of the full step: how much the actor's command itself swings from one decision to
    the next."""
    norm = np.linalg.norm(actions, axis=1)
    keep = (norm[1:] >= least) & (norm[:-1] >= least)
    if not keep.any():
        return float("nan")
    angle = np.arctan2(actions[:, 1], actions[:, 0])
    change = np.abs((np.diff(angle) + np.pi) % (2.0 * np.pi) - np.pi)
    return float(change[keep].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="deck1")
    parser.add_argument("--agents", default="mddpg,ddpg", help="comma-separated agents (deck-sim run --policy names)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of episode 0 (default: results.md's)")
    parser.add_argument("--slow", type=float, default=1.0, help="m/s: a segment below this speed is slow")
    args = parser.parse_args()
    agents = args.agents.split(",")
    print(machine())
    print(f"{args.scene}, {args.episodes} episodes from seed {args.seed}; slow: below {args.slow} m/s")
    runs = {a: play(a, args.scene, args.episodes, args.seed) for a in agents}
    period = deck_sim.load_scene(args.scene).episode.control_period
    both = [k for k in range(args.episodes) if all(runs[a][k]["outcome"] == "goal" for a in agents)]
    print(f"episodes every agent reaches: {len(both)}")
    print(f"{'agent':10s} {'success':>8s} {'turning mean':>13s} {'median':>8s} {'of it slow':>11s} "
          f"{'decisions slow':>15s} {'decisions':>10s} {'action swing':>13s}")
    split = {}
    for a in agents:
        s = np.array([turning_split(runs[a][k]["xy"], period, args.slow) for k in both]).reshape(-1, 2)
        split[a] = np.degrees(s)
        success = np.mean([e["outcome"] == "goal" for e in runs[a]])
        slow_share = np.mean([np.mean(runs[a][k]["speed"] < args.slow) for k in both]) if both else float("nan")
        decisions = np.mean([len(runs[a][k]["xy"]) - 1 for k in both]) if both else float("nan")
        swing = np.degrees(np.nanmean([action_swing(runs[a][k]["action"]) for k in both])) if both else float("nan")
        print(f"{a:10s} {100 * success:7.1f}% {split[a][:, 0].mean():9.1f} deg {np.median(split[a][:, 0]):4.1f} deg "
              f"{split[a][:, 1].mean():7.1f} deg {100 * slow_share:14.1f}% {decisions:10.1f} {swing:9.1f} deg")
    if len(agents) >= 2 and both:
        a, b = agents[:2]
        diff = split[a] - split[b]
        print(f"{a} minus {b}: turning {diff[:, 0].mean():+.1f} deg a episode, of which {diff[:, 1].mean():+.1f} "
              "deg between slow segments")
        print(f"episodes where they differ most (turning deg, decisions below {args.slow} m/s):")
        for i in np.argsort(-np.abs(diff[:, 0]))[:5]:
            k = both[i]
            shares = [100 * np.mean(runs[x][k]["speed"] < args.slow) for x in (a, b)]
            print(f"  episode {k}: {a} {split[a][i, 0]:.0f} ({shares[0]:.0f} %), {b} {split[b][i, 0]:.0f} "
                  f"({shares[1]:.0f} %)")


if __name__ == "__main__":
    main()
