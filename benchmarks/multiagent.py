"""The multi-aircraft scenes' full-knowledge reference: prioritised planning against independent planners.

For each scene and team policy, play episodes i = 0 .. N-1, episode i reset with seed 100000 + i (the held-out
stream of docs/results.md), and measure every aircraft (``deck_sim.rollout.run_team_episode``):

- ``prioritised``: ``deck_sim.policies.team.PrioritisedPolicy``, the aircraft planning in turn, each treating the
  plans of those before it as their future (the reference: the ceiling of what the scenes allow);
- ``independent``: every aircraft its own ``ScriptedPlanner`` (whole body) on the same full view, the other
  aircraft predicted by the task's predictor like any mover, no plan shared;
- ``shared:<policy>``: a single-agent policy acting for every aircraft on its own observation
  (``deck_sim.policies.team.make_team_policy``): ``shared:mddpg`` is the MDDPG shipped for the scene, or, where
  none is, the single-aircraft deck 1 or deck 2 MDDPG (an actor reads the nearest dynamic obstacles it was trained
  on); ``shared:<run>/actor.npz`` an actor file; each with the scene fields the policy needs (its predictor and
  observation).

Prints the machine, then per scene and policy: aircraft that reached their targets (Wilson 95 % interval), that
collided (and with what kind of obstacle), that were still taxiing at the time limit, episodes in which every
aircraft arrived, their mean makespan, collisions between two aircraft per episode, the sum of the paths against
the sum of the shortest ways (episodes in which every aircraft arrived), and the wall time.

    python benchmarks/multiagent.py [--scenes deck1-multi,deck2-multi] [--episodes 30] [--policies
                                    prioritised,independent,shared:mddpg] [--agents K] [--predictor NAME]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import re  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402

from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.metrics import rate_interval, summarize_team  # noqa: E402
from deck_sim.policies.team import TEAM_PLANNERS, make_team_policy, team_policy_overrides  # noqa: E402
from deck_sim.rollout import run_team_episode  # noqa: E402

HELD_OUT_SEED = 100000
"""Episode i is reset with this seed plus i (docs/results.md's held-out stream)."""


def make_team(name: str, scene: str, overrides: dict):  # noqa: ANN201 - (environment, team policy)
    """The environment and the team policy ``name`` (``prioritised``, ``independent`` or ``shared:<policy>``)."""
    single = name.split(":", 1)[1] if name.startswith("shared:") else name
    env = deck_sim.load(scene, seed=None, **{**team_policy_overrides(single, scene), **overrides})
    return env, make_team_policy(single, env)


def kind(name: str) -> str:
    """An obstacle's kind from its name: ``tractor_3`` -> ``tractor``, ``parked_aircraft_07`` -> ``parked
    aircraft``."""
    return re.sub(r"_\d+$", "", name).replace("_", " ")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1-multi,deck2-multi")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--policies", default="prioritised,independent")
    parser.add_argument("--agents", type=int, default=None, help="aircraft per episode (default: the scene's)")
    parser.add_argument("--predictor", default=None, help="the task's predictor (default: the scene's)")
    args = parser.parse_args()
    unknown = sorted(p for p in args.policies.split(",") if p not in TEAM_PLANNERS and not p.startswith("shared:"))
    if unknown:
        parser.error(f"unknown policies {unknown}; known: {', '.join(TEAM_PLANNERS)}, shared:<policy>")
    overrides = {}
    if args.agents is not None:
        overrides["agents__count"] = args.agents
    if args.predictor is not None:
        overrides["episode__predictor"] = args.predictor
    print(f"machine: {machine()}")
    print(f"episodes 0-{args.episodes - 1}, episode i reset with seed {HELD_OUT_SEED} + i")
    print()
    print("| scene | policy | aircraft | reached | 95 % interval | collided (with) | still taxiing | all arrived | "
          "makespan s | aircraft-aircraft collisions / episode | path sum / shortest sum | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for scene in args.scenes.split(","):
        for name in args.policies.split(","):
            env, policy = make_team(name, scene, overrides)
            t0 = time.perf_counter()
            results = []
            for i in range(args.episodes):
                env.random_state.seed(HELD_OUT_SEED + i)
                results.append(run_team_episode(env, policy, episode=i))
            wall = time.perf_counter() - t0
            env.close()
            s = summarize_team(results)
            aircraft = [r for team in results for r in team.aircraft]
            reached = sum(r.outcome == "goal" for r in aircraft)
            lo, hi = rate_interval(reached, len(aircraft))
            partners = Counter(kind(r.collision_partner) for r in aircraft if r.collision_partner)
            with_what = ", ".join(f"{k} {v}" for k, v in partners.most_common()) or "none"
            print(
                f"| {scene} | {name} | {len(aircraft)} | {100 * s['goal_rate']:.1f} % | {100 * lo:.1f}-{100 * hi:.1f} %"
                f" | {100 * s['collision_rate']:.1f} % ({with_what}) | {100 * s['timeout_rate']:.1f} % | "
                f"{100 * s['all_reached_rate']:.1f} % | {s['makespan']:.1f} | "
                f"{s['aircraft_collisions_per_episode']:.2f} | {s['path_sum_ratio']:.3f} | {wall:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
