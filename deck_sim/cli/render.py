"""``deck-sim render``: a short offscreen video from a camera behind the agent, and a top-down picture."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deck_sim.cli._common import add_command, refuse_multi_agent

CAMERA = "agent/chase"
"""The camera the video is filmed from."""


def cmd_render(args: argparse.Namespace) -> int:
    """Play one episode for at most ``--steps`` steps, filming it from the agent's chase camera."""
    import imageio.v3 as iio

    import deck_sim
    from deck_sim.policies import make_policy, policy_overrides
    from deck_sim.replay import (
        IMAGE_SUFFIXES,
        MIN_FRAME,
        VIDEO_SUFFIXES,
        check_count,
        check_speedup,
        check_suffix,
        check_view,
    )

    # every argument is checked before the scene is built, every size before the first frame
    out = check_suffix("--out", args.out, VIDEO_SUFFIXES)
    png = check_suffix("--png", args.png, IMAGE_SUFFIXES) if args.png else out.with_suffix(".png")
    if png.resolve() == out.resolve():
        raise ValueError(f"--png {png}: the picture would overwrite the video; give another path")
    for flag, value in (("--width", args.width), ("--height", args.height), ("--top-height", args.top_height)):
        check_count(flag, value, MIN_FRAME)
    check_count("--steps", args.steps)
    check_speedup("--speedup", args.speedup)
    refuse_multi_agent("render", args.scene)
    env = deck_sim.load(args.scene, seed=args.seed, **policy_overrides(args.policy, Path(args.scene).stem))
    h = args.top_height
    w = int(round(h * env.task.top_view_aspect / 8)) * 8
    check_view(env.physics, CAMERA, {"--width x --height": (args.width, args.height)})
    check_view(env.physics, "top", {f"the top-down picture (--top-height {h})": (w, h)})
    policy = make_policy(args.policy, env, seed=args.seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    ts = env.reset()
    policy.reset()
    frames = [env.physics.render(args.height, args.width, camera_id=CAMERA)]
    steps = 0
    while not ts.last() and steps < args.steps:
        ts = env.step(policy.act(ts.observation))
        frames.append(env.physics.render(args.height, args.width, camera_id=CAMERA))
        steps += 1
    fps = args.speedup / env.task.control_timestep
    iio.imwrite(out, np.stack(frames), fps=fps, codec="libx264", macro_block_size=8)
    iio.imwrite(png, env.physics.render(h, w, camera_id="top"))
    outcome = env.task.last_info
    print(
        f"wrote {out} ({len(frames)} frames at {fps:g} fps) and {png} ({w}x{h}); "
        f"goal={outcome['reached_goal']} collision={outcome['collision']}"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``render`` to the subcommands."""
    from deck_sim.agents import policy_help

    p = add_command(
        sub, "render", cmd_render, "write a short MP4 (offscreen, MUJOCO_GL=egl) and a top-down PNG of an episode",
        "Rendering is software rendering on a machine without a GPU: keep videos short and small.",
    )
    p.add_argument("--scene", default="deck1", help="scene name or TOML path")
    p.add_argument("--policy", default="scripted", help=policy_help())
    p.add_argument("--seed", type=int, default=0, help="seeds the layout and movers")
    p.add_argument("--out", default="ep.mp4", help="video path (.mp4, .mkv, .mov, .avi or .gif)")
    p.add_argument("--png", default=None, help="top-down picture path (default: the video's, .png)")
    p.add_argument("--steps", type=int, default=120, help="control steps at most")
    p.add_argument("--width", type=int, default=480, help="video width in pixels")
    p.add_argument("--height", type=int, default=360, help="video height in pixels")
    p.add_argument("--top-height", type=int, default=400, help="height of the top-down PNG in pixels")
    p.add_argument("--speedup", type=float, default=2.0, help="video playback speed over simulated time")
