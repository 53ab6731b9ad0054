"""``deck-sim``: the command line of deck_sim.

deck-sim scenes                                     list the scenes
deck-sim run --scene deck1 --policy scripted --episodes 20
                                                    play episodes, print and save the metrics
deck-sim render --scene deck2 --out ep.mp4          a short video (offscreen) and a top-down PNG
deck-sim train --algo mddpg --scene deck1 --steps 60000 --seed 0
                                                    train an agent (also ddpg; dqn, a2c via stable-baselines3)
deck-sim log info runs/deck1-scripted-seed0/episodes.mcap
                                                    an episode log: episodes, outcomes, topics (also: log plot,
                                                    log video, log export --csv, log recover)
"""

from __future__ import annotations

import os

os.environ.setdefault(
    "MUJOCO_GL", "egl"
)  # offscreen rendering on a headless machine; set before mujoco loads

import argparse  # noqa: E402
import contextlib  # noqa: E402
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


def _policy_label(policy: str) -> str:
    """A policy's name for folder names (an actor file's stem)."""
    return Path(policy).stem if policy.endswith(".npz") else policy


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    import deck_sim
    from deck_sim.metrics import summarize
    from deck_sim.policies import make_policy, policy_overrides
    from deck_sim.rollout import run_episode

    overrides = policy_overrides(args.policy, Path(args.scene).stem)
    if args.predictor:
        overrides["episode__predictor"] = args.predictor
    scene_set = _scene_set(args.scene_set)
    for key, value in scene_set.items():
        # an actor's observation fields (and --predictor) are not to be changed behind its back
        if key in overrides and overrides[key] != value:
            given = "--predictor" if key == "episode__predictor" and args.predictor else f"policy {args.policy!r}"
            raise ValueError(
                f"--scene-set {key.replace('__', '.')}={value!r} contradicts {given}, which needs {overrides[key]!r}"
            )
    overrides.update(scene_set)
    env = deck_sim.load(args.scene, seed=args.seed, **overrides)
    predictor = env.task.predictor.name
    policy = make_policy(args.policy, env, seed=args.seed)
    # a variant of the scene gets its own default folder (its fields in the name), not the plain scene's
    variant = "".join(f"-{k.split('__', 1)[1]}={v}" for k, v in scene_set.items())
    default_out = Path("runs") / f"{args.scene}-{_policy_label(args.policy)}-seed{args.seed}{variant}"
    out = Path(args.out) if args.out else default_out
    recorder = _open_run_recorder(args, env, out)
    results = []
    t0 = time.perf_counter()
    bar = tqdm(range(args.episodes), desc=f"{args.scene} {args.policy}", unit="ep", disable=args.quiet)
    with bar, recorder or contextlib.nullcontext():  # the log is finished even if a run fails
        for k in bar:
            r = run_episode(env, policy, episode=k, recorder=recorder)
            results.append(r)
            wins = sum(x.outcome == "goal" for x in results)
            bar.set_postfix(success=f"{100 * wins / len(results):.0f}%", last=r.outcome)
    wall = time.perf_counter() - t0
    summary = summarize(results)
    table = _format_summary(args.scene, args.policy, predictor, summary, wall)
    print(table)
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
        "scene_set": scene_set,
        "deck_sim": deck_sim.__version__,
        "summary": summary,
        "wall_s": wall,
    }
    (out / "summary.json").write_text(json.dumps(meta, indent=2))
    (out / "results.md").write_text(table + "\n")
    print(f"wrote {out / 'results.md'}, {out / 'summary.json'}, {out / 'episodes.csv'}")
    if recorder is not None:
        print(f"wrote {recorder.path} (episode log: deck-sim log info {recorder.path})")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    import imageio.v3 as iio

    import deck_sim
    from deck_sim.policies import make_policy, policy_overrides

    env = deck_sim.load(args.scene, seed=args.seed, **policy_overrides(args.policy, Path(args.scene).stem))
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


def _scene_set(items: list[str]) -> dict[str, object]:
    """``--scene-set section.field=value`` pairs as ``deck_sim.load`` overrides (``section__field``), values
    parsed as JSON where they can be, else strings; the scene checks the names and values."""
    from deck_sim.scenes import SECTIONS

    out = {}
    for key, value in _parse_set(items, flag="--scene-set").items():
        section, dot, field = key.partition(".")
        if not dot or not section or not field:
            raise ValueError(f"--scene-set expects section.field=value (e.g. movers.yield_distance=12), got {key!r}")
        if section not in SECTIONS:
            raise ValueError(f"--scene-set {key}: no section [{section}]; the sections are {', '.join(SECTIONS)}")
        out[f"{section}__{field}"] = value
    return out


# -- training: `deck-sim train` --------------------------------------------------------------------------------
def _parse_set(items: list[str], flag: str = "--set") -> dict[str, object]:
    """``--set field=value`` pairs as config fields (values parsed as JSON where they can be, else strings)."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{flag} expects field=value, got {item!r}")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def _cmd_train(args: argparse.Namespace) -> int:
    from training.config import ConfigError
    from training.loop import CheckpointError

    out = Path(args.out) if args.out else Path("runs") / f"train-{args.algo}-{Path(args.scene).stem}-seed{args.seed}"
    try:
        if args.algo in ("dqn", "a2c"):
            from training.baselines import train_baseline

            summary = train_baseline(args.algo, args.scene, args.steps, args.seed, out, resume=args.resume,
                                     progress=not args.quiet, **_parse_set(args.set))
        else:
            from training.config import TrainConfig, make_config
            from training.loop import Trainer, config_from_checkpoint

            if args.resume:
                from training.loop import RESUMABLE_CHANGES

                config = config_from_checkpoint(out)
                if args.steps is not None:
                    config.total_steps = int(args.steps)
                changes = _parse_set(args.set)
                fixed = sorted(set(changes) - set(RESUMABLE_CHANGES))
                if fixed:
                    raise ConfigError(
                        f"--resume keeps the run's config; --set may change only {', '.join(RESUMABLE_CHANGES)}, "
                        f"not {', '.join(fixed)}"
                    )
                config = TrainConfig.from_dict({**config.to_dict(), **changes})
            else:
                fields = {"algo": args.algo, "scene": args.scene, "seed": args.seed, **_parse_set(args.set)}
                if args.steps is not None:
                    fields["total_steps"] = args.steps
                config = make_config(args.preset, **fields)
            summary = Trainer(config, out, resume=args.resume, progress=not args.quiet).train()
    except (ConfigError, CheckpointError) as err:
        print(f"deck-sim train: error: {err}", file=sys.stderr)
        return 2
    ev = summary.get("eval") or {}
    if ev:
        print(
            f"{args.algo} on {args.scene}: {summary['step']} steps in {summary['wall_s']:.0f} s; held-out "
            f"success {100 * ev['goal_rate']:.1f} %, collision {100 * ev['collision_rate']:.1f} %, "
            f"timeout {100 * ev['timeout_rate']:.1f} %, mean reward {ev['mean_reward']:.1f}"
        )
    if summary.get("stopped"):
        print(f"stopped at step {summary['step']}; continue with: deck-sim train --algo {args.algo} "
              f"--out {out} --resume")
    actor = "exported actor actor.npz" if (out / "actor.npz").exists() else "no actor yet (the run is not finished)"
    print(f"wrote {out} (config.json, progress.csv, eval.csv, tb/, checkpoint; {actor})")
    return 0


# -- episode logs (MCAP): `run --record` and `deck-sim log ...` ------------------------------------------------
def _add_record_arguments(p: argparse.ArgumentParser) -> None:
    """``--record FILE`` / ``--no-record`` of ``deck-sim run``."""
    p.add_argument(
        "--record",
        default=None,
        metavar="FILE.mcap",
        help="write every episode to this MCAP episode log (default: episodes.mcap in the run's folder)",
    )
    p.add_argument("--no-record", action="store_true", help="write no episode log")


def _open_run_recorder(args: argparse.Namespace, env, out: Path):  # noqa: ANN001, ANN202 - lazy imports
    """The recorder of ``deck-sim run`` (``None`` with ``--no-record``), replacing an earlier log of the run."""
    if args.no_record:
        return None
    from deck_sim.rollout import open_recorder

    path = Path(args.record) if args.record else out / "episodes.mcap"
    path.parent.mkdir(parents=True, exist_ok=True)
    config = {k: getattr(args, k) for k in ("command", "scene", "policy", "episodes", "seed", "predictor")}
    from deck_sim.policies import policy_file

    actor = policy_file(args.policy, env.task.spec.name)
    return open_recorder(path, env, seed=args.seed, policy=args.policy, config=config, overwrite=True,
                         checkpoint=str(actor) if actor is not None else "")


def _fmt(x: float, spec: str) -> str:
    return "-" if x != x else format(x, spec)  # NaN: no value


def _cmd_log_info(args: argparse.Namespace) -> int:
    from deck_sim.recording import EpisodeLog

    log = EpisodeLog(args.file)
    m = log.metadata
    size = log.path.stat().st_size
    complete = [ep for ep in log.episodes if ep.complete]
    print(f"file      {log.path} ({size / 1024:.1f} KiB, {log.library})")
    print(
        f"run       scene {m.get('scene')}, seed {m.get('seed')}, policy {m.get('policy')}, "
        f"predictor {m.get('predictor')}, checkpoint {m.get('checkpoint') or '-'}"
    )
    print(
        f"software  deck_sim {m.get('deck_sim_version')}, mujoco {m.get('mujoco_version')}, git {m.get('git_commit')}"
    )
    print(
        f"episodes  {len(log.episodes)} ({len(complete)} complete), {log.duration:.1f} s simulated; "
        f"attachments: {', '.join(sorted(log.attachments)) or '-'}"
    )
    print("topics")
    for t in sorted(log.topics.values(), key=lambda t: t.topic):
        print(f"  {t.topic:14s} {t.schema_name:26s} {t.message_encoding:9s} {t.count:7d} messages")
    head = (
        f"{'episode':>7s}  {'outcome':11s} {'steps':>5s} {'time s':>7s} {'path m':>7s} {'turn deg':>8s} "
        f"{'clear m':>7s} {'return':>8s} {'ADE m':>6s} {'FDE m':>6s}  collision"
    )
    print(head)
    for ep in log.episodes:
        if not ep.complete:
            print(f"{ep.index:7d}  {'incomplete':11s} {len(ep.steps) - 1:5d} {ep.duration:7.1f}  (the log stops here)")
            continue
        s = ep.rescore()
        r = s.result
        print(
            f"{r.episode:7d}  {r.outcome:11s} {r.steps:5d} {r.sim_time:7.1f} {r.path_length:7.1f} "
            f"{r.turning_angle_deg:8.1f} {r.min_clearance:7.2f} {r.reward:8.2f} {_fmt(s.ade, '6.2f'):>6s} "
            f"{_fmt(s.fde, '6.2f'):>6s}  {r.collision_partner or '-'}"
        )
    return 0


def _parse_steps(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--steps: expected comma-separated step numbers, got {text!r}") from None


def _log_episode(log, index: int | None):  # noqa: ANN001, ANN202 - lazy imports
    if index is not None:
        return log.episode(index)
    if not log.episodes:
        raise ValueError(f"{log.path}: the log holds no episode")
    return log.episodes[0]


def _cmd_log_plot(args: argparse.Namespace) -> int:
    from deck_sim.recording import EpisodeLog
    from deck_sim.recording.plot import plot_episode

    log = EpisodeLog(args.file)
    ep = _log_episode(log, args.episode)
    out = Path(args.out) if args.out else log.path.with_name(f"{log.path.stem}-episode{ep.index}.png")
    plot_episode(ep, out, prediction_steps=_parse_steps(args.steps), width_inches=args.width)
    print(f"wrote {out} (episode {ep.index}, {ep.outcome or 'incomplete'})")
    return 0


def _cmd_log_video(args: argparse.Namespace) -> int:
    from deck_sim.recording import EpisodeLog
    from deck_sim.replay import render_episode, replay_environment

    log = EpisodeLog(args.file)
    ep = _log_episode(log, args.episode)
    out = Path(args.out) if args.out else log.path.with_name(f"{log.path.stem}-episode{ep.index}.mp4")
    env = replay_environment(log)
    path, frames, fps = render_episode(
        ep, env, out, width=args.width, camera=args.camera, speedup=args.speedup, max_steps=args.max_steps
    )
    print(f"wrote {path} ({frames} frames at {fps:g} fps, camera {args.camera}, episode {ep.index})")
    return 0


def _cmd_log_export(args: argparse.Namespace) -> int:
    from deck_sim.recording import EpisodeLog

    if not args.csv:
        raise ValueError("log export: choose a format (--csv)")
    log = EpisodeLog(args.file)
    folder = Path(args.out) if args.out else log.path.parent
    folder.mkdir(parents=True, exist_ok=True)
    stem = log.path.stem
    steps_path, episodes_path, events_path = (folder / f"{stem}_{k}.csv" for k in ("steps", "episodes", "events"))
    mover_names = log.episodes[0].scene.mover_names if log.episodes else ()
    step_fields = [
        "episode", "step", "time", "x", "y", "heading", "speed", "action_x", "action_y", "r1", "r2", "r3", "r4",
        "total", "distance_to_goal", "min_clearance", "predictor_fallbacks", "collision", "reached_goal",
        "left_surface", "diverged", "last", "discount",
    ]  # fmt: skip
    step_fields += [f"{name}_{c}" for name in mover_names for c in ("x", "y")]
    rows = 0
    with open(steps_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(step_fields)
        for s in log.steps():
            a = (None, None) if s.action is None else (float(s.action[0]), float(s.action[1]))
            t = s.reward_terms
            row = [
                s.episode, s.step, s.time, float(s.agent_xy[0]), float(s.agent_xy[1]), s.heading, s.speed, *a,
                t["r1"], t["r2"], t["r3"], t["r4"], t["total"], s.distance_to_goal, s.min_clearance,
                s.predictor_fallbacks, s.collision or "", s.reached_goal, s.left_surface, s.diverged, s.last,
                s.discount,
            ]  # fmt: skip
            w.writerow(row + [float(v) for v in s.mover_xy.reshape(-1)])
            rows += 1
    scored = [(ep.rescore(), ep) for ep in log.episodes if ep.complete]
    with open(episodes_path, "w", newline="") as f:
        fields = [*(scored[0][0].result.as_dict() if scored else {}), "ade", "fde", "prediction_samples"]
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for s, _ in scored:
            w.writerow({**s.result.as_dict(), "ade": s.ade, "fde": s.fde, "prediction_samples": s.prediction_samples})
    with open(events_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "log_time_ns", "kind", "level", "message"])
        for e in log.events():
            w.writerow([e.episode, e.time_ns, e.kind, e.level, e.message])
    print(f"wrote {steps_path} ({rows} steps), {episodes_path} ({len(scored)} complete episodes), {events_path}")
    return 0


def _cmd_log_recover(args: argparse.Namespace) -> int:
    from deck_sim.recording import recover

    rec = recover(args.file, args.out)
    state = f"truncated at {rec.stopped_at}" if rec.was_truncated else "whole (nothing was lost)"
    print(
        f"wrote {rec.path}: {rec.messages} messages, {rec.episodes_complete} complete episode(s), "
        f"{rec.episodes_incomplete} incomplete; the source was {state}"
    )
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from training.evaluate import EvalConfig, evaluate, plot_learning_curves, plot_trajectories, write_report

    split = [a.strip() for a in args.agents.split(",") if a.strip()]
    cfg = EvalConfig(
        agents=tuple(split),
        scenes=tuple(s.strip() for s in args.scenes.split(",") if s.strip()),
        episodes=args.episodes,
        seed=args.seed,
        backend=args.backend,
        workers=args.workers,
        ray_address=args.ray_address,
        chunk=args.chunk,
        record=args.record,
        out=args.out,
        near_miss=args.near_miss,
    )
    cfg.validate()
    curves = []
    for item in args.curves:  # checked before any episode runs
        label, _, run = item.partition("=")
        if not label or not run:
            raise ValueError(f"--curves {item!r}: expected LABEL=RUN_FOLDER")
        if not (Path(run) / "eval.csv").exists():
            raise ValueError(f"--curves {item!r}: {Path(run) / 'eval.csv'} does not exist (not a deck-sim train run)")
        curves.append((label, run))
    total = args.episodes * len(cfg.agents) * len(cfg.scenes)
    bar = tqdm(total=total, desc=f"eval ({cfg.backend})", unit="ep", disable=args.quiet)
    wins: dict[str, list[int]] = {}

    def progress(done: int, total: int, batch: list[dict]) -> None:
        bar.update(done - bar.n)
        for r in batch:
            w = wins.setdefault(f"{r['scene']}/{r['agent']}", [0, 0])
            w[0] += r["outcome"] == "goal"
            w[1] += 1
        key = f"{batch[-1]['scene']}/{batch[-1]['agent']}"
        bar.set_postfix({key: f"{100 * wins[key][0] / wins[key][1]:.0f}% of {wins[key][1]}"})

    with bar:
        res = evaluate(cfg, progress=progress)
    paths = write_report(res, args.out)
    print((Path(args.out) / "results.md").read_text())
    figures = plot_trajectories(res, Path(args.out) / "trajectories")
    if curves:
        figures.append(plot_learning_curves(dict(curves), Path(args.out) / "learning_curves.png"))
    print(f"{total} episodes in {res.wall_s:.1f} s ({cfg.backend}); wrote " + ", ".join(str(p) for p in paths.values()))
    if figures:
        print(f"figures: {', '.join(str(f) for f in figures)}")
    if res.config.record != "none":
        print(f"episode logs: {Path(args.out) / 'logs'} (deck-sim log info <file>, or open in Foxglove)")
    return 0


def _cmd_ensemble(args: argparse.Namespace) -> int:
    from deck_sim.policies import EnsemblePolicy, load_actor

    out = Path(args.out)
    if any(Path(a).resolve() == out.resolve() for a in args.actors):
        raise ValueError(f"--out {out} is one of the actors it would be made of; write the ensemble elsewhere")
    members = []
    for a in args.actors:  # an ensemble file given joins by its members: the result is flat, each actor weighs one
        policy = load_actor(a)
        members += policy.members if isinstance(policy, EnsemblePolicy) else [policy]
    ensemble = EnsemblePolicy(members, source=str(out))
    ensemble.save(out)
    meta = ensemble.meta
    print(f"wrote {out}: {len(ensemble.members)} {meta.get('algo', '?')} actors of scene {meta.get('scene', '?')!r} "
          f"(predictor {ensemble.predictor}), acting by their mean action; {out.stat().st_size / 1024:.0f} KiB")
    return 0


def _register_log_commands(sub: argparse._SubParsersAction) -> None:
    """``deck-sim log info|plot|video|export|recover FILE``."""
    log = sub.add_parser("log", help="read an episode log (MCAP): info, plot, video, export, recover")
    log_sub = log.add_subparsers(dest="log_command", required=True)

    p = log_sub.add_parser("info", help="episodes, outcomes, re-scored metrics, topics and message counts")
    p.add_argument("file")
    p.set_defaults(func=_cmd_log_info)

    p = log_sub.add_parser("plot", help="a top-down PNG of an episode: paths, obstacles, predictions")
    p.add_argument("file")
    p.add_argument("--episode", type=int, default=None, help="episode index (default: the first)")
    p.add_argument("--out", default=None, help="PNG path (default: beside the log)")
    p.add_argument("--steps", default=None, help="comma-separated steps whose predictions to draw (default: 4)")
    p.add_argument("--width", type=float, default=16.0, help="figure width in inches (default 16)")
    p.set_defaults(func=_cmd_log_plot)

    p = log_sub.add_parser("video", help="an MP4 replay of an episode rendered with MuJoCo (MUJOCO_GL=egl)")
    p.add_argument("file")
    p.add_argument("--episode", type=int, default=None, help="episode index (default: the first)")
    p.add_argument("--out", default=None, help="MP4 path (default: beside the log)")
    p.add_argument("--width", type=int, default=640, help="frame width in pixels (default 640)")
    p.add_argument("--camera", default="top", help="top (default), follow or agent/chase")
    p.add_argument("--speedup", type=float, default=4.0, help="playback speed over simulated time (default 4)")
    p.add_argument("--max-steps", type=int, default=None, help="render at most this many steps")
    p.set_defaults(func=_cmd_log_video)

    p = log_sub.add_parser("export", help="steps, episodes (re-scored) and events as CSV files")
    p.add_argument("file")
    p.add_argument("--csv", action="store_true", help="write CSV (the one format so far)")
    p.add_argument("--out", default=None, help="folder for the CSV files (default: beside the log)")
    p.set_defaults(func=_cmd_log_export)

    p = log_sub.add_parser("recover", help="turn a truncated log (writer killed) into a valid one")
    p.add_argument("file")
    p.add_argument("--out", default=None, help="output path (default: <name>.recovered.mcap beside it)")
    p.set_defaults(func=_cmd_log_recover)


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
    p.add_argument("--policy", default="scripted",
                   help="scripted (full knowledge; scripted-body: checking the aircraft's nose and tail), apf, astar, "
                        "mpc (classical references), random, zero, a shipped "
                        "learned policy (mddpg, ddpg, dqn, a2c) "
                        "or an actor .npz file")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0, help="seeds layouts and movers (default 0)")
    p.add_argument(
        "--predictor",
        default=None,
        help="none, constant_velocity, oracle or mpc (default: oracle for scripted, else the scene's)",
    )
    p.add_argument("--scene-set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override a field of the scene file, e.g. --scene-set movers.agent_yield_braking=2.0 "
                        "(recorded in summary.json)")
    p.add_argument("--out", default=None, help="folder for results.md, summary.json, episodes.csv")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)
    _add_record_arguments(p)

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

    p = sub.add_parser("train", help="train an agent (mddpg, ddpg; dqn, a2c through stable-baselines3)")
    p.add_argument("--algo", default="mddpg", choices=("mddpg", "ddpg", "dqn", "a2c"))
    p.add_argument("--scene", default="deck1", help="scene name or TOML path (default deck1)")
    p.add_argument("--steps", type=int, default=None, help="environment steps (default: the preset's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--preset", default="tuned", help="tuned (default: the switches that pay) or paper (plain DDPG)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a TrainConfig field, e.g. --set twin_critics=false --set hidden=[128,128]")
    p.add_argument("--out", default=None, help="run folder (default runs/train-<algo>-<scene>-seed<seed>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("eval", help="task-suite evaluation: agents x scenes on held-out episodes, tables and logs")
    p.add_argument("--agents", default="mddpg,ddpg,apf,astar,mpc",
                   help="comma-separated: mddpg, ddpg, dqn, a2c (shipped), apf, astar, mpc (classical), scripted, "
                        "scripted-body, random, zero, or label=actor.npz (default mddpg,ddpg,apf,astar,mpc)")
    p.add_argument("--scenes", default="deck1,deck2,square", help="comma-separated scene names or TOML paths")
    p.add_argument("--episodes", type=int, default=100, help="episodes per scene and agent (default 100)")
    p.add_argument("--seed", type=int, default=100_000,
                   help="seed of episode 0; episode i uses seed+i, below every training seed (default 100000)")
    p.add_argument("--backend", default="process", choices=("serial", "process", "ray"),
                   help="process pool (default), serial, or ray (pip install 'deck-sim[ray]')")
    p.add_argument("--workers", type=int, default=None, help="worker processes / Ray CPUs (default: CPU count)")
    p.add_argument("--ray-address", default=None, help="address of an existing Ray cluster (default: start one)")
    p.add_argument("--chunk", type=int, default=5, help="episodes per work unit (default 5)")
    p.add_argument("--record", default="2", help="episodes logged per scene and agent: all, none or N (default 2)")
    p.add_argument("--near-miss", type=float, default=None, help="near-miss clearance, m (default: half the reach)")
    p.add_argument("--curves", action="append", default=[], metavar="LABEL=RUN_FOLDER",
                   help="plot learning curves from a deck-sim train run folder (repeatable)")
    p.add_argument("--out", default="runs/eval", help="results folder (default runs/eval)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_eval)

    p = sub.add_parser("ensemble", help="join actor files into one policy that acts by the mean of their actions")
    p.add_argument("actors", nargs="+", help="actor .npz files (deck-sim train's actor.npz; an ensemble file adds its "
                                             "actors), two or more actors of one observation and scene fields")
    p.add_argument("--out", required=True, help="the ensemble .npz to write (an existing file is replaced)")
    p.set_defaults(func=_cmd_ensemble)

    _register_log_commands(sub)
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
    except (SceneSpecError, ValueError, OSError) as err:
        print(f"deck-sim {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
