"""What a policy's collisions are, and how many of them a forecast of the movers could have prevented at all.

Each policy of ``--policies`` (a shipped policy such as ``mddpg-reward``, a reference planner, or ``label=path`` to
an actor file) plays the first ``--episodes`` held-out episodes of ``--scene`` (those of ``docs/results.md``:
episode i reset from seed ``DEFAULT_SEED + i``, as ``deck_sim.evaluation`` seeds them), and every episode that ends
in a collision is classified by what the aircraft hit (``last_info["collision"]``), as it was over the control step
before the one in which they touched (that step itself for a contact in the first) (``classify``):

- ``static``: anything that is not a mover (a parked aircraft, a prop, the island);
- ``standing``: a mover that moved less than ``--standing`` m/s: its forecast is where it stands, which the current
  state shows already;
- ``moving``: a mover in motion, and of those ``coming at it``: one whose velocity had a component of at least
  ``--standing`` m/s towards the aircraft's centre (the aircraft was not alone in closing in).

For collisions with movers, where the mover's centre lay: ``ahead`` (within 45 degrees of the aircraft's heading),
``beside`` or ``behind`` (within 45 degrees of its tail). A forecast can only have helped with moving movers; with
those coming at the aircraft most. Prints one row per policy, with the regime it learnt in, and the machine.

    python benchmarks/collisions.py [--scene deck1] [--policies mddpg-reward,ddpg-reward,mddpg,ddpg]
                                    [--episodes 100] [--standing 0.3]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
from collections import Counter  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.evaluation import DEFAULT_SEED  # noqa: E402
from deck_sim.evaluation.harness import agent_label, agent_overrides, episode_seed, make_agent  # noqa: E402
from deck_sim.policies.regimes import actor_regime  # noqa: E402
from deck_sim.rollout import run_episode  # noqa: E402


def classify(mover_before: np.ndarray | None, mover_after: np.ndarray | None, agent_xy: np.ndarray, heading: float,
             dt: float, standing: float) -> tuple[str, bool, str]:
    """One collision: its kind (``static``, ``standing``, ``moving``), whether the mover came at the aircraft, and
    where it lay (``ahead``, ``beside``, ``behind``; ``""`` for a static obstacle).

    Args:
        mover_before, mover_after: (2,) the mover's centre at the start and the end of the control step before the
            contact, metres; None for a static obstacle.
        agent_xy: (2,) the aircraft's centre at the end of that step, metres; ``heading`` its yaw, radians.
        dt: the control period, seconds; ``standing``: the speed below which a mover counts as standing, m/s.
    """
    if mover_before is None or mover_after is None:
        return "static", False, ""
    velocity = (np.asarray(mover_after, float) - np.asarray(mover_before, float)) / dt
    to_agent = np.asarray(agent_xy, float) - np.asarray(mover_after, float)
    gap = float(np.linalg.norm(to_agent))
    towards = float(velocity @ to_agent) / gap if gap > 0 else 0.0
    bearing = math.atan2(-to_agent[1], -to_agent[0]) - heading  # the mover as the aircraft sees it
    off = abs((bearing + math.pi) % (2 * math.pi) - math.pi)
    where = "ahead" if off <= math.pi / 4 else "behind" if off >= 3 * math.pi / 4 else "beside"
    kind = "standing" if float(np.linalg.norm(velocity)) < standing else "moving"
    return kind, kind == "moving" and towards >= standing, where


def collisions(policy_name: str, scene: str, episodes: int, standing: float) -> dict[str, Any]:
    """Play ``episodes`` held-out episodes of ``scene`` with ``policy_name`` and classify every collision."""
    env = deck_sim.load(scene, seed=0, **agent_overrides(policy_name, scene))
    if env.task.spec.multi_agent:
        raise ValueError(f"{scene} has several aircraft; this script reads one aircraft's collisions")
    policy = make_agent(policy_name, env)
    task, dt = env.task, env.task.spec.episode.control_period
    names = [m.mjcf_model.model for m in task.movers]
    counts: Counter[str] = Counter()
    partners: Counter[str] = Counter()
    for i in range(episodes):
        trace: list[tuple[np.ndarray, np.ndarray, float]] = []

        def on_step(env: Any, ts: Any, action: Any, trace: list = trace) -> None:  # noqa: ARG001
            info = env.task.last_info
            trace.append((info["mover_positions"].copy(), info["position"].copy(), float(info["heading"])))

        seed = episode_seed(DEFAULT_SEED, i)
        if policy_name == "random":  # (its own stream, seeded per episode, as the harness seeds it)
            policy = make_agent(policy_name, env, seed=seed)
        env.random_state.seed(seed)
        run_episode(env, policy, episode=i, on_step=on_step)
        partner = task.last_info["collision"]
        if partner is None:
            continue
        partners[re.sub(r"_\d+$", "", partner)] += 1
        j = names.index(partner) if partner in names else None
        # the step before the one in which they touched: from frame -3 to frame -2 (the last frame is after it);
        # for a contact in the episode's first step, that step itself
        a, b = (trace[-3], trace[-2]) if len(trace) >= 3 else (trace[0], trace[-1])
        kind, coming, where = classify(None if j is None else a[0][j], None if j is None else b[0][j], b[1], b[2],
                                       dt, standing)
        counts["collisions"] += 1
        counts[kind] += 1
        counts["coming"] += coming
        if where:
            counts[where] += 1
    env.close()
    meta = getattr(policy, "meta", None)
    return {"policy": agent_label(policy_name), "regime": (actor_regime(meta) if meta else None) or "-",
            "episodes": episodes, "counts": counts, "partners": partners}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="deck1")
    parser.add_argument("--policies", default="mddpg-reward,ddpg-reward,mddpg,ddpg",
                        help="shipped policy names, reference planners or label=path/to/actor.npz, comma-separated")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--standing", type=float, default=0.3, help="m/s below which a mover counts as standing")
    args = parser.parse_args()
    if args.episodes < 1 or not args.standing > 0:
        sys.exit(f"collisions.py: --episodes must be at least 1 and --standing above 0, got {args.episodes} and "
                 f"{args.standing}")
    print(machine())
    print(f"{args.scene}: the first {args.episodes} held-out episodes (seeds {DEFAULT_SEED}-"
          f"{DEFAULT_SEED + args.episodes - 1}); a mover standing below {args.standing} m/s")
    print("| policy | learnt from | episodes | collisions | static | standing mover | moving mover | of those coming "
          "at the aircraft | mover ahead | beside | behind | what was hit |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for name in [p for p in args.policies.split(",") if p]:
        try:
            r = collisions(name, args.scene, args.episodes, args.standing)
        except (ValueError, OSError) as err:
            sys.exit(f"collisions.py: {name}: {err}")
        c = r["counts"]
        hit = ", ".join(f"{k} {v}" for k, v in r["partners"].most_common())
        print(f"| {r['policy']} | {r['regime']} | {r['episodes']} | {c['collisions']} | {c['static']} | "
              f"{c['standing']} | {c['moving']} | {c['coming']} | {c['ahead']} | {c['beside']} | {c['behind']} | "
              f"{hit or '-'} |", flush=True)


if __name__ == "__main__":
    main()
