"""Environment factories: the one place where the control period, physics timestep and time limit are applied."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from dm_control import composer
from dm_control.composer import observation

from deck_sim.control.prediction import Predictor
from deck_sim.scenes import SceneSpec, load_scene
from deck_sim.tasks.navigate import Navigate


class _PlainUpdater(observation.Updater):
    """composer's observation updater, with a fast path for observables read once per control step.

    With one composer substep per control step and observables that have composer's defaults (update every
    step, no delay, a buffer of one, no aggregator or corruptor), composer's schedule and buffers only copy each
    value twice; this reads every observable once when the observation is taken, giving the same arrays. Any
    other configuration goes through composer's own code.
    """

    def reset(self, physics, random_state) -> None:  # noqa: ANN001 - composer's signature
        super().reset(physics, random_state)
        plain = self._physics_steps_per_control_step == 1 and self._strip_singleton_buffer_dim and not self._is_nested
        for enabled in self._enabled_list:
            plain = plain and (
                enabled.update_interval == 1
                and enabled.delay == 0
                and enabled.buffer_size == 1
                and enabled.observable.aggregator is None
                and enabled.observable.corruptor is None
            )
        self._reads = (
            [(name, enabled.observation_callable) for name, enabled in self._enabled_structure.items()]
            if plain
            else None
        )

    def prepare_for_next_control_step(self) -> None:
        if self._reads is None:
            super().prepare_for_next_control_step()

    def update(self) -> None:
        if self._reads is None:
            super().update()
        else:
            self._step_counter += 1

    def get_observation(self):  # noqa: ANN201 - composer's signature
        if self._reads is None:
            return super().get_observation()
        out = type(self._enabled_structure)()
        for name, read in self._reads:
            out[name] = np.array(read())
        return out


class DeckEnvironment(composer.Environment):
    """composer's ``Environment`` with ``_PlainUpdater`` for its observations (identical values, less Python).

    composer's one substep per control step calls ``mujoco.mj_step`` itself, without dm_control's warning
    bookkeeping around it (``Physics.check_invalid_state``): the task already checks MuJoCo's divergence warnings
    over the whole control step and ends a diverged episode cleanly, so the check was done twice.
    """

    def _substep(self, action: np.ndarray) -> None:
        if not isinstance(self._task, Navigate):
            super()._substep(action)
            return
        self._hooks.before_substep(self._physics_proxy, action, self._random_state)
        mujoco.mj_step(self._physics.model.ptr, self._physics.data.ptr)
        self._hooks.after_substep(self._physics_proxy, self._random_state)

    def close(self) -> None:
        """Release the physics; closing a closed environment does nothing."""
        if self._physics is not None:
            super().close()

    def _make_observation_updater(self) -> observation.Updater:
        if self._delayed_observation_padding == composer.ObservationPadding.INITIAL_VALUE:
            return super()._make_observation_updater()
        return _PlainUpdater(
            self._task.observables, self._task.physics_steps_per_control_step, self._strip_singleton_obs_buffer_dim
        )


def make_environment(
    spec: SceneSpec,
    seed: int | None = None,
    predictor: Predictor | None = None,
    max_reset_attempts: int = 1,
    plain_observations: bool = True,
) -> composer.Environment:
    """A composer environment for a scene spec (the multi-agent task, ``tasks.multi.MultiNavigate``, for a scene
    with ``agents.count`` above 1).

    The task's control period (``spec.episode.control_period``) is composer's only substep: the physics substeps
    are fused inside the task (see ``deck_sim.tasks.physics_step``). Physics divergence ends the episode cleanly
    (the task flags it in ``task.last_info["diverged"]``) instead of raising. ``plain_observations`` takes the
    observation through ``_PlainUpdater`` (the same arrays as composer's updater, cheaper).
    """
    if spec.multi_agent:
        from deck_sim.tasks.multi import MultiNavigate

        task: Navigate = MultiNavigate(spec, predictor=predictor)
    else:
        task = Navigate(spec, predictor=predictor)
    return (DeckEnvironment if plain_observations else composer.Environment)(
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
    """Load a scene by name (``deck1``, ``deck2``, ``square``, ``deck1-multi``, ``deck2-multi``) or TOML path as a
    composer environment.

    Args:
        name: scene name or path to a scene TOML file.
        seed: seeds the episode layouts and the movers; the same seed gives the same episodes, bit for bit.
        predictor: a predictor object overriding the scene's ``[episode].predictor``.
        **overrides: scene fields as ``<section>__<field>=value``, e.g. ``episode__predictor="oracle"``.

    Raises:
        deck_sim.scenes.SceneSpecError: unknown scene, malformed file or bad override.
    """
    return make_environment(load_scene(name, **overrides), seed=seed, predictor=predictor)
