"""The environments a training run steps: the Gymnasium adapter of a scene, the observation layout, the curriculum's
reduced scenes, and the scripted planner's demonstrations.

A curriculum stage may leave movers out of the episode; its observation is then padded to the full scene's layout
with ``FAR`` (a relative position 1 km away, far outside every influence radius), so one network serves every
stage.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from deck_sim.control.planners import ScriptedPlanner
from deck_sim.policies import ScriptedPolicy
from deck_sim.progress import progress as progress_report
from deck_sim.scenes import load_scene
from deck_sim.wrappers import DeckSimEnv
from training.config import CurriculumStage, TrainConfig, demo_episode_seed

if TYPE_CHECKING:
    from dm_control import composer

log = logging.getLogger(__name__)

FAR = 1000.0
"""Metres: the relative position (x and y) that stands for a mover left out by a curriculum stage."""
MOVER_KEYS = (
    "dynamic_obstacles", "predicted", "predicted_approach", "dynamic_nearest", "dynamic_heading", "dynamic_size",
    "dynamic_near", "predicted_near",
)
FORECAST_KEYS = ("predicted", "predicted_approach", "predicted_near")
"""Observation keys read from the forecast: what an agent without prediction does not see."""
PAD: dict[str, float | tuple[float, ...]] = {
    "dynamic_heading": 0.0, "dynamic_size": 0.0, "predicted_approach": (0.0, FAR * math.sqrt(2.0)),
}
"""What fills the rows of movers a curriculum stage leaves out, where not ``FAR`` (``mover_pad_fills`` adds the
run's own); a tuple fills each column (``predicted_approach``: closest now, as far as a ``FAR`` row)."""


def mover_pad_fills(config: TrainConfig) -> dict[str, float]:
    """The fills of a run's left-out movers that depend on its scene: 0 for ``predicted`` when it holds each
    mover's own displacement (``episode.predicted_frame = "mover"``), and for ``dynamic_near`` and ``predicted_near``
    the value whose (x, y) row is as long as the near field (a mover beyond the field reads as a vector of the
    field's length, as every far one does; ``FAR`` would break the clip and swamp the set's pooled statistics)."""
    spec = load_scene(config.scene, **config.scene_overrides)
    fills: dict[str, float] = {}
    if spec.episode.predicted_frame == "mover":
        fills["predicted"] = 0.0
    edge = spec.episode.near_steps * spec.agent.reach / math.sqrt(2.0)  # (validation: near_steps > 0 for both)
    if spec.episode.near_obstacles:
        fills["dynamic_near"] = edge
    if spec.episode.predicted_near:
        fills["predicted_near"] = edge
    return fills


@dataclass(frozen=True)
class ObservationLayout:
    """Key order and shapes of a scene's flat observation (the Gymnasium adapter's order)."""

    shapes: dict[str, tuple[int, ...]]

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(self.shapes)

    @property
    def dim(self) -> int:
        return int(sum(np.prod(s) for s in self.shapes.values()))

    def slices(self) -> dict[str, slice]:
        """Where each key lies in the flat vector."""
        out, start = {}, 0
        for k, s in self.shapes.items():
            n = int(np.prod(s))
            out[k] = slice(start, start + n)
            start += n
        return out

    def without(self, drop: tuple[str, ...]) -> ObservationLayout:
        """This layout with the keys ``drop`` removed."""
        return ObservationLayout({k: s for k, s in self.shapes.items() if k not in drop})

    def select(self, flat: np.ndarray, target: ObservationLayout) -> np.ndarray:
        """The part of flat observations (..., self.dim) that ``target`` (a subset of keys) holds."""
        sl = self.slices()
        return np.concatenate([flat[..., sl[k]] for k in target.keys], axis=-1)

    def pad_to(
        self, flat: np.ndarray, full: ObservationLayout, fills: dict[str, float] | None = None
    ) -> np.ndarray:
        """Flat observations of a scene with fewer movers, padded (nearest-first rows kept) to ``full``.

        A missing mover's rows hold ``FAR`` (``PAD`` where given, then ``fills``: e.g. 0 for ``predicted`` when
        it holds each mover's own displacement, ``episode.predicted_frame = "mover"``)."""
        sl = self.slices()
        parts = []
        for k, shape in full.shapes.items():
            v = flat[..., sl[k]].reshape(*flat.shape[:-1], *self.shapes[k])
            if k in MOVER_KEYS and self.shapes[k][0] < shape[0]:
                fill = {**PAD, **(fills or {})}.get(k, FAR)
                pad = np.full((*flat.shape[:-1], shape[0] - self.shapes[k][0], *shape[1:]), fill, dtype=flat.dtype)
                v = np.concatenate([v, pad], axis=flat.ndim - 1)
            parts.append(v.reshape(*flat.shape[:-1], -1))
        return np.concatenate(parts, axis=-1)

    def real_mask(self, full: ObservationLayout) -> np.ndarray:
        """(full.dim,) booleans: True where ``pad_to`` puts this layout's own values into ``full``, False on the
        rows it pads for the movers this layout lacks (what the observation normaliser leaves out)."""
        parts = []
        for k, shape in full.shapes.items():
            mask = np.ones(shape, dtype=bool)
            if k in MOVER_KEYS and self.shapes[k][0] < shape[0]:
                mask[self.shapes[k][0]:] = False
            parts.append(mask.reshape(-1))
        return np.concatenate(parts)


def composer_layout(env: composer.Environment) -> ObservationLayout:
    """The layout of the flat observations of ``env``, a deck_sim composer environment."""
    return ObservationLayout({k: tuple(v) for k, v in env.task.observation_shapes.items()})


def env_layout(env: DeckSimEnv) -> ObservationLayout:
    """The layout of ``env``'s flat observations."""
    return composer_layout(env.composer_env)


def scene_layout(scene: str, predictor: str, overrides: dict[str, Any]) -> ObservationLayout:
    """The layout of one aircraft's flat observation in ``scene`` as ``predictor`` and the scene ``overrides`` make
    it (built from a probe environment, closed again)."""
    probe = make_env(scene, predictor, **overrides)
    try:
        return env_layout(probe)
    finally:
        probe.close()


def stage_overrides(
    scene: str, stage: CurriculumStage | None, overrides: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Scene overrides for a curriculum stage of ``scene`` as the run's ``overrides`` make it.

    The first ``stage.movers`` movers take part (tractors, then taxiing aircraft, then pedestrians). Targets lie at
    most ``stage.max_target_distance`` from the start: where the scene's own target sites are farther, the stage
    also draws targets from the start sites, so that short trips exist (not from the movers' spots, where a mover
    may stand on the target); the final stage (``None``) is the scene as it is.
    """
    if stage is None:
        return {}
    spec = load_scene(scene, **(overrides or {}))
    m, agent = spec.movers, spec.agent
    left = int(stage.movers)
    counts = {}
    for kind in ("tractors", "aircraft", "pedestrians"):
        counts[kind] = min(getattr(m, kind), left)
        left -= counts[kind]
    total = sum(counts.values())
    near = min(m.spawn_near_agent, total)
    cap = float(stage.max_target_distance)
    out: dict[str, Any] = {
        **{f"movers__{k}": v for k, v in counts.items()},
        "movers__spawn_near_agent": near,
        "movers__spawn_random": min(m.spawn_random, total - near),
    }
    if cap < agent.max_target_distance:
        sites = list(dict.fromkeys([*agent.target_sites, *agent.start_sites]))
        out.update(
            {
                "agent__target_sites": sites,
                "agent__max_target_distance": cap,
                "agent__min_target_distance": min(agent.min_target_distance, 0.5 * cap),
            }
        )
    return out


TEACHER_PREDICTOR = "mpc"
"""The forecasts the scripted planner plans around whenever it teaches: its demonstrations and its labels of the
agent's own transitions (``training.runners``). An agent without prediction (``predictor = "none"``) gets the
same planner's actions and the observation without its ``predicted`` part, so DDPG and MDDPG are taught alike and
differ only in what they observe."""


def make_env(scene: str, predictor: str, **overrides: Any) -> DeckSimEnv:
    """The Gymnasium adapter of ``scene`` with ``predictor`` filling the observation's predicted part."""
    return DeckSimEnv(scene, episode__predictor=predictor, **overrides)


@dataclass
class Demonstrations:
    """Transitions of the scripted planner, flat float32 observations in the training layout."""

    obs: np.ndarray
    action: np.ndarray
    """What was done (the planner's action plus the injected noise)."""
    expert_action: np.ndarray
    """What the planner asked for."""
    reward: np.ndarray
    next_obs: np.ndarray
    terminated: np.ndarray
    episodes: int
    successes: int

    def __len__(self) -> int:
        return len(self.obs)


def collect_demonstrations(
    scene: str,
    episodes: int,
    seed: int,
    layout: ObservationLayout,
    progress: bool = True,
    noise: float = 0.0,
    body: bool = False,
    view: str = "full",
    **overrides: Any,
) -> Demonstrations:
    """Play ``episodes`` episodes of the scripted planner and keep their transitions.

    The planner plans around the MPC predictor's forecasts (``TEACHER_PREDICTOR``), the same forecasts MDDPG
    observes; for an agent without prediction (``layout`` lacks ``predicted``) that part of the observation is
    dropped, so DDPG and MDDPG learn from the same demonstrated episodes. Episode ``k`` is reset with
    ``demo_episode_seed(seed, k)`` (disjoint from training and evaluation seeds); ``overrides`` are scene fields.
    With ``noise`` > 0 the executed action is the planner's plus N(0, noise^2) per component (DART), drawn from a
    generator seeded by ``seed``; the planner's own action is kept as the cloning target. ``body`` is the
    planner's ``ScriptedPlanner.body`` (``TrainConfig.teacher_body``), ``view`` what it reads
    (``TrainConfig.teacher_policy_view``: the task's full state, or the agent's own observation).
    """
    env = make_env(scene, TEACHER_PREDICTOR, **overrides)
    full = env_layout(env)
    policy = ScriptedPolicy(env.composer_env, ScriptedPlanner(body=body), view=view)
    rows: dict[str, list[np.ndarray]] = {
        k: [] for k in ("obs", "action", "expert_action", "reward", "next_obs", "terminated")
    }
    rng = np.random.default_rng([seed, 77])
    successes = 0
    bar = progress_report(
        range(episodes), desc=f"demonstrations {scene}", unit="ep", disable=not progress, leave=False
    )
    for k in bar:
        obs, _ = env.reset(seed=demo_episode_seed(seed, k))
        policy.reset()
        done = False
        while not done:
            expert = np.clip(policy.act({}), -1.0, 1.0)  # the planner reads the task's state, as its view allows
            action = np.clip(expert + noise * rng.standard_normal(2), -1.0, 1.0) if noise > 0 else expert
            next_obs, reward, terminated, truncated, info = env.step(action)
            rows["obs"].append(obs)
            rows["action"].append(action.astype(np.float32))
            rows["expert_action"].append(expert.astype(np.float32))
            rows["reward"].append(np.float32(reward))
            rows["next_obs"].append(next_obs)
            rows["terminated"].append(np.float32(terminated))
            obs, done = next_obs, terminated or truncated
        successes += bool(info["reached_goal"])
        bar.set_postfix(success=f"{100 * successes / (k + 1):.0f}%")
    env.close()
    stack = {k: np.asarray(v, dtype=np.float32) for k, v in rows.items()}
    for k in ("obs", "next_obs"):
        stack[k] = full.select(stack[k], layout) if layout.keys != full.keys else stack[k]
    log.info("demonstrations: %d episodes, %d transitions, %d successes", episodes, len(stack["obs"]), successes)
    return Demonstrations(**stack, episodes=episodes, successes=successes)
