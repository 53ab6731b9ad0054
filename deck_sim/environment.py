"""Environment factories: the one place where the control period, physics timestep and time limit are applied."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from dm_control import composer

from deck_sim.control.prediction import Predictor
from deck_sim.scenes import SceneSpec, load_scene
from deck_sim.tasks.navigate import Navigate


def make_environment(
    spec: SceneSpec, seed: int | None = None, predictor: Predictor | None = None, max_reset_attempts: int = 1
) -> composer.Environment:
    """A composer environment for a scene spec.

    The task's control period (``spec.episode.control_period``) is composer's only substep: the physics substeps
    are fused inside the task (see ``deck_sim.tasks.navigate``). Physics divergence ends the episode cleanly
    (the task flags it in ``task.last_info["diverged"]``) instead of raising.
    """
    task = Navigate(spec, predictor=predictor)
    return composer.Environment(
        task,
        time_limit=spec.episode.time_limit,
        random_state=seed,
        strip_singleton_obs_buffer_dim=True,
        raise_exception_on_physics_error=False,
        legacy_step=False,
        max_reset_attempts=max_reset_attempts,
        recompile_mjcf_every_episode=False,  # layouts move bodies in place; no need to recompile
    )


def load(
    name: str | Path, seed: int | None = None, predictor: Predictor | None = None, **overrides: Any
) -> composer.Environment:
    """Load a scene by name (``deck1``, ``deck2``, ``square``) or TOML path as a composer environment.

    Args:
        name: scene name or path to a scene TOML file.
        seed: seeds the episode layouts and the movers; the same seed gives the same episodes, bit for bit.
        predictor: a predictor object overriding the scene's ``[episode].predictor``.
        **overrides: scene fields as ``<section>__<field>=value``, e.g. ``episode__predictor="oracle"``.

    Raises:
        deck_sim.scenes.SceneSpecError: unknown scene, malformed file or bad override.
    """
    return make_environment(load_scene(name, **overrides), seed=seed, predictor=predictor)
