"""Run episodes of a composer environment with a policy, measure them, and record them.

This module is the seam between a running task and an episode log: ``TaskFrames`` reads the task's public state
(``last_info``, ``planner_view``, ``layout``, its entities and the physics' body poses) into the plain frames of
``deck_sim.types`` that ``deck_sim.recording.EpisodeRecorder`` writes; ``run_episode(..., recorder=...)`` records
an episode as it plays, and ``open_recorder`` opens a log carrying the run's metadata and attachments.
"""

from __future__ import annotations

import json
import os
import subprocess
import weakref
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from dm_control import composer

import deck_sim
from deck_sim.geometry import Footprints
from deck_sim.metrics import (
    EpisodeResult,
    TeamEpisodeResult,
    outcome_of,
    path_length,
    shortest_path,
    turning_angle,
)
from deck_sim.policies import Policy
from deck_sim.policies.team import TeamPolicy
from deck_sim.recording import DEFAULT_CHUNK_SIZE, Attachment, EpisodeRecorder
from deck_sim.scenes import dump_scene
from deck_sim.types import AircraftStep, SceneFrame, StepFrame, TeamSceneFrame, TeamStepFrame

StepCallback = Callable[[composer.Environment, object, np.ndarray | None], None]


class TaskFrames:
    """Reads a ``Navigate`` task running in ``env`` into recording frames (``SceneFrame``, ``StepFrame``).

    Positions are the task's own float64 values (``last_info``), so metrics recomputed from a log equal the live
    ones; the third coordinate and the orientation of the agent and movers come from their root bodies.
    """

    def __init__(self, env: composer.Environment) -> None:
        self._env = env
        self._model_ptr: Any = None
        self._body_ids = np.zeros(0, dtype=int)

    def _ids(self) -> np.ndarray:
        physics = self._env.physics
        if self._model_ptr is not physics.model.ptr:  # compiled anew: look the bodies up again
            task = self._env.task
            aircraft = task.agents if task.spec.multi_agent else [task.agent]
            bodies = [*(a.root_body for a in aircraft), *(m.root_body for m in task.movers)]
            self._body_ids = np.array([physics.bind(b).element_id for b in bodies], dtype=int)
            self._model_ptr = physics.model.ptr
        return self._body_ids

    def scene(self, episode: int) -> SceneFrame:
        """What stays fixed in the episode that has just been reset (a ``TeamSceneFrame`` for several aircraft)."""
        task = self._env.task
        view = task.planner_view()
        layout = task.layout
        n_props = len(task.statics)
        static_poses = np.vstack(
            [
                np.column_stack([layout.static_xy, layout.static_yaw]).reshape(-1, 3),
                np.column_stack([view.statics.centers[n_props:], view.statics.yaw[n_props:]]).reshape(-1, 3),
            ]
        )
        center, half, radius = task.agent.footprint
        movers = task.movers
        team = {}
        if task.spec.multi_agent:
            team = {"agent_names": tuple(task.agent_names), "targets_xy": np.array(layout.targets_xy, dtype=np.float64)}
        return (TeamSceneFrame if team else SceneFrame)(
            **team,
            scene=task.spec.name,
            episode=int(episode),
            dt=float(task.spec.episode.control_period),
            bounds=np.array(view.bounds, dtype=np.float64),
            target_xy=np.array(layout.target_xy, dtype=np.float64),
            goal_radius=float(view.goal_radius),
            agent_radius=float(view.agent_radius),
            agent_footprint=Footprints(
                np.array([center], dtype=float), np.array([half], dtype=float), np.zeros(1), np.array([radius])
            ),
            static_names=tuple(task.obstacle_names[: len(view.statics)]),
            statics=view.statics,
            static_poses=static_poses,
            mover_names=tuple(m.mjcf_model.model for m in movers),
            movers=Footprints(
                np.array([m.footprint[0] for m in movers], dtype=float).reshape(-1, 2),
                np.array([m.footprint[1] for m in movers], dtype=float).reshape(-1, 2),
                np.zeros(len(movers)),
                np.array([m.footprint[2] for m in movers], dtype=float),
            ),
        )

    def step(self, ts: Any, action: np.ndarray | None, episode: int, step: int) -> StepFrame:
        """The state after the reset (``step`` 0, ``action`` None) or after a control step."""
        info = self._env.task.last_info
        data = self._env.physics.data
        ids = self._ids()
        z, quat = data.xpos[ids, 2], data.xquat[ids]
        return StepFrame(
            episode=int(episode),
            step=int(step),
            time=float(info["time"]),
            action=None if action is None else np.array(action, dtype=np.float64),
            agent_pose=np.concatenate([info["position"], z[:1], quat[0]]),
            heading=float(info["heading"]),
            speed=float(info["speed"]),
            mover_poses=np.column_stack([info["mover_positions"], z[1:], quat[1:]]).reshape(-1, 7),
            prediction=np.array(info["prediction"], dtype=np.float64),
            reward_terms={k: float(v) for k, v in info["reward_terms"].items()},
            distance_to_goal=float(info["distance_to_goal"]),
            min_clearance=float(info["min_clearance"]),
            predictor_fallbacks=int(info["predictor_fallbacks"]),
            collision=info["collision"],
            reached_goal=bool(info["reached_goal"]),
            left_surface=bool(info["left_surface"]),
            diverged=bool(info["diverged"]),
            last=bool(ts.last()),
            discount=None if ts.discount is None else float(ts.discount),
        )


    def team_step(
        self, ts: Any, actions: np.ndarray | None, episode: int, step: int, acted: Sequence[bool] | None = None
    ) -> TeamStepFrame:
        """The state of several aircraft after the reset (``step`` 0, ``actions`` None) or after a control step in
        which the aircraft marked in ``acted`` were taxiing (their rows of ``actions`` were read)."""
        info = self._env.task.last_info
        data = self._env.physics.data
        ids = self._ids()
        z, quat = data.xpos[ids, 2], data.xquat[ids]
        agents = info["agents"]
        k = len(agents)
        aircraft = []
        for i, a in enumerate(agents):
            act = None if actions is None or acted is None or not acted[i] else np.array(actions[i], dtype=np.float64)
            aircraft.append(
                AircraftStep(
                    name=a["name"],
                    action=act,
                    pose=np.concatenate([a["position"], z[i : i + 1], quat[i]]),
                    heading=float(a["heading"]),
                    speed=float(a["speed"]),
                    track_xy=np.array(a["done_position"] if a["done"] else a["position"], dtype=np.float64),
                    reward_terms={key: float(v) for key, v in a["reward_terms"].items()},
                    distance_to_goal=float(a["distance_to_goal"]),
                    min_clearance=float(a["min_clearance"]),
                    collision=a["collision"],
                    reached_goal=bool(a["reached_goal"]),
                    left_surface=bool(a["left_surface"]),
                    done=bool(a["done"]),
                    discount=None if ts.discount is None else float(np.asarray(ts.discount)[i]),
                )
            )
        return TeamStepFrame(
            episode=int(episode),
            step=int(step),
            time=float(info["time"]),
            aircraft=tuple(aircraft),
            mover_poses=np.column_stack([info["mover_positions"], z[k:], quat[k:]]).reshape(-1, 7),
            prediction=np.array(info["prediction"], dtype=np.float64),
            predictor_fallbacks=int(info["predictor_fallbacks"]),
            diverged=bool(info["diverged"]),
            last=bool(ts.last()),
        )


_FRAMES: weakref.WeakKeyDictionary[composer.Environment, TaskFrames] = weakref.WeakKeyDictionary()


def task_frames(env: composer.Environment) -> TaskFrames:
    """The ``TaskFrames`` of ``env`` (one per environment, kept while the environment lives)."""
    frames = _FRAMES.get(env)
    if frames is None:
        frames = _FRAMES[env] = TaskFrames(env)
    return frames


def run_episode(
    env: composer.Environment,
    policy: Policy,
    episode: int = 0,
    on_step: StepCallback | None = None,
    recorder: EpisodeRecorder | None = None,
) -> EpisodeResult:
    """Play one episode from ``env.reset()`` to its end and measure it.

    Args:
        on_step: called after the reset and after every step with (env, timestep, action or None).
        recorder: writes the episode (its scene, every step and its events) to an episode log.
    """
    ts = env.reset()
    policy.reset()
    task = env.task
    frames = task_frames(env) if recorder is not None else None
    start = task.last_info["position"].copy()
    positions = [start]
    total = 0.0
    min_clear = task.last_info["min_clearance"]
    fallbacks = 0
    if frames is not None:
        recorder.begin_episode(frames.scene(episode), frames.step(ts, None, episode, 0))
    if on_step is not None:
        on_step(env, ts, None)
    steps = 0
    while not ts.last():
        action = np.asarray(policy.act(ts.observation), dtype=np.float64)
        ts = env.step(action)
        steps += 1
        info = task.last_info
        positions.append(info["position"].copy())
        total += float(ts.reward)
        min_clear = min(min_clear, info["min_clearance"])
        fallbacks += info["predictor_fallbacks"]
        if frames is not None:
            recorder.record_step(frames.step(ts, action, episode, steps))
        if on_step is not None:
            on_step(env, ts, action)
    info = task.last_info
    truncated = ts.discount is not None and ts.discount > 0 and not info["reached_goal"]
    xy = np.array(positions)
    return EpisodeResult(
        scene=task.spec.name,
        episode=episode,
        outcome=outcome_of(info, truncated),
        steps=steps,
        sim_time=float(info["time"]),
        reward=total,
        path_length=path_length(xy),
        start_target_distance=float(np.linalg.norm(task.layout.target_xy - start)),
        turning_angle_deg=float(np.degrees(turning_angle(xy))),
        min_clearance=float(min_clear),
        collision_partner=info["collision"],
        predictor_fallbacks=int(fallbacks),
    )


def run_team_episode(
    env: composer.Environment,
    policy: TeamPolicy,
    episode: int = 0,
    on_step: StepCallback | None = None,
    recorder: EpisodeRecorder | None = None,
) -> TeamEpisodeResult:
    """Play one episode of a multi-aircraft scene from ``env.reset()`` to its end and measure every aircraft.

    Each aircraft's path runs from its start to where it was done (``done_position``) or, for one still taxiing
    at the time limit, to where it stands then; its reward is the sum of its rewards.

    Args:
        on_step: called after the reset and after every step with (env, timestep, actions or None).
        recorder: writes the episode (its scene, every aircraft at every step, the events) to an episode log.
    """
    ts = env.reset()
    policy.reset()
    task = env.task
    frames = task_frames(env) if recorder is not None else None
    if frames is not None:
        recorder.begin_team_episode(frames.scene(episode), frames.team_step(ts, None, episode, 0))
    k = task.n_agents
    agents = task.last_info["agents"]
    tracks = [[a["position"].copy()] for a in agents]
    min_clear = [a["min_clearance"] for a in agents]
    total = np.zeros(k)
    fallbacks, steps = 0, 0
    if on_step is not None:
        on_step(env, ts, None)
    while not ts.last():
        live = [not a["done"] for a in task.last_info["agents"]]
        actions = np.asarray(policy.act(ts.observation), dtype=np.float64)
        ts = env.step(actions)
        steps += 1
        info = task.last_info
        total += np.asarray(ts.reward, dtype=np.float64)
        fallbacks += info["predictor_fallbacks"]
        for i, a in enumerate(info["agents"]):
            if live[i]:
                tracks[i].append((a["done_position"] if a["done"] else a["position"]).copy())
                min_clear[i] = min(min_clear[i], a["min_clearance"])
        if frames is not None:
            recorder.record_team_step(frames.team_step(ts, actions, episode, steps, live))
        if on_step is not None:
            on_step(env, ts, actions)
    info = task.last_info
    _, half, rounding = task.agent.footprint
    body_width = float(np.min(half) + rounding)
    statics = task.planner_view(0).statics
    results, shortest = [], []
    for i, a in enumerate(info["agents"]):
        xy = np.array(tracks[i])
        start, target = xy[0], task.layout.targets_xy[i]
        shortest.append(
            max(shortest_path(statics, body_width, task.arena.bounds, start, target) - task.spec.agent.goal_radius, 0.0)
        )
        results.append(
            EpisodeResult(
                scene=task.spec.name,
                episode=episode,
                outcome=outcome_of({**a, "diverged": info["diverged"] and not a["done"]}, truncated=not a["done"]),
                steps=len(xy) - 1,
                sim_time=float(a["done_time"] if a["done_time"] is not None else info["time"]),
                reward=float(total[i]),
                path_length=path_length(xy),
                start_target_distance=float(np.linalg.norm(target - start)),
                turning_angle_deg=float(np.degrees(turning_angle(xy))),
                min_clearance=float(min_clear[i]),
                collision_partner=a["collision"],
                predictor_fallbacks=int(fallbacks),
            )
        )
    names = set(task.agent_names)
    pairs = {frozenset((a["name"], a["collision"])) for a in info["agents"] if a["collision"] in names}
    reached = [r.sim_time for r in results if r.outcome == "goal"]
    return TeamEpisodeResult(
        scene=task.spec.name,
        episode=episode,
        aircraft=tuple(results),
        shortest=tuple(shortest),
        makespan=float(max(reached)) if len(reached) == k else float("nan"),
        aircraft_collisions=len(pairs),
    )


def git_commit() -> str:
    """The commit of the source tree deck_sim runs from (``+dirty`` with uncommitted changes), or ``unknown``."""
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def run_metadata(
    env: composer.Environment, seed: int | None, policy: str, checkpoint: str = "", commit: str | None = None
) -> dict[str, str]:
    """The ``deck_sim`` metadata record of a log of runs in ``env``: scene, seed, predictor, policy, checkpoint,
    versions, git commit, episode timing and every reward constant (``reward.<field>``), all as strings."""
    spec = env.task.spec
    meta = {
        "scene": spec.name,
        "seed": "none" if seed is None else str(seed),
        "predictor": env.task.predictor.name,
        "policy": policy,
        "checkpoint": checkpoint,
        "deck_sim_version": deck_sim.__version__,
        "mujoco_version": mujoco.__version__,
        "git_commit": git_commit() if commit is None else commit,
    }
    for section in ("episode", "reward"):
        for key, value in vars(getattr(spec, section)).items():
            meta[f"{section}.{key}"] = repr(value) if isinstance(value, float) else str(value)
    return meta


def run_attachments(env: composer.Environment, config: Mapping[str, Any]) -> list[Attachment]:
    """The files a log of runs in ``env`` carries: ``model.xml`` (the MJCF the physics was compiled from),
    ``scene.toml`` (the scene with its overrides, ``deck_sim.scenes.dump_scene``) and ``run.json`` (``config``)."""
    task = env.task
    return [
        Attachment("model.xml", "application/xml", task.root_entity.mjcf_model.to_xml_string().encode()),
        Attachment("scene.toml", "application/toml", dump_scene(task.spec).encode()),
        Attachment("run.json", "application/json", json.dumps(dict(config), indent=2, sort_keys=True).encode()),
    ]


def open_recorder(
    path: str | os.PathLike[str],
    env: composer.Environment,
    seed: int | None,
    policy: str,
    checkpoint: str = "",
    config: Mapping[str, Any] | None = None,
    overwrite: bool = False,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
) -> EpisodeRecorder:
    """An ``EpisodeRecorder`` writing ``path`` with the metadata and attachments of runs in ``env``.

    Args:
        seed: The environment's seed.
        policy: The policy's name.
        checkpoint: The policy's checkpoint file, if it has one.
        config: The run's configuration (stored as ``run.json``; JSON-serialisable values).
        overwrite: Replace an existing file.
        chunk_size: Bytes (uncompressed) after which a chunk is closed.
    """
    return EpisodeRecorder(
        path,
        metadata=run_metadata(env, seed, policy, checkpoint),
        attachments=run_attachments(env, config or {}),
        chunk_size=chunk_size,
        overwrite=overwrite,
    )
