"""``deck-sim``: the command line of deck_sim.

deck-sim scenes                                     list the scenes
deck-sim run --scene deck1 --policy scripted --episodes 20
                                                    play episodes, print and save the metrics
deck-sim render --scene deck2 --out ep.mp4          a short video (offscreen) and a top-down PNG
"""

from __future__ import annotations

import os

os.environ.setdefault(
    "MUJOCO_GL", "egl"
)  # offscreen rendering on a headless machine; set before mujoco loads

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

log = logging.getLogger("deck_sim")


def _cmd_scenes(args: argparse.Namespace) -> int:
    from deck_sim.scenes import load_scene, scene_names

    print(
        f"{'scene':8s} {'arena':7s} {'static':>6s} {'dynamic':>7s} {'predictor':>18s} {'limit s':>7s}  description"
    )
    for name in scene_names():
        s = load_scene(name)
        print(
            f"{name:8s} {s.arena:7s} {s.static.count:6d} {s.movers.count:7d} {s.episode.predictor:>18s} "
            f"{s.episode.time_limit:7.0f}  {s.description}"
        )
    return 0


def _format_summary(name: str, policy: str, predictor: str, summary: dict[str, float], wall: float) -> str:
    rows = [
        ("episodes", f"{summary['episodes']:.0f}"),
        ("success", f"{100 * summary['goal_rate']:.1f} %"),
        ("collision", f"{100 * summary['collision_rate']:.1f} %"),
        ("timeout", f"{100 * summary['timeout_rate']:.1f} %"),
        ("left the surface", f"{100 * summary['off_surface_rate']:.1f} %"),
        ("physics diverged", f"{100 * summary['diverged_rate']:.1f} %"),
        ("path length (successes)", f"{summary['path_length']:.1f} m"),
        ("path / straight distance", f"{summary['path_ratio']:.3f}"),
        ("turning angle (successes)", f"{summary['turning_angle_deg']:.1f} deg"),
        ("time to goal", f"{summary['time_to_goal']:.1f} s"),
        ("mean episode reward", f"{summary['mean_reward']:.1f}"),
        ("minimum clearance", f"{summary['min_clearance']:.2f} m"),
        ("wall time", f"{wall:.1f} s"),
    ]
    width = max(len(r[0]) for r in rows)
    head = f"| {'scene ' + name + ', policy ' + policy + ', predictor ' + predictor:<{width + 14}} |"
    lines = [head, f"|{'-' * (width + 2)}|{'-' * 13}|"]
    lines += [f"| {k:<{width}} | {v:>11} |" for k, v in rows]
    return "\n".join(lines)


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    import deck_sim
    from deck_sim.metrics import summarize
    from deck_sim.policies import make_policy
    from deck_sim.rollout import run_episode

    overrides = {}
    predictor = args.predictor or ("oracle" if args.policy == "scripted" else None)
    if predictor:
        overrides["episode__predictor"] = predictor
    env = deck_sim.load(args.scene, seed=args.seed, **overrides)
    predictor = env.task.predictor.name
    policy = make_policy(args.policy, env, seed=args.seed)
    results = []
    t0 = time.perf_counter()
    with tqdm(range(args.episodes), desc=f"{args.scene} {args.policy}", unit="ep", disable=args.quiet) as bar:
        for k in bar:
            r = run_episode(env, policy, episode=k)
            results.append(r)
            wins = sum(x.outcome == "goal" for x in results)
            bar.set_postfix(success=f"{100 * wins / len(results):.0f}%", last=r.outcome)
    wall = time.perf_counter() - t0
    summary = summarize(results)
    table = _format_summary(args.scene, args.policy, predictor, summary, wall)
    print(table)
    out = Path(args.out) if args.out else Path("runs") / f"{args.scene}-{args.policy}-seed{args.seed}"
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(results[0].as_dict()))
        writer.writeheader()
        writer.writerows(r.as_dict() for r in results)
    meta = {
        "scene": args.scene,
        "policy": args.policy,
        "predictor": predictor,
        "seed": args.seed,
        "episodes": args.episodes,
        "deck_sim": deck_sim.__version__,
        "summary": summary,
        "wall_s": wall,
    }
    (out / "summary.json").write_text(json.dumps(meta, indent=2))
    (out / "results.md").write_text(table + "\n")
    print(f"wrote {out / 'results.md'}, {out / 'summary.json'}, {out / 'episodes.csv'}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    import imageio.v3 as iio

    import deck_sim
    from deck_sim.policies import make_policy

    env = deck_sim.load(
        args.scene, seed=args.seed, **({"episode__predictor": "oracle"} if args.policy == "scripted" else {})
    )
    policy = make_policy(args.policy, env, seed=args.seed)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    ts = env.reset()
    policy.reset()
    frames = [env.physics.render(args.height, args.width, camera_id="agent/chase")]
    steps = 0
    while not ts.last() and steps < args.steps:
        ts = env.step(policy.act(ts.observation))
        frames.append(env.physics.render(args.height, args.width, camera_id="agent/chase"))
        steps += 1
    fps = args.speedup / env.task.control_timestep
    iio.imwrite(out, np.stack(frames), fps=fps, codec="libx264", macro_block_size=8)
    png = Path(args.png) if args.png else out.with_suffix(".png")
    h = args.top_height
    w = int(round(h * env.task.top_view_aspect / 8)) * 8
    iio.imwrite(png, env.physics.render(h, w, camera_id="top"))
    outcome = env.task.last_info
    print(
        f"wrote {out} ({len(frames)} frames at {fps:g} fps) and {png} ({w}x{h}); "
        f"goal={outcome['reached_goal']} collision={outcome['collision']}"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``deck-sim``."""
    parser = argparse.ArgumentParser(
        prog="deck-sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log diagnostics")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list the scenes")
    p.set_defaults(func=_cmd_scenes)

    p = sub.add_parser("run", help="play episodes with a policy and report the metrics")
    p.add_argument("--scene", default="deck1", help="scene name or TOML path (default deck1)")
    p.add_argument("--policy", default="scripted", help="scripted (full knowledge), random or zero")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0, help="seeds layouts and movers (default 0)")
    p.add_argument(
        "--predictor",
        default=None,
        help="none, constant_velocity, oracle or mpc (default: oracle for scripted, else the scene's)",
    )
    p.add_argument("--out", default=None, help="folder for results.md, summary.json, episodes.csv")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("render", help="write a short MP4 (offscreen, MUJOCO_GL=egl) and a top-down PNG")
    p.add_argument("--scene", default="deck1")
    p.add_argument("--policy", default="scripted")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="ep.mp4", help="video path (default ep.mp4)")
    p.add_argument("--png", default=None, help="top-down picture path (default: the video's, .png)")
    p.add_argument("--steps", type=int, default=120, help="control steps at most (default 120)")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--top-height", type=int, default=400, help="height of the top-down PNG in pixels")
    p.add_argument("--speedup", type=float, default=2.0, help="video playback speed over real time")
    p.set_defaults(func=_cmd_render)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``deck-sim``; returns the exit code (2 with a message on bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    from deck_sim.scenes import SceneSpecError

    try:
        return int(args.func(args))
    except (SceneSpecError, ValueError) as err:
        print(f"deck-sim {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
