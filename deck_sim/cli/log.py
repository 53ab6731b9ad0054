"""``deck-sim log``: read an episode log (MCAP): a summary, a plot, a video, CSV files, or a repaired copy."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from deck_sim.cli._common import HelpFormatter, add_command, fmt


def cmd_log_info(args: argparse.Namespace) -> int:
    """Print the run's metadata, the topics and one line per episode, re-scored from the log alone."""
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
    if log.summary_damage:
        print(f"summary   damaged at {log.summary_damage}; the data section is whole and was read in full")
    print("topics")
    width = max([14, *(len(t) for t in log.topics)])
    for t in sorted(log.topics.values(), key=lambda t: t.topic):
        print(f"  {t.topic:{width}s} {t.schema_name:26s} {t.message_encoding:9s} {t.count:7d} messages")
    head = (
        f"{'episode':>7s}  {'outcome':11s} {'steps':>5s} {'time s':>7s} {'path m':>7s} {'turn deg':>8s} "
        f"{'clear m':>7s} {'return':>8s} {'ADE m':>6s} {'FDE m':>6s}  collision"
    )
    print(head)
    for ep in log.episodes:
        if not ep.complete:
            steps = len(ep.team_steps if ep.team else ep.steps) - 1
            print(f"{ep.index:7d}  {'incomplete':11s} {steps:5d} {ep.duration:7.1f}  (the log stops here)")
            continue
        if ep.team:
            _team_rows(ep)
            continue
        s = ep.rescore()
        r = s.result
        print(
            f"{r.episode:7d}  {r.outcome:11s} {r.steps:5d} {r.sim_time:7.1f} {r.path_length:7.1f} "
            f"{r.turning_angle_deg:8.1f} {r.min_clearance:7.2f} {r.reward:8.2f} {fmt(s.ade, '6.2f'):>6s} "
            f"{fmt(s.fde, '6.2f'):>6s}  {r.collision_partner or '-'}"
        )
    return 0


def _team_rows(ep) -> None:  # noqa: ANN001 - a LoggedEpisode of several aircraft
    """``log info``'s rows of an episode of several aircraft: the team's line, then one per aircraft."""
    team = ep.rescore_team()
    reached = sum(r.outcome == "goal" for r in team.aircraft)
    print(
        f"{ep.index:7d}  {reached} of {len(team.aircraft)} aircraft reached their targets; makespan "
        f"{fmt(team.makespan, '.1f')} s, {team.aircraft_collisions} aircraft-aircraft collision(s)"
    )
    for name, r in zip(ep.scene.agent_names, team.aircraft, strict=True):
        print(
            f"{name:>16s}  {r.outcome:11s} {r.steps:5d} {r.sim_time:7.1f} {r.path_length:7.1f} "
            f"{r.turning_angle_deg:8.1f} {r.min_clearance:7.2f} {r.reward:8.2f} {'-':>6s} {'-':>6s}  "
            f"{r.collision_partner or '-'}"
        )


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


def cmd_log_plot(args: argparse.Namespace) -> int:
    """Draw one episode from above: the agent's path, every mover's, obstacles and some forecasts."""
    from deck_sim.recording import EpisodeLog
    from deck_sim.recording.plot import plot_episode

    log = EpisodeLog(args.file)
    ep = _log_episode(log, args.episode)
    out = Path(args.out) if args.out else log.path.with_name(f"{log.path.stem}-episode{ep.index}.png")
    plot_episode(ep, out, prediction_steps=_parse_steps(args.steps), width_inches=args.width)
    if ep.team and ep.complete:  # (each aircraft has its outcome)
        reached = sum(r.outcome == "goal" for r in ep.rescore_team().aircraft)
        outcome = f"{reached} of {len(ep.scene.agent_names)} aircraft reached their targets"
    else:
        outcome = ep.outcome or "incomplete"
    print(f"wrote {out} (episode {ep.index}, {outcome})")
    return 0


def cmd_log_video(args: argparse.Namespace) -> int:
    """Pose every logged step in MuJoCo and render it to an MP4."""
    from deck_sim.recording import EpisodeLog
    from deck_sim.replay import (
        MIN_FRAME,
        VIDEO_SUFFIXES,
        check_count,
        check_speedup,
        check_suffix,
        render_episode,
        replay_environment,
    )

    # the arguments first, before the log is read and the scene built (render_episode checks the camera)
    if args.out:
        check_suffix("--out", args.out, VIDEO_SUFFIXES)
    check_count("--width", args.width, MIN_FRAME)
    check_speedup("--speedup", args.speedup)
    check_count("--max-steps", args.max_steps)
    log = EpisodeLog(args.file)
    ep = _log_episode(log, args.episode)
    out = Path(args.out) if args.out else log.path.with_name(f"{log.path.stem}-episode{ep.index}.mp4")
    env = replay_environment(log)
    path, frames, fps = render_episode(
        ep, env, out, width=args.width, camera=args.camera, speedup=args.speedup, max_steps=args.max_steps
    )
    print(f"wrote {path} ({frames} frames at {fps:g} fps, camera {args.camera}, episode {ep.index})")
    return 0


def cmd_log_export(args: argparse.Namespace) -> int:
    """Write the log's steps, episodes (re-scored) and events as three CSV files."""
    from deck_sim.recording import EpisodeLog

    if not args.csv:
        raise ValueError("log export: choose a format (--csv)")
    log = EpisodeLog(args.file)
    folder = Path(args.out) if args.out else log.path.parent
    folder.mkdir(parents=True, exist_ok=True)
    stem = log.path.stem
    steps_path, episodes_path, events_path = (folder / f"{stem}_{k}.csv" for k in ("steps", "episodes", "events"))
    if any(ep.team for ep in log.episodes):
        rows, scored = _export_team(log, steps_path, episodes_path)
        _export_events(log, events_path)
        print(f"wrote {steps_path} ({rows} aircraft steps), {episodes_path} ({scored} complete episodes, one row per "
              f"aircraft), {events_path}")
        return 0
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
    _export_events(log, events_path)
    print(f"wrote {steps_path} ({rows} steps), {episodes_path} ({len(scored)} complete episodes), {events_path}")
    return 0


def _export_events(log, path: Path) -> None:  # noqa: ANN001 - an EpisodeLog
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "log_time_ns", "kind", "level", "message"])
        for e in log.events():
            w.writerow([e.episode, e.time_ns, e.kind, e.level, e.message])


def _export_team(log, steps_path: Path, episodes_path: Path) -> tuple[int, int]:  # noqa: ANN001 - an EpisodeLog
    """``log export --csv`` of a log of several aircraft: one steps row per aircraft and step (its state record's
    fields, ``x``, ``y`` where its path stands), one episodes row per aircraft of each complete episode (its
    ``rescore_team`` result); the counts of both."""
    from dataclasses import fields

    from deck_sim.metrics import EpisodeResult

    step_fields = [
        "episode", "step", "time", "aircraft", "x", "y", "heading", "speed", "action_x", "action_y", "r1", "r2", "r3",
        "r4", "total", "distance_to_goal", "min_clearance", "predictor_fallbacks", "collision", "reached_goal",
        "left_surface", "done", "diverged", "last", "discount",
    ]  # fmt: skip
    rows = 0
    with open(steps_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(step_fields)
        for ep in log.episodes:
            for s in ep.team_steps:
                for a in s.aircraft:
                    act = (None, None) if a.action is None else (float(a.action[0]), float(a.action[1]))
                    t = a.reward_terms
                    w.writerow([
                        s.episode, s.step, s.time, a.name, float(a.track_xy[0]), float(a.track_xy[1]), a.heading,
                        a.speed, *act, t["r1"], t["r2"], t["r3"], t["r4"], t["total"], a.distance_to_goal,
                        a.min_clearance, s.predictor_fallbacks, a.collision or "", a.reached_goal, a.left_surface,
                        a.done, s.diverged, s.last, a.discount,
                    ])  # fmt: skip
                    rows += 1
    scored = 0
    with open(episodes_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["aircraft", *(fl.name for fl in fields(EpisodeResult)), "shortest"])
        w.writeheader()
        for ep in log.episodes:
            if not ep.complete:
                continue
            team = ep.rescore_team()
            for name, r, bound in zip(ep.scene.agent_names, team.aircraft, team.shortest, strict=True):
                w.writerow({"aircraft": name, **r.as_dict(), "shortest": bound})
            scored += 1
    return rows, scored


def cmd_log_recover(args: argparse.Namespace) -> int:
    """Copy every complete message of a truncated or damaged log into a new, valid file with a new summary."""
    from deck_sim.recording import recover

    rec = recover(args.file, args.out)
    if rec.was_truncated:
        state = f"truncated at {rec.stopped_at}"
    elif rec.summary_damage:
        state = f"whole in its data, its summary section damaged at {rec.summary_damage} (the copy has a new one)"
    else:
        state = "whole (nothing was lost)"
    print(
        f"wrote {rec.path}: {rec.messages} messages, {rec.episodes_complete} complete episode(s), "
        f"{rec.episodes_incomplete} incomplete; the source was {state}"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``log info|plot|video|export|recover FILE`` to the subcommands."""
    parent = sub.add_parser(
        "log", help="read an episode log (MCAP): info, plot, video, export, recover",
        description="Read an episode log (MCAP) written by deck-sim run or deck-sim eval.",
        formatter_class=HelpFormatter,
    )
    log_sub = parent.add_subparsers(dest="log_command", required=True)

    p = add_command(log_sub, "info", cmd_log_info, "episodes, outcomes, re-scored metrics, topics and message counts")
    p.add_argument("file", help="the MCAP episode log")

    p = add_command(log_sub, "plot", cmd_log_plot, "a top-down PNG of an episode: paths, obstacles, predictions")
    p.add_argument("file", help="the MCAP episode log")
    p.add_argument("--episode", type=int, default=None, help="episode index (default: the first)")
    p.add_argument("--out", default=None, help="PNG path (default: beside the log)")
    p.add_argument("--steps", default=None, help="comma-separated steps whose predictions to draw (default: 4 steps)")
    p.add_argument("--width", type=float, default=16.0, help="figure width in inches")

    p = add_command(log_sub, "video", cmd_log_video, "an MP4 replay of an episode rendered with MuJoCo (MUJOCO_GL=egl)")
    p.add_argument("file", help="the MCAP episode log")
    p.add_argument("--episode", type=int, default=None, help="episode index (default: the first)")
    p.add_argument("--out", default=None, help="MP4 path (default: beside the log)")
    p.add_argument("--width", type=int, default=640, help="frame width in pixels (rounded to a multiple of 16)")
    p.add_argument("--camera", default="top", help="top, follow or agent/chase")
    p.add_argument("--speedup", type=float, default=4.0, help="playback speed over simulated time")
    p.add_argument("--max-steps", type=int, default=None, help="render at most this many steps")

    p = add_command(log_sub, "export", cmd_log_export, "steps, episodes (re-scored) and events as CSV files")
    p.add_argument("file", help="the MCAP episode log")
    p.add_argument("--csv", action="store_true", help="write CSV (the one format)")
    p.add_argument("--out", default=None, help="folder for the CSV files (default: beside the log)")

    p = add_command(log_sub, "recover", cmd_log_recover,
                    "turn a truncated or damaged log (writer killed) into a valid one")
    p.add_argument("file", help="the truncated or damaged MCAP episode log")
    p.add_argument("--out", default=None, help="output path (default: <name>.recovered.mcap beside it)")
