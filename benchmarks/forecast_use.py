"""Does a trained MDDPG actor use its forecast? Its held-out success with the forecast it learnt from swapped for
other predictors' forecasts of the same shape.

Each actor file (one actor or an ensemble of them; trained with a predictor, i.e. MDDPG) is evaluated on the same
``--episodes`` held-out episodes of its scene (``deck_sim.evaluation``: episode ``i`` reset with seed
``DEFAULT_SEED + i``, the episodes of ``docs/results.md`` and their continuation) once per predictor of
``--predictors``: the environment computes that predictor's forecast into the observation's ``predicted`` rows (and
the keys read from it, ``predicted_approach`` and ``predicted_near``, where the actor has them), and the actor reads
it as it read its own. Everything else (weights, observation, scene) is the same, so a difference in
success is what the forecast's content is worth to that actor:

- ``constant_velocity``: each mover's last velocity held over the horizon (no intent);
- ``stationary``: each mover held where it is now (no motion at all: what the actor does with positions alone);
- ``oracle``: the movers' true future, simulated ahead (the best forecast there can be);
- ``mpc``: the MPC predictor the shipped MDDPG actors learn from.

``deck-sim run --policy <actor> --predictor <name>`` plays one actor with one swapped forecast; this script plays
every pair on the same episodes and pairs the differences.

Prints, per actor and predictor, the success rate with its Wilson 95 % interval and the collision rate, and the
difference in success to the actor's own predictor, paired by episode, with a 95 % interval over the episodes
(Student's t over the per-episode differences, `deck_sim.metrics.mean_interval`), with the machine and the load
average.

    python benchmarks/forecast_use.py --actors runs/learning/deck1-reward-mddpg-seed0/actor_best.npz[,...]
        [--scene deck1] [--episodes 400] [--predictors mpc,constant_velocity,stationary,oracle] [--workers N]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402

from deck_sim.control.prediction import PREDICTOR_NAMES  # noqa: E402
from deck_sim.evaluation import EvalConfig, evaluate  # noqa: E402
from deck_sim.metrics import mean_interval, rate_interval  # noqa: E402
from deck_sim.policies import PolicyFileError, load_actor  # noqa: E402


def with_predictor(src: Path, predictor: str, out: Path) -> Path:
    """A copy of the actor file ``src`` whose record (and every ensemble member's) names ``predictor``: the same
    weights, fed that predictor's forecast."""
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["meta"]))
    meta["predictor"] = predictor
    for member in meta.get("members") or []:
        member["predictor"] = predictor
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(out, **arrays)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--actors", required=True, help="actor files (actor.npz, actor_best.npz or a shipped file), "
                                                        "comma-separated")
    parser.add_argument("--scene", default=None, help="scene (default: each actor's own)")
    parser.add_argument("--episodes", type=int, default=400)
    parser.add_argument("--predictors", default="mpc,constant_velocity,stationary,oracle",
                        help="forecasts to feed, comma-separated: constant_velocity, stationary, oracle, mpc")
    parser.add_argument("--workers", type=int, default=None, help="evaluation processes (default: the CPU count)")
    args = parser.parse_args()
    predictors = [p for p in args.predictors.split(",") if p]
    bad = [p for p in predictors if p not in PREDICTOR_NAMES or p == "none"]
    if bad or not predictors:
        names = ", ".join(p for p in PREDICTOR_NAMES if p != "none")
        sys.exit(f"forecast_use.py: --predictors: expected names of {names}, got {bad or '[]'}")
    if args.episodes < 2:
        sys.exit(f"forecast_use.py: --episodes must be at least 2, got {args.episodes}")
    actors = [Path(a) for a in args.actors.split(",") if a]
    policies = {}
    for path in actors:
        try:
            policies[path] = load_actor(path)
        except PolicyFileError as err:
            sys.exit(f"forecast_use.py: {err}")
        if policies[path].predictor == "none":
            sys.exit(f"forecast_use.py: {path} was trained without a forecast (DDPG); it has none to swap")
    print(machine())
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (1 min)")
    with tempfile.TemporaryDirectory() as tmp:
        for i, path in enumerate(actors):
            policy = policies[path]
            scene = args.scene or str(policy.meta.get("scene"))
            own = policy.predictor
            print(f"\n{path} (scene {scene}, trained with {own}): {args.episodes} held-out episodes")
            success: dict[str, np.ndarray] = {}
            for predictor in [own, *[p for p in predictors if p != own]]:
                swapped = Path(tmp) / f"a{i}_{predictor}.npz"
                file = path if predictor == own else with_predictor(path, predictor, swapped)
                res = evaluate(EvalConfig(agents=(f"run={file}",), scenes=(scene,), episodes=args.episodes,
                                          workers=args.workers, record="none"))
                rows = sorted(res.episodes, key=lambda r: int(r["seed"]))
                success[predictor] = np.array([r["outcome"] == "goal" for r in rows])
                collided = sum(r["outcome"] == "collision" for r in rows)
                n, k = len(rows), int(success[predictor].sum())
                lo, hi = rate_interval(k, n)
                line = (f"  {predictor:<18} success {k / n:6.1%} ({lo:.1%}-{hi:.1%}), collision {collided / n:6.1%}")
                if predictor != own:
                    d, dlo, dhi = mean_interval(success[predictor].astype(float) - success[own].astype(float))
                    line += f"; minus {own}: {100 * d:+.1f} points ({100 * dlo:+.1f} to {100 * dhi:+.1f})"
                print(line, flush=True)
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (1 min)")


if __name__ == "__main__":
    main()
