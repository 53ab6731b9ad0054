"""Gymnasium adapter over the composer task: flat float32 observations and a Box action.

``import deck_sim`` registers ``deck_sim/Deck1-v0``, ``deck_sim/Deck2-v0`` and ``deck_sim/Square-v0``
(``deck_sim.registration``), so ``gymnasium.make`` builds this environment. Episodes end by termination (goal,
collision, leaving the surface, divergence: discount 0) or truncation (the scene's time limit).

``step`` before the first ``reset``, or after an episode ended (terminated or truncated), raises
``gymnasium.error.ResetNeeded``, the error of Gymnasium's own order-enforcing wrapper; an action that is not a
finite pair of real numbers in [-1, 1] raises ``deck_sim.tasks.navigate.InvalidActionError`` and leaves the episode
as it was.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from deck_sim.environment import load
from deck_sim.registration import GYM_IDS, register_envs


class DeckSimEnv(gymnasium.Env):
    """One deck_sim scene as a Gymnasium environment.

    The observation is the task's observation dict flattened in its fixed key order (``observation_keys``):
    target, static obstacles, dynamic obstacles, predicted positions (if any), position, velocity, heading.

    Args:
        scene: scene name or TOML path.
        render_mode: ``None`` or ``"rgb_array"`` (MuJoCo offscreen; set ``MUJOCO_GL=egl`` on a headless machine).
        width, height: rendered image size in pixels.
        camera: MuJoCo camera name (``follow``, ``top``, or the agent's ``agent/chase``).
        **overrides: scene fields, e.g. ``episode__predictor="oracle"``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        scene: str = "deck1",
        render_mode: str | None = None,
        width: int = 480,
        height: int = 360,
        camera: str = "agent/chase",
        **overrides: Any,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._env = load(scene, seed=None, **overrides)
        if self._env.task.spec.multi_agent:
            self._env.close()
            raise ValueError(
                f"scene {scene!r} puts several aircraft on the deck: use its PettingZoo environment, "
                "deck_sim.multiagent.parallel_env"
            )
        self.render_mode = render_mode
        self._size = (height, width)
        self._camera = camera
        shapes = self._env.task.observation_shapes
        self.observation_keys = tuple(shapes)
        dim = int(sum(np.prod(s) for s in shapes.values()))
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self._env.task.control_timestep)}
        self._needs_reset = True  # before the first reset and after an episode's end

    @property
    def composer_env(self):  # noqa: ANN201 - dm_control composer.Environment
        """The wrapped composer environment."""
        return self._env

    def _flatten(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([np.ravel(observation[k]) for k in self.observation_keys]).astype(np.float32)

    def _info(self) -> dict[str, Any]:
        return dict(self._env.task.last_info)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` reseeds the layouts and movers (same seed, same episodes)."""
        super().reset(seed=seed)
        if seed is not None:
            self._env.random_state.seed(seed)
        ts = self._env.reset()
        self._needs_reset = False
        return self._flatten(ts.observation), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Advance one decision period (``task.control_timestep`` seconds).

        Raises:
            gymnasium.error.ResetNeeded: no episode is running (before the first ``reset``, or after the last step
                returned ``terminated`` or ``truncated``).
            deck_sim.tasks.navigate.InvalidActionError: ``action`` is not a finite pair of real numbers in [-1, 1].
        """
        if self._needs_reset:
            raise ResetNeeded(
                "DeckSimEnv.step: no episode is running (the last one ended, or none began); call reset() first"
            )
        ts = self._env.step(action)  # the task checks the action and reads it as float64
        terminated = bool(ts.last() and ts.discount == 0.0)
        truncated = bool(ts.last() and not terminated)
        self._needs_reset = terminated or truncated
        return self._flatten(ts.observation), float(ts.reward), terminated, truncated, self._info()

    def render(self) -> np.ndarray | None:
        """An RGB frame (height, width, 3) from ``camera`` when ``render_mode == "rgb_array"``."""
        if self.render_mode != "rgb_array":
            return None
        return self._env.physics.render(*self._size, camera_id=self._camera)

    def close(self) -> None:
        """Release the physics."""
        self._env.close()


__all__ = ["GYM_IDS", "DeckSimEnv", "register_envs"]
