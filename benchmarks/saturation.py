"""How far a DDPG / MDDPG actor drives its tanh into saturation, and whether the critic's gradient still reaches it.

The actor's action is ``a = tanh(u)``. Past ``|u|`` of about 3 (``|a|`` > 0.995) the derivative ``1 - a**2`` is
below 0.01, and past 10 it is below 1e-8: the critic's ``dQ/da`` reaches ``u`` multiplied by it, so an actor whose
``u`` has drifted far out can no longer learn to change that action, whatever the critic says (the switch
``+preact``, ``actor_preact_weight``, penalises ``u**2``; docs/training.md).

For each action component it prints the median ``|u|`` and the shares of states with ``|u|`` > 3 and > 10, on
states of one of two kinds:

- a run folder (``checkpoint.pt``, ``training.checkpoints``): up to ``--samples`` of the run's own transitions in
  its replay buffer (seeded), and with the run's critic, the medians of ``|dQ/da|`` (first critic head, at the
  actor's action) and of ``|dQ/du| = |dQ/da| (1 - a**2)``, the gradient the actor's last layer receives;
- an MLP actor file (``actor.npz``, ``actor_best.npz``, a shipped ensemble: each member apart; not a set actor's
  or a stable-baselines3 agent's): the states of ``--episodes`` episodes of the actor's own single-aircraft scene
  (observation fields as it was trained with), stream ``--seed``, driven by that actor, up to ``--max-steps``
  steps each. No critic travels with an actor file.

A checkpoint taken after the final cloning fit is refused: its actor is the fit's, not the one its critic trained.

    python benchmarks/saturation.py runs/learning/square-reward-mddpg-seed0 deck_sim/trained/deck1_mddpg-reward.npz
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.policies import PolicyFileError, load_actor  # noqa: E402
from deck_sim.policies.actors import LearnedPolicy  # noqa: E402
from training.checkpoints import CheckpointError, load_run_agent  # noqa: E402

SATURATED = 3.0
"""|u| past which ``1 - tanh(u)**2`` < 0.01."""
DEAD = 10.0
"""|u| past which ``1 - tanh(u)**2`` < 1e-8."""


def shares(u: np.ndarray) -> dict[str, np.ndarray]:
    """Per action component of pre-tanh actions ``u`` (n, act_dim): the median |u| and the shares past
    ``SATURATED`` and ``DEAD``."""
    a = np.abs(np.asarray(u, dtype=np.float64))
    return {"median": np.median(a, axis=0), "over3": (a > SATURATED).mean(axis=0), "over10": (a > DEAD).mean(axis=0)}


def run_saturation(run: Path, samples: int, seed: int = 0) -> dict[str, Any]:
    """The module docstring's figures for one run folder: its buffer's states, its actor and first critic head."""
    state, _, agent = load_run_agent(run)
    if state.get("polished", False):
        raise CheckpointError(f"{run}: the checkpoint holds the final cloning fit's actor, not the one its critic "
                              "trained (read a checkpoint of the run before its fit)")
    buf = state["buffer"]
    start, size = int(buf["n_demo"]), int(buf["size"])  # (demonstrations: not the run's own states)
    if size <= start:
        raise CheckpointError(f"{run}: the replay buffer holds none of the run's own transitions")
    pick = np.random.default_rng(seed).choice(np.arange(start, size), size=min(samples, size - start), replace=False)
    obs_raw = buf["obs"][torch.from_numpy(np.sort(pick))]
    with torch.no_grad():
        obs = agent.norm(obs_raw.float())
        u = agent.actor.preactivation(obs)
    a = torch.tanh(u).requires_grad_(True)
    (dq_da,) = torch.autograd.grad(agent.critic.first(obs, a).sum(), a)
    dq_du = dq_da * (1.0 - a.detach() ** 2)
    return {
        "steps": int(state["step"]), "states": len(pick), **shares(u.numpy()),
        "dq_da": dq_da.abs().median(dim=0).values.numpy(), "dq_du": dq_du.abs().median(dim=0).values.numpy(),
    }


def check_mlp(policy: LearnedPolicy) -> None:
    """``PolicyFileError`` unless ``policy`` is an MLP actor with a tanh head (``preactivation`` reads it)."""
    if policy.sets or policy.head != "tanh":
        raise PolicyFileError(f"{policy.source}: not an MLP actor with a tanh head (a set actor or a baseline's)")


def preactivation(policy: LearnedPolicy, x: np.ndarray) -> np.ndarray:
    """An MLP actor file's action before its tanh for flat observations ``x`` (n, dim)."""
    check_mlp(policy)
    if policy.norm_enabled:
        x = np.clip((x - policy.norm_mean) / policy.norm_std, -policy.norm_clip, policy.norm_clip)
    for i, (w, b) in enumerate(zip(policy.weights, policy.biases, strict=True)):
        x = x @ w.T + b
        if i < len(policy.weights) - 1:
            x = np.maximum(x, 0.0) if policy.activation == "relu" else np.tanh(x)
    return x


def actor_saturation(path: Path, episodes: int, seed: int, max_steps: int) -> list[dict[str, Any]]:
    """The module docstring's figures for each member of one actor file, on the states it drives itself into."""
    loaded = load_actor(path)
    members = getattr(loaded, "members", [loaded])
    for policy in members:
        check_mlp(policy)
    out = []
    for k, policy in enumerate(members):
        scene = policy.meta.get("scene")
        if not isinstance(scene, str):
            raise PolicyFileError(f"{path}: the actor records no scene to play")
        env = deck_sim.load(scene, seed=seed, **policy.scene_overrides)
        if env.task.spec.multi_agent:
            env.close()
            raise PolicyFileError(f"{path}: scene {scene!r} has several aircraft; this reads "
                                  "single-aircraft actors")
        rows = []
        try:
            for _ in range(episodes):
                ts, n = env.reset(), 0
                policy.reset()
                while not ts.last() and n < max_steps:
                    u = preactivation(policy, policy.flatten(ts.observation)[None])[0]
                    rows.append(u)
                    ts, n = env.step(np.tanh(u)), n + 1
        finally:
            env.close()
        out.append({"member": k, "states": len(rows), **shares(np.array(rows))})
    return out


def _cells(values: np.ndarray, fmt: str) -> str:
    return " / ".join(format(float(v), fmt) for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="+", type=Path, help="run folders (checkpoint.pt) or actor files (.npz)")
    parser.add_argument("--samples", type=int, default=20_000, help="buffer states per run folder (seeded)")
    parser.add_argument("--episodes", type=int, default=3, help="episodes per actor file")
    parser.add_argument("--seed", type=int, default=500, help="episode stream of the actor files' episodes")
    parser.add_argument("--max-steps", type=int, default=200, help="steps per episode at most (actor files)")
    args = parser.parse_args()
    for name in ("samples", "episodes", "max_steps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')}: at least 1")
    if args.seed < 0:
        parser.error("--seed: at least 0")
    print(machine(torch=torch.__version__))
    print(f"u: the action before tanh, per component (a0 / a1); |u| > {SATURATED:g}: 1 - tanh^2 < 0.01; "
          f"|u| > {DEAD:g}: < 1e-8")
    print("| source | steps | states | median abs u | share abs u > 3 | share abs u > 10 | median abs dQ/da | "
          "median abs dQ/du |")
    print("|---|---:|---:|---|---|---|---|---|")
    failed = False
    for path in args.paths:
        try:
            if not path.exists():
                raise OSError(f"{path}: no such run folder or actor file")
            if path.is_dir():
                r = run_saturation(path, args.samples)
                print(f"| {path.name} | {r['steps']} | {r['states']} | {_cells(r['median'], '.2f')} | "
                      f"{_cells(r['over3'], '.1%')} | {_cells(r['over10'], '.1%')} | {_cells(r['dq_da'], '.3g')} | "
                      f"{_cells(r['dq_du'], '.3g')} |", flush=True)
            else:
                for r in actor_saturation(path, args.episodes, args.seed, args.max_steps):
                    print(f"| {path.name} member {r['member']} | - | {r['states']} | {_cells(r['median'], '.2f')} | "
                          f"{_cells(r['over3'], '.1%')} | {_cells(r['over10'], '.1%')} | - | - |", flush=True)
        except (CheckpointError, PolicyFileError, OSError, ValueError, KeyError) as err:
            print(f"{path}: {err}" if isinstance(err, KeyError) else err, file=sys.stderr)
            failed = True
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
