"""PettingZoo adapter over the multi-aircraft composer task: a ``ParallelEnv`` of agents ``aircraft_0`` ...

``parallel_env(scene="deck1-multi", seed=...)`` builds it (install the ``multiagent`` extra: ``pip install
'deck-sim[multiagent]'``). Every aircraft's observation is its single-agent observation flattened in the task's key
order (as ``deck_sim.wrappers.DeckSimEnv`` flattens it), float32; its action is a Box (2,) in [-1, 1], the
displacement asked over the next decision as a fraction of the scene's reach.

An aircraft that reaches its target, collides or leaves the surface is terminated and leaves ``agents`` (it leaves
the deck too, for its stand on an apron beyond the stern: ``deck_sim.tasks.multi``); on divergence every aircraft
still taxiing is terminated; at the scene's time limit every aircraft still taxiing is truncated. Each aircraft's
info is its ``task.last_info["agents"]`` record plus the episode's ``diverged`` flag. ``step`` needs an action for
every aircraft in ``agents``: a missing one, an unknown name, or an action that is not a finite pair in [-1, 1]
raises ``InvalidActionError`` naming the aircraft, and nothing moves. An action for an aircraft that has already
left is ignored (its body stands braked).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from deck_sim.environment import load
from deck_sim.tasks.actions import InvalidActionError

try:
    from pettingzoo import ParallelEnv
except ModuleNotFoundError as err:  # pragma: no cover - the extra is installed in CI
    raise ModuleNotFoundError(
        "deck_sim.multiagent needs PettingZoo: pip install 'deck-sim[multiagent]'"
    ) from err

__all__ = ["DeckParallelEnv", "parallel_env"]


class DeckParallelEnv(ParallelEnv):
    """A multi-aircraft deck_sim scene as a PettingZoo ``ParallelEnv``.

    Args:
        scene: a scene name or TOML path with ``agents.count`` above 1 (``deck1-multi``, ``deck2-multi``).
        seed: seeds the episodes (the same seed, the same episodes); ``reset(seed=...)`` reseeds.
        render_mode: ``None`` or ``"rgb_array"`` (the top camera; ``MUJOCO_GL=egl`` on a headless machine).
        width, height: rendered image size in pixels.
        **overrides: scene fields as ``<section>__<field>=value``, e.g. ``agents__count=2``.

    Raises:
        ValueError: the scene has one agent (use ``gymnasium.make`` or ``deck_sim.load``), or a bad
            ``render_mode``.
        deck_sim.scenes.SceneSpecError: unknown scene, malformed file or bad override.
    """

    metadata = {"name": "deck_sim_multi_v0", "render_modes": ["rgb_array"], "render_fps": 2, "is_parallelizable": True}

    def __init__(
        self,
        scene: str = "deck1-multi",
        seed: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 160,
        **overrides: Any,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._env = load(scene, seed=seed, **overrides)
        task = self._env.task
        if not getattr(task, "spec", None) or not task.spec.multi_agent:
            self._env.close()
            raise ValueError(
                f"scene {scene!r} has one agent: use gymnasium.make or deck_sim.load for it, or a multi-agent scene "
                "(deck1-multi, deck2-multi, or agents__count=2..8)"
            )
        self.render_mode = render_mode
        self._size = (height, width)
        self.possible_agents: list[str] = task.agent_names
        self.agents: list[str] = []
        self._keys = tuple(task.observation_shapes)
        dim = int(sum(np.prod(s) for s in task.observation_shapes.values()))
        self._observation_spaces = {
            a: spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32) for a in self.possible_agents
        }
        self._action_spaces = {a: spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32) for a in self.possible_agents}
        self.metadata = {**self.metadata, "render_fps": round(1.0 / task.control_timestep)}

    @property
    def composer_env(self):  # noqa: ANN201 - dm_control composer.Environment
        """The wrapped composer environment (its ``task`` is a ``deck_sim.tasks.multi.MultiNavigate``)."""
        return self._env

    def observation_space(self, agent: str) -> spaces.Box:
        """The flat float32 observation of ``agent``."""
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        """The action (2,) of ``agent`` in [-1, 1]."""
        return self._action_spaces[agent]

    def _observations(self, observation: dict[str, np.ndarray], names: list[str]) -> dict[str, np.ndarray]:
        """Each named aircraft's part of the composer observation (``<name>:<key>``), flattened."""
        return {
            a: np.concatenate([np.ravel(observation[f"{a}:{k}"]) for k in self._keys]).astype(np.float32)
            for a in names
        }

    def _infos(self, names: list[str]) -> dict[str, dict[str, Any]]:
        info = self._env.task.last_info
        per_agent = {record["name"]: record for record in info["agents"]}
        return {a: {**per_agent[a], "diverged": bool(info["diverged"])} for a in names}

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode with every aircraft; ``seed`` reseeds the episodes."""
        if seed is not None:
            self._env.random_state.seed(seed)
        ts = self._env.reset()
        self.agents = list(self.possible_agents)
        return self._observations(ts.observation, self.agents), self._infos(self.agents)

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:
        """Advance one decision period for every aircraft in ``agents``.

        Raises:
            gymnasium.error.ResetNeeded: no episode is running.
            InvalidActionError: ``actions`` is not a dict, lacks an aircraft of ``agents``, names an unknown one,
                or holds an action that is not a finite pair in [-1, 1]; nothing moves.
        """
        if not self.agents:
            raise ResetNeeded("DeckParallelEnv.step: no episode is running (every aircraft is done); call reset()")
        if not isinstance(actions, dict):
            raise InvalidActionError(
                f"actions must be a dict of aircraft name -> action, got {type(actions).__name__}"
            )
        unknown = sorted(set(actions) - set(self.possible_agents), key=str)
        if unknown:
            raise InvalidActionError(
                f"actions name unknown aircraft {unknown}; the aircraft are {self.possible_agents}"
            )
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise InvalidActionError(f"actions lack an action for {missing} (every aircraft in agents needs one)")
        # the task ignores the actions of aircraft that are done; it checks every other one, naming the aircraft
        zero = np.zeros(2)
        ts = self._env.step([actions[a] if a in self.agents else zero for a in self.possible_agents])
        index = {a: i for i, a in enumerate(self.possible_agents)}
        live = list(self.agents)
        done = {info["name"]: info["done"] for info in self._env.task.last_info["agents"]}
        diverged = self._env.task.last_info["diverged"]
        terminations = {a: bool(done[a] or diverged) for a in live}
        truncations = {a: bool(ts.last() and not terminations[a]) for a in live}
        rewards = {a: float(ts.reward[index[a]]) for a in live}
        observations, infos = self._observations(ts.observation, live), self._infos(live)
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos

    def render(self) -> np.ndarray | None:
        """An RGB frame (height, width, 3) of the whole surface from the top camera with ``render_mode``
        ``"rgb_array"``; None otherwise."""
        if self.render_mode != "rgb_array":
            return None
        return self._env.physics.render(*self._size, camera_id="top")

    def close(self) -> None:
        """Release the physics."""
        self._env.close()


def parallel_env(scene: str = "deck1-multi", seed: int | None = None, **kwargs: Any) -> DeckParallelEnv:
    """A multi-aircraft scene as a PettingZoo ``ParallelEnv`` (``DeckParallelEnv``'s arguments)."""
    return DeckParallelEnv(scene=scene, seed=seed, **kwargs)
