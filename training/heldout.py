"""A training run's actor measured on the held-out episodes of ``docs/results.md``, cached in the run folder.

A run's own periodic evaluations (``eval.csv``) use the seed-500 stream, which also picks the run's best actor
(``actor_best.npz``), so they flatter it. The comparisons across seeds and regimes are therefore made on another
stream: the episodes of ``deck_sim.evaluation`` (episode ``i`` reset with seed ``DEFAULT_SEED + i``, the
episodes of every table in ``docs/results.md``), which no training, demonstration or selection ever sees.

``held_out(run)`` evaluates the actor that ``scripts/train_shipped.py`` would ship from the run
(``training.final_fit.shipped_actor``) and writes ``heldout_<episodes>.json`` beside it; ``held_out(run,
play="averaged-select")`` the run's averaged actor choosing by its own critic (``training.final_fit.PLAYS``), in
``heldout_<episodes>_averaged-select.json``. The file names the actor by its
SHA-256, so a later call returns it without evaluating again until the actor changes (an unfinished run's
``actor_best.npz`` does, at each better evaluation). The record keeps each episode's success (``goal_each``), the
values a paired comparison of two agents resamples (``deck_sim.metrics.paired_bootstrap_interval``).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter
from pathlib import Path
from typing import Any

from deck_sim.evaluation import DEFAULT_SEED, EvalConfig, evaluate, machine
from deck_sim.rollout import git_commit
from training.final_fit import PLAYS, play_settings, played_actor


def held_out_file(episodes: int | str, play: str = "shipped") -> str:
    """The name of the cached record of ``episodes`` held-out episodes in a run folder (``held_out``; ``"*"``: the
    glob pattern of every count), of the shipped actor or of another ``play`` (``training.final_fit.PLAYS``)."""
    return f"heldout_{episodes}.json" if play == "shipped" else f"heldout_{episodes}_{play}.json"


def shipped_held_out(logs: str | Path, episodes: int, play: str = "shipped") -> dict[str, Any] | None:
    """The held-out record in a folder of logs shipped beside an actor of ``deck_sim/trained`` (no actor to measure
    again: ``scripts/train_shipped.py`` copies a run's ``heldout_<episodes>.json`` there) if it is a record of
    ``episodes`` episodes of the held-out stream with each episode's outcome (``goal_each``), of ``play`` with
    today's ``play_settings``; else None. The file is ``heldout_<episodes>.json``, or ``heldout_<episodes>_<play>.json``
    (``held_out_file``)."""
    try:
        record = json.loads((Path(logs) / held_out_file(episodes, play)).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    ok = (_of_episodes(record, episodes, per_episode=True) and record.get("play", "shipped") == play
          and record.get("play_settings", {}) == play_settings(play))
    return record if ok else None


def _of_episodes(record: Any, episodes: int, per_episode: bool) -> bool:
    """Whether a cached record measures ``episodes`` episodes of the held-out stream (with ``per_episode``, each
    one's outcome kept)."""
    return (isinstance(record, dict) and record.get("episodes") == episodes and record.get("seed") == DEFAULT_SEED
            and not (per_episode and len(record.get("goal_each") or ()) != episodes))


class HeldOutError(RuntimeError):
    """A run folder that cannot be measured (no config, no actor yet)."""


def held_out(
    run: str | os.PathLike[str],
    episodes: int = 100,
    workers: int | None = None,
    *,
    refresh: bool = False,
    per_episode: bool = False,
    play: str = "shipped",
) -> dict[str, Any]:
    """The run's shipped actor (or the actor of another ``play``) on ``episodes`` held-out episodes of its scene.

    Args:
        run: A ``deck-sim train`` or stable-baselines3 run folder (its ``config.json`` names the scene).
        episodes: Episodes ``DEFAULT_SEED`` to ``DEFAULT_SEED + episodes - 1``.
        workers: Evaluation processes (default: the CPU count).
        refresh: Evaluate again even when the run folder holds this actor's figures.
        per_episode: Evaluate again when the cached record lacks ``goal_each`` (a record written before it was kept)
            or holds another number of values than ``episodes``.
        play: How the run acts (``training.final_fit.PLAYS``): ``shipped``, its shipped actor; ``averaged-select``,
            its averaged actor choosing each action by its own critic (a finished run with ``actor_average``).

    Returns:
        ``{"success", "collision", "timeout", "off_surface"}`` (fractions) with Wilson 95 % intervals
        (``success_ci`` ...), ``reward``, ``path_ratio`` (path over the shortest static path) and ``turning_deg``
        (degrees per successful episode) with Student-t 95 % intervals, and the record of what was measured:
        ``scene``, ``play``, ``play_settings``, ``actor``, ``actor_sha256``, ``selected_at_step``, ``episodes``,
        ``seed``, ``wall_s``, ``git_commit``, ``machine``; ``collision_partners`` counts the collisions by what was
        hit; ``goal_each`` gives each episode, in episode order, the share of its aircraft that reached their
        targets (1 or 0 with one aircraft).

    Raises:
        HeldOutError: The folder has no ``config.json`` or no actor of ``play`` yet, or its averaged actor no
            critic to choose by.
        ValueError: An unknown ``play``.
    """
    if play not in PLAYS:
        raise ValueError(f"unknown play {play!r}; expected one of {', '.join(PLAYS)}")
    run = Path(run)
    try:
        config = json.loads((run / "config.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise HeldOutError(f"{run}: not a training run folder (config.json: {err})") from None
    try:
        actor = played_actor(run, play)
    except ValueError as err:  # (an averaged actor whose critic cannot be found)
        raise HeldOutError(str(err)) from None
    if not actor.exists():
        if play == "shipped":
            raise HeldOutError(f"{run}: no actor to measure yet ({actor.name} appears at the run's first evaluation)")
        raise HeldOutError(f"{run}: no averaged actor to measure (actor_avg.npz, written when a run with "
                           f"actor_average finishes; its config has actor_average = {config.get('actor_average', 0)})")
    digest = hashlib.sha256(actor.read_bytes()).hexdigest()
    cache = run / held_out_file(episodes, play)
    if not refresh:
        try:
            record = json.loads(cache.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            record = None
        if record and record.get("actor_sha256") == digest and _of_episodes(record, episodes, per_episode):
            return record
    scene = str(config["scene"])
    res = evaluate(
        EvalConfig(agents=(f"run={actor}",), scenes=(scene,), episodes=episodes, workers=workers, record="none")
    )
    s = res.summary(scene, "run")
    from deck_sim.policies import load_actor

    meta = load_actor(actor).meta
    record = {
        "scene": scene,
        "play": play,
        "play_settings": play_settings(play),
        "actor": actor.name,
        "actor_sha256": digest,
        "selected_at_step": int(meta.get("trained_steps", -1)),
        "episodes": episodes,
        "seed": DEFAULT_SEED,
        "success": s["goal_rate"],
        "success_ci": s["goal_ci"],
        "collision": s["collision_rate"],
        "collision_ci": s["collision_ci"],
        "timeout": s["timeout_rate"],
        "timeout_ci": s["timeout_ci"],
        "off_surface": s["off_surface_rate"],
        "reward": s["reward"],
        "reward_ci": s["reward_ci"],
        "path_ratio": s["shortest_ratio"],
        "path_ratio_ci": s["shortest_ratio_ci"],
        "turning_deg": s["turning_deg"],
        "turning_deg_ci": s["turning_deg_ci"],
        "collision_partners": dict(
            sorted(Counter(str(r["collision_partner"]) for r in res.episodes if r["outcome"] == "collision").items())
        ),
        "goal_each": goal_each(res.episodes, episodes),
        "wall_s": res.wall_s,
        "git_commit": git_commit(),
        "machine": machine(),
    }
    tmp = cache.with_name(cache.name + ".tmp")
    tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, cache)
    return record


def goal_each(rows: list[dict[str, Any]], episodes: int) -> list[int | float]:
    """Each episode's share of aircraft that reached their targets, in episode order (1 or 0 where all or none
    did), from the evaluation's rows: one row per episode, or one per aircraft of a multi-aircraft scene.

    Raises:
        HeldOutError: The rows do not hold episodes 0 to ``episodes - 1``.
    """
    by_episode: dict[int, list[bool]] = {}
    for r in rows:
        by_episode.setdefault(int(r["episode"]), []).append(r["outcome"] == "goal")
    if sorted(by_episode) != list(range(episodes)):
        raise HeldOutError(f"the evaluation returned {len(by_episode)} distinct episodes, expected 0 to {episodes - 1}")
    shares = [sum(v) / len(v) for _, v in sorted(by_episode.items())]
    return [int(x) if x in (0.0, 1.0) else x for x in shares]
