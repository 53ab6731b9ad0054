"""Policies by name: the shipped actors of each scene, the references, and the scene fields each runs with.

The names come from ``deck_sim.agents``, the one registry that the command line, the evaluation and the training
configuration read.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dm_control import composer

from deck_sim import agents
from deck_sim.control.planners import APFPlanner, AStarPlanner, MPCPlanner, ScriptedPlanner
from deck_sim.policies.actors import PolicyFileError, load_actor
from deck_sim.policies.reference import Policy, RandomPolicy, ScriptedPolicy, ZeroPolicy

TRAINED_DIR = Path(__file__).resolve().parent.parent / "trained"
"""Where the shipped actors lie: ``<scene>_<algo>.npz``."""
SHIPPED_ALGOS = agents.LEARNED
CLASSICAL = dict(zip(agents.CLASSICAL, (APFPlanner, AStarPlanner, MPCPlanner), strict=True))
"""The classical references: planners on the task's ``planner_view`` that need no training."""
SCRIPTED = dict(zip(agents.ORACLES, (False, True), strict=True))
"""The full-knowledge scripted planner, by name: the value is its ``ScriptedPlanner.body`` (``scripted-body`` checks
the aircraft's nose and tail on the way its tracker will really take it: the teacher of the ``body`` recipes)."""
POLICY_NAMES = tuple(agents.AGENTS)


def shipped_policy_path(algo: str, scene: str) -> Path:
    """The actor file shipped for ``algo`` (one of ``SHIPPED_ALGOS``) on ``scene``; ``PolicyFileError`` if none is."""
    path = TRAINED_DIR / f"{scene}_{algo}.npz"
    if not path.exists():
        shipped = sorted(p.stem for p in TRAINED_DIR.glob("*.npz"))
        how = "pass an actor file"
        if algo in agents.LEARNED and agents.AGENTS[algo].play:  # (another way of acting of a recipe's runs)
            how = (f"it is shipped where the scene's recipe {agents.recipe_name(algo, scene)} keeps an averaged "
                   f"actor (actor_average): python scripts/train_shipped.py --scenes {scene} --algos {algo}; one "
                   "finished run of such a recipe acts this way through deck-sim select RUN --averaged --out FILE; "
                   "or pass an actor file")
        elif algo in agents.LEARNED:
            how = (f"train one with python scripts/train_shipped.py --scenes {scene} --algos {algo} (one seed: "
                   f"deck-sim train --recipe {agents.recipe_name(algo, scene)} --algo {agents.training_algo(algo)}; "
                   "the scenes with recipes: training/recipes), or pass an actor file")
        raise PolicyFileError(
            f"no shipped {algo} policy for scene {scene!r} (shipped: {', '.join(shipped) or 'none'}); {how}"
        )
    return path


def shipped_log_dir(algo: str, scene: str) -> Path:
    """Where the training log of the shipped ``algo`` actor of ``scene`` lies (``eval.csv``, ``config.json``;
    ``scripts/train_shipped.py`` writes it, ``scripts/make_results.py`` draws its learning curve); it may not exist."""
    return TRAINED_DIR / "logs" / f"{scene}_{algo}"


def shipped_logs(algo: str, scene: str) -> list[tuple[Path, int | None]]:
    """The training logs shipped with the ``algo`` actor of ``scene``, one folder per run behind it: the first run's
    (``shipped_log_dir``), then the further runs' (an ensemble's other members, or the seeds a stable-baselines3
    agent was not chosen from) in its ``seed<k>/`` folders by ``k``; those holding an ``eval.csv``, each with the
    training seed its ``config.json`` records (None if that file or its seed is missing or unreadable)."""
    logs = shipped_log_dir(algo, scene)
    extra = sorted((int(m[1]), d) for d in logs.glob("seed*")
                   if d.is_dir() and (m := re.fullmatch(r"seed(\d+)", d.name)))
    found = []
    for folder in (logs, *(d for _, d in extra)):
        if not (folder / "eval.csv").exists():
            continue
        try:
            seed = int(json.loads((folder / "config.json").read_text(encoding="utf-8"))["seed"])
        except (OSError, ValueError, KeyError, TypeError):
            seed = None
        found.append((folder, seed))
    return found


def seeds_text(seeds: Sequence[int], trained: Sequence[int] | None = None) -> str:
    """How many training runs stand behind a shipped agent, and their seeds, for tables: ``1 (seed 0)``,
    ``2 (seeds 0, 1; mean action)`` (an ensemble), or for one run chosen from several (``trained``)
    ``1 (seed 1, the best of seeds 0, 1, 2)``."""
    if len(seeds) == 1:
        if trained and len(trained) > 1:
            return f"1 (seed {seeds[0]}, the best of seeds {', '.join(map(str, trained))})"
        return f"1 (seed {seeds[0]})"
    return f"{len(seeds)} (seeds {', '.join(map(str, seeds))}; mean action)"


def policy_file(name: str, scene: str) -> Path | None:
    """The actor file behind policy ``name`` on ``scene``: a shipped one, a path, or None for a reference policy."""
    if name in SHIPPED_ALGOS:
        return shipped_policy_path(name, scene)
    if name.endswith(".npz") or os.sep in name:
        return Path(name)
    return None


REFERENCE_PREDICTOR = "mpc"
"""The predictor whose forecast the classical references plan around (the one MDDPG is trained on)."""


def policy_overrides(name: str, scene: str) -> dict[str, Any]:
    """The scene fields (``deck_sim.load`` keywords) policy ``name`` runs with on ``scene`` unless told otherwise:
    the oracle for ``scripted`` and ``scripted-body``, ``REFERENCE_PREDICTOR`` for the classical references,
    ``REFERENCE_PREDICTOR`` and the observed footprints (``deck_sim.agents.OBSERVED_FIELDS``) for
    ``scripted-observed``, a learned actor's own predictor and observation (``LearnedPolicy.scene_overrides``),
    none for ``random`` and ``zero``."""
    if name in SCRIPTED:
        return {"episode__predictor": "oracle"}
    if name in CLASSICAL:
        return {"episode__predictor": REFERENCE_PREDICTOR}
    if name in agents.OBSERVERS:
        return {"episode__predictor": REFERENCE_PREDICTOR, **agents.OBSERVED_FIELDS}
    path = policy_file(name, scene)
    return load_actor(path).scene_overrides if path is not None else {}


def make_policy(name: str, env: composer.Environment, seed: int = 0) -> Policy:
    """The policy called ``name`` for ``env``: a reference policy (``scripted``, ``scripted-body``,
    ``scripted-observed``, ``apf``, ``astar``, ``mpc``, ``random``, ``zero``), a shipped learned one (``mddpg``,
    ``ddpg``, ``dqn``, ``a2c`` ...) or an actor file (a path ending in ``.npz``); raises ``ValueError`` listing the
    known names."""
    if name in SCRIPTED:
        return ScriptedPolicy(env, ScriptedPlanner(body=SCRIPTED[name]))
    if name in CLASSICAL:
        return ScriptedPolicy(env, CLASSICAL[name]())
    if name in agents.OBSERVERS:
        return ScriptedPolicy(env, ScriptedPlanner(body=True), view="observation")
    if name == "random":
        return RandomPolicy(seed)
    if name == "zero":
        return ZeroPolicy()
    path = policy_file(name, env.task.spec.name)
    if path is not None:
        return load_actor(path)
    raise ValueError(f"unknown policy {name!r}; expected one of {', '.join(POLICY_NAMES)} or an actor .npz file")
