"""How far a DDPG / MDDPG run's critic is from the returns it is meant to predict: its Q values on the transitions
of its own replay buffer against their Monte Carlo returns.

Reads each run folder's ``checkpoint.pt`` (``training.checkpoints``: the agent and the replay buffer as the run last
saved them). Follows every stored transition to the one that starts where it ends (the row whose observation equals
its next observation, whatever environment or ring position holds it) and sums, back from each episode that ends
in the buffer (the goal or a collision), the discounted return of the actions the run took (exploration noise
included) in the critic's units: ``reward_scale`` times the reward, discounted by ``gamma``. Transitions whose
episode runs past the buffer's newest row, or was cut by the time limit, have no such return and are left out.
On up to ``--samples`` of the others (seeded) it prints, per run:

- the mean Monte Carlo return G and the mean Q of the online critic at the same state and stored action (the
  minimum of the twin heads, or the weighted mean that the run's TD target takes: ``twin_min_weight``), their
  difference (the critic's bias) and correlation;
- at the next states and the target actor's action (the TD target's bootstrap): the twin heads' mean absolute
  disagreement. Their minimum lies half of it below their mean, TD3's minimum removes that much from every
  bootstrapped step, and the discount compounds it over the horizon.

G is the return of the actions stored (exploration noise, and the policies of the past), Q the critic's value of
the same action followed by its target policy: a difference of a unit or two can be either's doing, not one of many.

    python benchmarks/critic_bias.py runs/switches/deck1-reward-mddpg-seed0 [RUN ...] [--samples 20000]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from training.checkpoints import CheckpointError, load_run_agent  # noqa: E402


def monte_carlo_returns(obs: np.ndarray, next_obs: np.ndarray, reward: np.ndarray, terminated: np.ndarray,
                        gamma: float, scale: float) -> tuple[np.ndarray, int]:
    """Discounted return (``scale`` x reward, discount ``gamma``) of each transition to the end of its episode,
    following each transition to the row whose ``obs`` equals its ``next_obs`` byte for byte. NaN where the episode
    does not end (terminated) within the rows given, or where the way there passes an observation that several rows
    hold (a standstill can repeat one exactly; which row follows would be a guess). Arrays (n, ...) in any order.
    Returns the returns (n,) and how many rows hold such a repeated observation."""
    n = len(obs)
    first: dict[bytes, int] = {}
    repeated: set[bytes] = set()
    for i, row in enumerate(np.ascontiguousarray(obs)):
        key = row.tobytes()
        if key in first:
            repeated.add(key)
        else:
            first[key] = i
    succ = np.array([-1 if (key := row.tobytes()) in repeated else first.get(key, -1)
                     for row in np.ascontiguousarray(next_obs)], dtype=np.int64)
    done = terminated > 0.5
    g = np.full(n, np.nan)
    g[done] = scale * reward[done]
    todo = ~done & (succ >= 0)
    while todo.any():  # one step further back from the episodes' ends each pass
        ready = todo & ~np.isnan(g[np.where(succ >= 0, succ, 0)])
        if not ready.any():
            break  # (what is left never reaches an episode's end: cut by the time limit or the buffer)
        g[ready] = scale * reward[ready] + gamma * g[succ[ready]]
        todo &= ~ready
    ambiguous = sum(1 for row in np.ascontiguousarray(obs) if row.tobytes() in repeated) if repeated else 0
    return g, ambiguous


def critic_bias(run: Path, samples: int, seed: int = 0) -> dict[str, float]:
    """The figures of the module docstring for one run folder."""
    state, cfg, agent = load_run_agent(run)
    buf = state["buffer"]
    start = int(buf["n_demo"])  # (demonstrations: not the run's own actions)
    arrays = {k: buf[k][start:].numpy() for k in ("obs", "next_obs", "reward", "terminated", "action")}
    g, repeated = monte_carlo_returns(arrays["obs"], arrays["next_obs"], arrays["reward"], arrays["terminated"],
                                      cfg.gamma, cfg.reward_scale)
    known = np.flatnonzero(~np.isnan(g))
    if len(known) == 0:
        raise CheckpointError(f"{run}: no episode ends within the replay buffer")
    pick = np.random.default_rng(seed).choice(known, size=min(samples, len(known)), replace=False)
    t = lambda k: torch.from_numpy(arrays[k][pick])  # noqa: E731
    with torch.no_grad():
        obs, next_obs = agent.norm(t("obs")), agent.norm(t("next_obs"))
        heads = torch.stack(agent.critic(obs, t("action")))
        q = agent.combine_heads(heads)
        boot = torch.stack(agent.critic_target(next_obs, agent.actor_target(next_obs)))
    q, gs = q.numpy().astype(np.float64), g[pick]
    out = {
        "steps": int(state["step"]), "transitions": len(g), "with_return": len(known) / len(g),
        "return": float(gs.mean()), "q": float(q.mean()), "bias": float((q - gs).mean()),
        "corr": float(np.corrcoef(q, gs)[0, 1]), "heads": len(heads), "repeated": repeated,
    }
    if len(boot) > 1:
        out["disagreement"] = float((boot[0] - boot[1]).abs().mean())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders holding checkpoint.pt")
    parser.add_argument("--samples", type=int, default=20_000, help="transitions compared per run (seeded)")
    args = parser.parse_args()
    if args.samples < 2:
        parser.error("--samples: at least 2")
    print(machine(torch=torch.__version__))
    print("G: Monte Carlo return of the stored action; Q: the critic's TD-target estimate of it (critic units)")
    print("| run | steps | transitions with G | mean G | mean Q | Q - G | corr | heads disagree |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    failed = False
    for run in args.runs:
        try:
            r = critic_bias(run, args.samples)
        except CheckpointError as err:
            print(err, file=sys.stderr)
            failed = True
            continue
        twin = f"{r['disagreement']:.2f}" if "disagreement" in r else "-"
        print(f"| {run.name} | {r['steps']} | {r['with_return']:.0%} of {r['transitions']} | {r['return']:.2f} | "
              f"{r['q']:.2f} | {r['bias']:+.2f} | {r['corr']:.2f} | {twin} |", flush=True)
        if r["repeated"]:
            print(f"  ({r['repeated']} rows hold an observation that another row repeats: the returns through them "
                  "are left out)", flush=True)
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
