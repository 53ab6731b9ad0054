"""``deck-sim scenes`` and ``deck-sim run``: list the scenes; play episodes with a policy and report the metrics."""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING

from deck_sim.cli._common import add_command, fmt, policy_label, scene_overrides
from deck_sim.progress import progress

if TYPE_CHECKING:
    from deck_sim.metrics import EpisodeResult, TeamEpisodeResult


def cmd_scenes(args: argparse.Namespace) -> int:
    """Print one line per scene: arena, agents, obstacle counts, default predictor, time limit, description."""
    del args
    from deck_sim.scenes import load_scene, scene_names

    print(
        f"{'scene':12s} {'arena':7s} {'agents':>6s} {'static':>6s} {'dynamic':>7s} {'predictor':>18s} {'limit s':>7s}"
        "  description"
    )
    for name in scene_names():
        s = load_scene(name)
        print(
            f"{name:12s} {s.arena:7s} {s.agents.count:6d} {s.static.count:6d} {s.movers.count:7d} "
            f"{s.episode.predictor:>18s} {s.episode.time_limit:7.0f}  {s.description}"
        )
    return 0


def _two_columns(name: str, policy: str, predictor: str, rows: list[tuple[str, str]]) -> str:
    """A run's metric rows (label, value) as a two-column Markdown table headed by its scene, policy and
    predictor."""
    width = max(len(r[0]) for r in rows)
    head = f"| {'scene ' + name + ', policy ' + policy + ', predictor ' + predictor:<{width + 14}} |"
    lines = [head, f"|{'-' * (width + 2)}|{'-' * 13}|"]
    lines += [f"| {k:<{width}} | {v:>11} |" for k, v in rows]
    return "\n".join(lines)


def format_summary(name: str, policy: str, predictor: str, summary: dict[str, float], wall: float) -> str:
    """The metrics of a run (``deck_sim.metrics.summarize``) as a two-column Markdown table."""
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
    return _two_columns(name, policy, predictor, rows)


INTERRUPTED = 130
"""Exit code of a run stopped by Ctrl-C (SIGINT): 128 + the signal's number, as a shell reports a process that
SIGINT ended, so scripts tell it from bad input (2) and from success (0)."""


def cmd_run(args: argparse.Namespace) -> int:
    """Play ``--episodes`` episodes, print the metrics and write them (and the episode log) into the run's folder.

    ``episodes.csv`` gets each episode's row as the episode ends, so a killed run keeps its finished rows (as its
    log keeps its finished episodes). Ctrl-C stops the run cleanly: the results of the episodes that finished are
    written (``summary.json`` marked ``"stopped"``), the log is closed, and the exit code is ``INTERRUPTED``.
    """
    try:
        return _play(args)
    except KeyboardInterrupt:  # while the scene loads, or a second Ctrl-C while the results are written
        print("deck-sim run: stopped (Ctrl-C)", file=sys.stderr)
        return INTERRUPTED


def _run_overrides(
    args: argparse.Namespace, overrides: dict[str, object]
) -> tuple[dict[str, object], dict[str, object]]:
    """The scene fields of the run: the policy's ``overrides``, ``--predictor``, then ``--scene-set`` (which may
    not contradict the other two); and the ``--scene-set`` fields alone."""
    overrides = dict(overrides)
    if args.predictor:
        overrides["episode__predictor"] = args.predictor
    scene_set = scene_overrides(args.scene_set)
    for key, value in scene_set.items():
        # an actor's observation fields (and --predictor) are not to be changed behind its back
        if key in overrides and overrides[key] != value:
            given = "--predictor" if key == "episode__predictor" and args.predictor else f"policy {args.policy!r}"
            raise ValueError(
                f"--scene-set {key.replace('__', '.')}={value!r} contradicts {given}, which needs {overrides[key]!r}"
            )
    overrides.update(scene_set)
    return overrides, scene_set


def _out_folder(args: argparse.Namespace, scene_set: dict[str, object]) -> Path:
    """``--out``, or ``runs/<scene>-<policy>-seed<seed>`` with a variant's ``--scene-set`` fields in the name."""
    variant = "".join(f"-{k.split('__', 1)[1]}={v}" for k, v in scene_set.items())
    default_out = Path("runs") / f"{args.scene}-{policy_label(args.policy)}-seed{args.seed}{variant}"
    return Path(args.out) if args.out else default_out


def _play(args: argparse.Namespace) -> int:
    """``cmd_run`` but for a Ctrl-C outside the episodes. On a scene of several aircraft one team policy
    (``make_team_policy``) acts for all; the tables count aircraft and episodes in which every one arrived, and the
    log holds every aircraft."""
    import deck_sim
    from deck_sim.metrics import rate_interval, summarize, summarize_team
    from deck_sim.policies import (
        make_policy,
        make_team_policy,
        policy_file,
        policy_overrides,
        team_policy_overrides,
    )
    from deck_sim.policies.regimes import actor_regime, regime_text
    from deck_sim.policies.team import team_policy_file
    from deck_sim.rollout import run_episode, run_team_episode
    from deck_sim.scenes import load_scene

    if args.episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {args.episodes}")
    team = load_scene(args.scene, **scene_overrides(args.scene_set)).multi_agent
    fields = team_policy_overrides if team else policy_overrides
    overrides, scene_set = _run_overrides(args, fields(args.policy, Path(args.scene).stem))
    env = deck_sim.load(args.scene, seed=args.seed, **overrides)
    predictor = env.task.predictor.name
    policy = (make_team_policy if team else make_policy)(args.policy, env, seed=args.seed)
    play = run_team_episode if team else run_episode
    actor = (team_policy_file if team else policy_file)(args.policy, env.task.spec.name)
    out = _out_folder(args, scene_set)
    results = []
    stopped = False
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        label = "--out" if args.out else "the run's folder"
        table = stack.enter_context(_EpisodeTable(out, label, aircraft=env.task.agent_names if team else ()))
        recorder = _open_run_recorder(args, env, out, actor)
        if recorder is not None:
            stack.enter_context(recorder)  # the log is finished even if a run fails or is stopped
        bar = stack.enter_context(
            progress(range(args.episodes), desc=f"{args.scene} {args.policy}", unit="ep", disable=args.quiet)
        )
        try:
            for k in bar:
                results.append(play(env, policy, episode=k, recorder=recorder))
                table.write(results)
                done = _aircraft(results)
                wins = 100 * sum(x.outcome == "goal" for x in done) / len(done)
                bar.set_postfix(**({"reached": f"{wins:.0f}%"} if team else
                                   {"success": f"{wins:.0f}%", "last": results[-1].outcome}))
        except KeyboardInterrupt:
            stopped = True
        table.write(results)
    wall = time.perf_counter() - t0
    if not results:
        print(
            f"deck-sim run: stopped (Ctrl-C) before the first episode finished; {out / 'episodes.csv'} holds only "
            "its header" + (f", {recorder.path} the unfinished episode" if recorder is not None else ""),
            file=sys.stderr,
        )
        return INTERRUPTED
    if team:
        aircraft = _aircraft(results)
        low, high = rate_interval(sum(r.outcome == "goal" for r in aircraft), len(aircraft))
        summary = {**summarize(aircraft), **summarize_team(results), "reached_low": low, "reached_high": high}
        table_text = format_team_summary(args.scene, args.policy, predictor, summary, wall)
    else:
        summary = summarize(results)
        table_text = format_summary(args.scene, args.policy, predictor, summary, wall)
    learned = getattr(policy, "policy", policy) if team else policy  # (a shared policy's own)
    meta_record = getattr(learned, "meta", None)
    regime = actor_regime(meta_record) if isinstance(meta_record, dict) else None
    if meta_record is not None:  # a learned policy: say what it learnt from (and, shared, where)
        shared = f" (an actor trained on {meta_record.get('scene', '?')}, acting for every aircraft)" if team else ""
        table_text = f"{args.policy}{shared} learnt from {regime_text(regime)}\n\n{table_text}"
    print(table_text)
    meta = {
        "scene": args.scene,
        "policy": args.policy,
        "predictor": predictor,
        "regime": regime,
        "seed": args.seed,
        "episodes": args.episodes,
        "scene_set": scene_set,
        "deck_sim": deck_sim.__version__,
        "summary": summary,
        "wall_s": wall,
    }
    note = ""
    if stopped:
        meta.update(stopped=True, episodes_finished=len(results))
        note = f"\nStopped by Ctrl-C after {len(results)} of {args.episodes} episodes: the table covers those.\n"
    (out / "summary.json").write_text(json.dumps(meta, indent=2))
    (out / "results.md").write_text(table_text + "\n" + note)
    rows = " (one row per aircraft)" if team else ""
    print(f"wrote {out / 'results.md'}, {out / 'summary.json'}, {out / 'episodes.csv'}{rows}")
    if recorder is not None:
        print(f"wrote {recorder.path} (episode log{' of every aircraft' if team else ''}: deck-sim log info "
              f"{recorder.path})")
    if stopped:
        log_note = "" if recorder is None else f"; {recorder.path} is closed, the unfinished episode incomplete"
        print(
            f"deck-sim run: stopped (Ctrl-C) after {len(results)} of {args.episodes} episodes; their results are "
            f"written to {out} (summary.json marked stopped){log_note}",
            file=sys.stderr,
        )
        return INTERRUPTED
    return 0


def _aircraft(results: Sequence[EpisodeResult | TeamEpisodeResult]) -> list[EpisodeResult]:
    """Every aircraft's result: the episodes' own, or every aircraft of every episode of several."""
    return [r for x in results for r in (x.aircraft if hasattr(x, "aircraft") else (x,))]


def format_team_summary(name: str, policy: str, predictor: str, summary: dict[str, float], wall: float) -> str:
    """The metrics of a run of several aircraft (``summarize`` over every aircraft, with ``summarize_team``'s team
    figures and the ``reached_low``/``reached_high`` interval) as a two-column Markdown table."""
    rows = [
        ("episodes", f"{summary['episodes']:.0f}"),
        ("aircraft", f"{summary['aircraft']:.0f}"),
        ("aircraft reached", f"{100 * summary['goal_rate']:.1f} %"),
        ("95 % interval", f"{100 * summary['reached_low']:.1f}-{100 * summary['reached_high']:.1f} %"),
        ("aircraft collided", f"{100 * summary['collision_rate']:.1f} %"),
        ("aircraft still taxiing", f"{100 * summary['timeout_rate']:.1f} %"),
        ("left the surface", f"{100 * summary['off_surface_rate']:.1f} %"),
        ("physics diverged", f"{100 * summary['diverged_rate']:.1f} %"),
        ("episodes all arrived", f"{100 * summary['all_reached_rate']:.1f} %"),
        ("makespan (all arrived)", f"{fmt(summary['makespan'], '.1f')} s"),
        ("aircraft-aircraft collisions / episode", f"{summary['aircraft_collisions_per_episode']:.2f}"),
        ("path sum / shortest sum", fmt(summary["path_sum_ratio"], ".3f")),
        ("turning angle (arrivals)", f"{fmt(summary['turning_angle_deg'], '.1f')} deg"),
        ("mean reward per aircraft", f"{summary['mean_reward']:.1f}"),
        ("wall time", f"{wall:.1f} s"),
    ]
    return _two_columns(name, policy, predictor, rows)


class _EpisodeTable:
    """``episodes.csv`` of a run, one row per episode (per aircraft, named ``aircraft``, for several) written (and
    flushed) as the episode ends.

    Opening it creates the run's folder and proves it writable before any episode is played; it removes the
    ``summary.json`` and ``results.md`` of an earlier run in that folder, which would not describe this one.
    """

    def __init__(self, out: Path, label: str, aircraft: Sequence[str] = ()) -> None:
        from deck_sim.metrics import EpisodeResult

        if out.exists() and not out.is_dir():
            raise ValueError(f"{label} {out}: a file, not a folder")
        try:
            out.mkdir(parents=True, exist_ok=True)
            self._file = open(out / "episodes.csv", "w", newline="")  # noqa: SIM115 - closed by __exit__
            for name in ("summary.json", "results.md"):
                (out / name).unlink(missing_ok=True)
        except OSError as err:
            raise ValueError(f"{label} {out}: cannot write the run's files there ({err.strerror or err})") from None
        names = [f.name for f in fields(EpisodeResult)]
        self._aircraft = list(aircraft)
        self._writer = csv.DictWriter(self._file, fieldnames=["aircraft", *names] if aircraft else names)
        self._writer.writeheader()
        self._file.flush()
        self._written = 0

    def write(self, results: Sequence[EpisodeResult | TeamEpisodeResult]) -> None:
        """Append the rows of ``results`` not yet written (one per aircraft of an episode of several, its name
        first), and flush them to the disk."""
        from deck_sim.metrics import TeamEpisodeResult

        for r in results[self._written :]:
            if isinstance(r, TeamEpisodeResult):
                for name, aircraft in zip(self._aircraft, r.aircraft, strict=True):
                    self._writer.writerow({"aircraft": name, **aircraft.as_dict()})
            else:
                self._writer.writerow(r.as_dict())
            self._written += 1
        self._file.flush()

    def __enter__(self) -> _EpisodeTable:
        return self

    def __exit__(self, *exc: object) -> None:
        self._file.close()


def _add_record_arguments(p: argparse.ArgumentParser) -> None:
    """``--record FILE`` / ``--no-record`` of ``deck-sim run``."""
    p.add_argument(
        "--record",
        default=None,
        metavar="FILE.mcap",
        help="write every episode to this MCAP episode log (default: episodes.mcap in the run's folder)",
    )
    p.add_argument("--no-record", action="store_true", help="write no episode log")


def _open_run_recorder(args: argparse.Namespace, env, out: Path, actor: Path | None):  # noqa: ANN001, ANN202
    """The recorder of ``deck-sim run`` (``None`` with ``--no-record``), replacing an earlier log of the run;
    ``actor`` is the policy's actor file, if it has one."""
    if args.no_record:
        return None
    from deck_sim.rollout import open_recorder

    path = Path(args.record) if args.record else out / "episodes.mcap"
    path.parent.mkdir(parents=True, exist_ok=True)
    config = {k: getattr(args, k) for k in ("command", "scene", "policy", "episodes", "seed", "predictor")}
    return open_recorder(path, env, seed=args.seed, policy=args.policy, config=config, overwrite=True,
                         checkpoint=str(actor) if actor is not None else "")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``scenes`` and ``run`` to the subcommands."""
    from deck_sim.agents import policy_help

    add_command(sub, "scenes", cmd_scenes, "list the scenes with their obstacle counts, predictor and time limit")

    p = add_command(
        sub, "run", cmd_run, "play episodes with a policy and report the metrics",
        "Writes results.md, summary.json and episodes.csv into the run's folder and every episode into an MCAP\n"
        "log (episodes.mcap) that Foxglove opens. Example:\n"
        "  deck-sim run --scene deck1 --policy mddpg --episodes 10 --seed 1000",
    )
    p.add_argument("--scene", default="deck1", help="scene name or TOML path")
    p.add_argument("--policy", default="scripted", help=policy_help())
    p.add_argument("--episodes", type=int, default=20, help="episodes to play")
    p.add_argument("--seed", type=int, default=0, help="seeds layouts and movers")
    p.add_argument(
        "--predictor",
        default=None,
        help="none, constant_velocity, stationary, oracle or mpc (default: oracle for scripted, else the scene's)",
    )
    p.add_argument("--scene-set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override a field of the scene file, e.g. --scene-set movers.agent_yield_braking=2.0 "
                        "(recorded in summary.json)")
    p.add_argument("--out", default=None,
                   help="folder for results.md, summary.json, episodes.csv (default: runs/<scene>-<policy>-seed<seed>)")
    p.add_argument("--quiet", action="store_true", help="no progress report")
    _add_record_arguments(p)
