"""``EpisodeRecorder``: write episodes as MCAP that Foxglove opens with no plugin (see ``schema`` for the topics).

The recorder writes plain frames (``deck_sim.types.SceneFrame`` and ``StepFrame``); turning a running task into
frames is the caller's job (``deck_sim.rollout.TaskFrames``), so this module needs neither MuJoCo nor the task.

The file is written by foxglove-sdk (``foxglove.open_mcap``: chunking, zstd and indexes in Rust), with one
``foxglove.Context`` per file so that channels never leak between files. The messages of every step (``/tf``,
``/prediction``, ``/agent/path``) are protobuf-encoded with numpy (``_lines``, byte-identical to the SDK's encoder)
and logged on channels carrying the SDK's own schemas; the rare ones (``/scene``, ``/events``) use the SDK's
message classes. ``benchmarks/recording.py`` compares this with the pure-Python mcap-protobuf writer.

Chunks are zstd-compressed and bounded (``chunk_size`` bytes before compression); every episode's end closes the
current chunk and flushes the file, so a process killed mid-episode loses at most the part of the current episode
that had not yet filled a chunk (``deck_sim.recording.recover`` repairs such a file).

Messages hold no wall-clock time: two runs with one seed write the same bytes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import foxglove
import numpy as np
from foxglove.channels import LogChannel, SceneUpdateChannel
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import (
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransforms,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from deck_sim.metrics import outcome_of, path_length
from deck_sim.recording import _lines, schema
from deck_sim.types import AircraftStep, SceneFrame, StepFrame, TeamSceneFrame, TeamStepFrame

DEFAULT_CHUNK_SIZE = 128 * 1024
"""Bytes (before compression) after which a chunk is closed: the most a killed process can lose of an episode."""

_LINE_Z = 0.3  # m above the deck: paths and predictions
_BOX_HEIGHT = 3.0  # m: nominal height of the obstacle boxes in the 3D view
_NO_ROTATION = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_IDENTITY = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=_NO_ROTATION)
_DECK_COLOR = Color(r=0.35, g=0.37, b=0.4, a=1.0)
_STATIC_COLOR = Color(r=0.55, g=0.57, b=0.6, a=1.0)
_MOVER_COLOR = Color(r=0.95, g=0.75, b=0.1, a=1.0)
_AGENT_COLOR = Color(r=0.85, g=0.15, b=0.1, a=1.0)
_TARGET_COLOR = Color(r=0.1, g=0.9, b=0.2, a=0.5)
_PATH_COLOR = Color(r=0.85, g=0.15, b=0.1, a=1.0)
_PREDICTION_COLOR = Color(r=0.2, g=0.6, b=1.0, a=1.0)
_WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)
_IDENTITY_PB, _PATH_PB, _PREDICTION_PB = _IDENTITY.encode(), _PATH_COLOR.encode(), _PREDICTION_COLOR.encode()


class RecordingError(RuntimeError):
    """The recorder was used out of order (a step outside an episode, a write after ``close``)."""


@dataclass(frozen=True)
class Attachment:
    """A file stored in the log: a name, its media type (e.g. ``application/xml``) and its bytes."""

    name: str
    media_type: str
    data: bytes


def _timestamp(t_ns: int) -> Timestamp:
    return Timestamp(t_ns // schema.NS, t_ns % schema.NS)


def _yaw_quaternion(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=float(np.sin(yaw / 2.0)), w=float(np.cos(yaw / 2.0)))


def _box(center: np.ndarray, half: np.ndarray, radius: float, yaw: float, z: float, color: Color) -> CubePrimitive:
    """A box standing for a rounded-rectangle footprint (the rounding added to the half-extents)."""
    return CubePrimitive(
        pose=Pose(position=Vector3(x=float(center[0]), y=float(center[1]), z=z), orientation=_yaw_quaternion(yaw)),
        size=Vector3(x=2.0 * float(half[0] + radius), y=2.0 * float(half[1] + radius), z=_BOX_HEIGHT),
        color=color,
    )


def _state_schema() -> foxglove.Schema:
    """The JSON schema of the state topics (``schema.STATE_SCHEMA``)."""
    return foxglove.Schema(
        name=schema.TOPICS[schema.STATE], encoding="jsonschema", data=json.dumps(schema.STATE_SCHEMA).encode()
    )


class EpisodeRecorder:
    """Writes episodes to one MCAP file.

    Usage: ``begin_episode(scene, first_step)`` after each reset, ``record_step(step)`` after every control step
    (a step with ``last`` set ends the episode: outcome event, ``episode_end``, flush), ``close()`` at the end
    (or use it as a context manager). An episode not ended when the recorder closes stays incomplete in the log.

    Args:
        path: The ``.mcap`` file to create.
        metadata: String pairs stored in the ``deck_sim`` metadata record (scene, seed, predictor, policy, ...);
            the recorder adds ``format``.
        attachments: Files stored in the log (compiled model, scene TOML, run configuration).
        chunk_size: Bytes (uncompressed) after which a chunk is closed.
        overwrite: Replace ``path`` if it exists (otherwise that is an error).

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is false.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, str],
        attachments: Sequence[Attachment] = (),
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise FileExistsError(f"{self.path}: the log exists; pass overwrite=True to replace it")
        bad = {k: v for k, v in metadata.items() if not isinstance(k, str) or not isinstance(v, str)}
        if bad:
            raise TypeError(f"metadata keys and values must be strings, got {bad!r}")
        self._context = foxglove.Context()
        options = MCAPWriteOptions(compression=MCAPCompression.Zstd, chunk_size=int(chunk_size), compression_threads=0)
        self._writer = foxglove.open_mcap(
            self.path, allow_overwrite=overwrite, context=self._context, writer_options=options
        )
        ctx = self._context
        self._tf = foxglove.Channel(
            schema.TF, schema=FrameTransforms.get_schema(), message_encoding="protobuf", context=ctx
        )
        self._scene = SceneUpdateChannel(schema.SCENE, context=ctx)
        # transforms and line strips are encoded with numpy (``_lines``): raw channels with the SDK's own schemas
        self._prediction = foxglove.Channel(
            schema.PREDICTION, schema=SceneUpdate.get_schema(), message_encoding="protobuf", context=ctx
        )
        self._path = foxglove.Channel(
            schema.PATH, schema=SceneUpdate.get_schema(), message_encoding="protobuf", context=ctx
        )
        self._state = foxglove.Channel(
            schema.STATE,
            schema=_state_schema(),
            message_encoding="json",
            context=ctx,
        )
        self._events = LogChannel(schema.EVENTS, context=ctx)
        self._writer.write_metadata(schema.METADATA_NAME, {**metadata, "format": schema.FORMAT})
        for a in attachments:
            self._writer.attach(log_time=0, create_time=0, name=a.name, media_type=a.media_type, data=a.data)
        self._writer.flush()
        self._closed = False
        self._next_base = 0
        self._scene_frame: SceneFrame | None = None
        self._aircraft_channels: dict[str, tuple[foxglove.Channel, foxglove.Channel]] = {}
        self.episodes_completed = 0
        """Episodes written to their end."""

    # -- episodes ------------------------------------------------------------------------------------------
    def begin_episode(self, scene: SceneFrame, first: StepFrame) -> None:
        """Start an episode: its ``episode_start`` event, its scene, and its state after the reset (step 0).

        An episode still open is left incomplete.
        """
        self._check_open()
        if isinstance(scene, TeamSceneFrame):
            raise RecordingError(f"the scene has {len(scene.agent_names)} aircraft: call begin_team_episode")
        self._open_episode(scene, first.step, first.episode, [schema.AGENT_FRAME], [])
        self._path_line = _lines.LineStrips(schema.ROOT_FRAME, ["agent_path"], _IDENTITY_PB, 0.5, _PATH_PB)
        self._path_fields = bytearray()  # the encoded points of the agent's path so far
        self._positions: list[np.ndarray] = []
        self._return = 0.0
        t_ns = schema.log_time(self._base, first.time)
        self._event(
            t_ns,
            "episode_start",
            LogLevel.Info,
            f"episode {scene.episode} start: {scene.scene}, target ({scene.target_xy[0]:.1f}, "
            f"{scene.target_xy[1]:.1f}) m, {len(scene.static_names)} static obstacles, "
            f"{len(scene.mover_names)} movers",
        )
        target = [("target", scene.target_xy, "target")]
        self._write_scene(t_ns, scene, target, [(schema.AGENT_FRAME, schema.AGENT_FRAME, first.agent_pose)],
                          first.mover_poses)
        self.record_step(first)

    def _open_episode(
        self, scene: SceneFrame, step: int, episode: int, aircraft: list[str], predicted_aircraft: list[str]
    ) -> None:
        """The start every episode shares: its first step checked, its time base, and the encoders of its frames
        (the ``aircraft`` frames, then the movers') and of its forecast lines (the movers', then
        ``predicted_aircraft``'s)."""
        if step != 0:
            raise RecordingError(f"an episode starts with step 0, got step {step}")
        if episode != scene.episode:
            raise RecordingError(f"step of episode {episode} given with the scene of episode {scene.episode}")
        if self._scene_frame is not None:  # the previous episode did not end
            self._next_base = schema.next_base(self._base, self._last_ns)
        self._base = self._next_base
        self._scene_frame = scene
        self._names = [*scene.mover_names]
        self._transforms = _lines.Transforms(schema.ROOT_FRAME, [*aircraft, *scene.mover_names])
        ids = [f"prediction/{name}" for name in (*scene.mover_names, *predicted_aircraft)]
        self._prediction_lines = _lines.LineStrips(schema.ROOT_FRAME, ids, _IDENTITY_PB, 0.4, _PREDICTION_PB)

    def _write_motion(self, t_ns: int, poses: np.ndarray, now_xy: np.ndarray, prediction: np.ndarray) -> bytes:
        """``/tf`` of every frame's pose and ``/prediction`` of every predicted vehicle (where it is now, then its
        N predicted positions); the step's encoded stamp."""
        self._last_ns = t_ns
        stamp = _lines.stamp(t_ns)
        self._tf.log(self._transforms.encode(stamp, poses), log_time=t_ns)
        n, horizon = prediction.shape[:2]
        if horizon > 0 and n > 0:
            xyz = np.empty((n, horizon + 1, 3))
            xyz[:, 0, :2], xyz[:, 1:, :2], xyz[..., 2] = now_xy, prediction, _LINE_Z
            fields = _lines.points(xyz)
            size = len(fields) // n
            parts = [fields[i * size : (i + 1) * size] for i in range(n)]
            self._prediction.log(self._prediction_lines.encode(stamp, parts), log_time=t_ns)
        return stamp

    def _fallback_event(self, t_ns: int, episode: int, step: int, count: int, what: str) -> None:
        if count:
            self._event(
                t_ns,
                "predictor_fallback",
                LogLevel.Warning,
                f"episode {episode} step {step}: the predictor fell back to constant velocity for {count} {what}",
            )

    def _close_episode(self, t_ns: int) -> None:
        """The end every episode shares, after its events: flush, the next time base, no episode open."""
        self._writer.flush()
        self._next_base = schema.next_base(self._base, t_ns)
        self._scene_frame = None
        self.episodes_completed += 1

    def record_step(self, frame: StepFrame) -> None:
        """Write one control step (``/tf``, ``/prediction``, ``/agent/path``, ``/agent/state``, events)."""
        self._check_open()
        scene = self._scene_frame
        if scene is None:
            raise RecordingError("record_step outside an episode: call begin_episode first")
        if isinstance(scene, TeamSceneFrame):
            raise RecordingError("record_step inside an episode of several aircraft: call record_team_step")
        if frame.episode != scene.episode:
            raise RecordingError(f"step of episode {frame.episode} in episode {scene.episode}")
        if frame.mover_poses.shape[0] != len(self._names):
            raise RecordingError(f"step has {frame.mover_poses.shape[0]} movers, the scene has {len(self._names)}")
        t_ns = schema.log_time(self._base, frame.time)
        poses = np.vstack([frame.agent_pose[None], frame.mover_poses])
        stamp = self._write_motion(t_ns, poses, frame.mover_xy, frame.prediction)
        self._path_fields += _lines.points([frame.agent_pose[0], frame.agent_pose[1], _LINE_Z])
        self._positions.append(frame.agent_pose[:2].copy())
        self._path.log(self._path_line.encode(stamp, [bytes(self._path_fields)]), log_time=t_ns)
        terms = frame.reward_terms
        self._state.log(json.dumps(schema.state_record(frame)).encode(), log_time=t_ns)
        if frame.step > 0:
            self._return += float(terms["total"])
        self._fallback_event(t_ns, frame.episode, frame.step, frame.predictor_fallbacks, "mover(s)")
        if frame.last:
            self._end_episode(frame, t_ns)

    def _end_episode(self, frame: StepFrame, t_ns: int) -> None:
        truncated = frame.discount is not None and frame.discount > 0 and not frame.reached_goal
        flags = {
            "diverged": frame.diverged,
            "collision": frame.collision,
            "left_surface": frame.left_surface,
            "reached_goal": frame.reached_goal,
        }
        outcome = outcome_of(flags, truncated)
        k, t = frame.episode, frame.time
        text = {
            "goal": (LogLevel.Info, f"episode {k}: reached the target at t = {t:.1f} s"),
            "collision": (LogLevel.Error, f"episode {k}: collision with {frame.collision} at t = {t:.1f} s"),
            "off_surface": (
                LogLevel.Warning,
                f"episode {k}: left the surface at ({frame.agent_pose[0]:.1f}, {frame.agent_pose[1]:.1f}) m",
            ),
            "timeout": (
                LogLevel.Warning,
                f"episode {k}: time limit at t = {t:.1f} s, {frame.distance_to_goal:.1f} m from the target",
            ),
            "diverged": (LogLevel.Error, f"episode {k}: the physics diverged at t = {t:.1f} s"),
        }
        level, message = text[outcome]
        self._event(t_ns, outcome, level, message)
        self._event(
            t_ns,
            "episode_end",
            LogLevel.Info,
            f"episode {k} end: {outcome}, {frame.step} steps, {t:.1f} s, return {self._return:.2f}, "
            f"path {path_length(np.array(self._positions)):.1f} m",
        )
        self._close_episode(t_ns)

    # -- episodes of several aircraft -----------------------------------------------------------------------
    def _agent_channels(self, name: str) -> tuple[foxglove.Channel, foxglove.Channel]:
        """Aircraft ``name``'s path and state channels (made on first use, kept for the file's later episodes)."""
        if name not in self._aircraft_channels:
            ctx = self._context
            path = foxglove.Channel(
                schema.agent_path_topic(name), schema=SceneUpdate.get_schema(), message_encoding="protobuf", context=ctx
            )
            state = foxglove.Channel(
                schema.agent_state_topic(name),
                schema=_state_schema(),
                message_encoding="json",
                context=ctx,
            )
            self._aircraft_channels[name] = (path, state)
        return self._aircraft_channels[name]

    def begin_team_episode(self, scene: TeamSceneFrame, first: TeamStepFrame) -> None:
        """``begin_episode`` for several aircraft: the scene with every aircraft's target and box, and step 0.

        An episode still open is left incomplete.
        """
        self._check_open()
        if not isinstance(scene, TeamSceneFrame):
            raise RecordingError("the scene has one aircraft: call begin_episode")
        if [a.name for a in first.aircraft] != list(scene.agent_names):
            raise RecordingError(f"step of aircraft {[a.name for a in first.aircraft]}, scene of {scene.agent_names}")
        names = list(scene.agent_names)
        self._open_episode(scene, first.step, first.episode, names, names)
        self._team_paths = [
            (_lines.LineStrips(schema.ROOT_FRAME, [f"{name}_path"], _IDENTITY_PB, 0.5, _PATH_PB), bytearray())
            for name in names
        ]
        self._team_done = [False] * len(names)
        self._team_returns = [0.0] * len(names)
        t_ns = schema.log_time(self._base, first.time)
        self._event(
            t_ns,
            "episode_start",
            LogLevel.Info,
            f"episode {scene.episode} start: {scene.scene}, {len(names)} aircraft, "
            f"{len(scene.static_names)} static obstacles, {len(scene.mover_names)} movers",
        )
        targets = [(f"target/{name}", xy, f"{name} target") for name, xy in zip(names, scene.targets_xy, strict=True)]
        agents = [(a.name, a.name, a.pose) for a in first.aircraft]
        self._write_scene(t_ns, scene, targets, agents, first.mover_poses)
        self.record_team_step(first)

    def record_team_step(self, frame: TeamStepFrame) -> None:
        """Write one control step of several aircraft (``/tf``, ``/prediction``, every aircraft's path and state,
        the outcome event of each aircraft done at this step; the episode's end at its last step)."""
        self._check_open()
        scene = self._scene_frame
        if not isinstance(scene, TeamSceneFrame):
            raise RecordingError("record_team_step outside an episode of several aircraft: call begin_team_episode")
        if frame.episode != scene.episode:
            raise RecordingError(f"step of episode {frame.episode} in episode {scene.episode}")
        if frame.mover_poses.shape[0] != len(self._names) or len(frame.aircraft) != len(scene.agent_names):
            raise RecordingError(
                f"step has {frame.mover_poses.shape[0]} movers and {len(frame.aircraft)} aircraft, the scene "
                f"{len(self._names)} and {len(scene.agent_names)}"
            )
        t_ns = schema.log_time(self._base, frame.time)
        poses = np.vstack([*(a.pose[None] for a in frame.aircraft), frame.mover_poses])
        now = np.vstack([frame.mover_xy, *(a.pose[None, :2] for a in frame.aircraft)])  # (the forecasts' order)
        stamp = self._write_motion(t_ns, poses, now, frame.prediction)
        for i, a in enumerate(frame.aircraft):
            path_channel, state_channel = self._agent_channels(a.name)
            line, points = self._team_paths[i]
            if not self._team_done[i]:  # the path ends where the aircraft was done
                points += _lines.points([a.track_xy[0], a.track_xy[1], _LINE_Z])
            path_channel.log(line.encode(stamp, [bytes(points)]), log_time=t_ns)
            state_channel.log(json.dumps(schema.aircraft_state_record(frame, i)).encode(), log_time=t_ns)
            if frame.step > 0 and not self._team_done[i]:
                self._team_returns[i] += float(a.reward_terms["total"])
            if a.done and not self._team_done[i]:
                self._team_done[i] = True
                self._aircraft_outcome(t_ns, frame, a, outcome_of({**vars(a), "diverged": False}, False))
        self._fallback_event(t_ns, frame.episode, frame.step, frame.predictor_fallbacks, "vehicle(s)")
        if frame.last:
            for i, a in enumerate(frame.aircraft):
                if not self._team_done[i]:
                    self._aircraft_outcome(t_ns, frame, a, "diverged" if frame.diverged else "timeout")
            reached = sum(a.reached_goal for a in frame.aircraft)
            self._event(
                t_ns,
                "episode_end",
                LogLevel.Info,
                f"episode {frame.episode} end: {reached} of {len(frame.aircraft)} aircraft reached their targets, "
                f"{frame.step} steps, {frame.time:.1f} s, returns "
                + ", ".join(f"{a.name} {r:.2f}" for a, r in zip(frame.aircraft, self._team_returns, strict=True)),
            )
            self._close_episode(t_ns)

    def _aircraft_outcome(self, t_ns: int, frame: TeamStepFrame, a: AircraftStep, outcome: str) -> None:
        k, t, name = frame.episode, frame.time, a.name
        text = {
            "goal": (LogLevel.Info, f"episode {k}: {name} reached its target at t = {t:.1f} s"),
            "collision": (LogLevel.Error, f"episode {k}: {name} collided with {a.collision} at t = {t:.1f} s"),
            "off_surface": (
                LogLevel.Warning,
                f"episode {k}: {name} left the surface at ({a.track_xy[0]:.1f}, {a.track_xy[1]:.1f}) m",
            ),
            "timeout": (
                LogLevel.Warning,
                f"episode {k}: {name} still taxiing at the time limit, t = {t:.1f} s, {a.distance_to_goal:.1f} m "
                "from its target",
            ),
            "diverged": (LogLevel.Error, f"episode {k}: the physics diverged at t = {t:.1f} s with {name} taxiing"),
        }
        level, message = text[outcome]
        self._event(t_ns, outcome, level, message)

    # -- messages ------------------------------------------------------------------------------------------
    def _event(self, t_ns: int, kind: str, level: LogLevel, message: str) -> None:
        self._events.log(Log(timestamp=_timestamp(t_ns), level=level, message=message, name=kind), log_time=t_ns)

    def _write_scene(
        self,
        t_ns: int,
        scene: SceneFrame,
        targets: Sequence[tuple[str, np.ndarray, str]],
        agents: Sequence[tuple[str, str, np.ndarray]],
        mover_poses: np.ndarray,
    ) -> None:
        """``/scene``: the deck, each target (entity id, position, label), the static obstacles, each aircraft's box
        (frame, entity id, pose at the reset) and each mover's."""
        stamp = _timestamp(t_ns)
        (x0, y0), (x1, y1) = np.asarray(scene.bounds, dtype=float).tolist()
        entities = [
            SceneEntity(
                timestamp=stamp,
                frame_id=schema.ROOT_FRAME,
                id="deck",
                metadata=[KeyValuePair(key="scene_frame", value=schema.scene_to_json(scene))],
                cubes=[
                    CubePrimitive(
                        pose=Pose(
                            position=Vector3(x=(x0 + x1) / 2, y=(y0 + y1) / 2, z=-0.05),
                            orientation=_NO_ROTATION,
                        ),
                        size=Vector3(x=x1 - x0, y=y1 - y0, z=0.1),
                        color=_DECK_COLOR,
                    )
                ],
                lines=[
                    LinePrimitive(
                        type=LinePrimitiveLineType.LineLoop,
                        pose=_IDENTITY,
                        thickness=0.5,
                        color=_WHITE,
                        points=[Point3(x=x, y=y, z=0.05) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))],
                    )
                ],
            ),
        ]
        for entity, xy, label in targets:
            entities.append(
                SceneEntity(
                    timestamp=stamp,
                    frame_id=schema.ROOT_FRAME,
                    id=entity,
                    cylinders=[
                        CylinderPrimitive(
                            pose=Pose(
                                position=Vector3(x=float(xy[0]), y=float(xy[1]), z=0.1), orientation=_NO_ROTATION
                            ),
                            size=Vector3(x=2 * scene.goal_radius, y=2 * scene.goal_radius, z=0.2),
                            bottom_scale=1.0,
                            top_scale=1.0,
                            color=_TARGET_COLOR,
                        )
                    ],
                    texts=[
                        TextPrimitive(
                            pose=Pose(
                                position=Vector3(x=float(xy[0]), y=float(xy[1]), z=3.0), orientation=_NO_ROTATION
                            ),
                            billboard=True,
                            font_size=14.0,
                            scale_invariant=True,
                            color=_WHITE,
                            text=label,
                        )
                    ],
                )
            )
        st = scene.statics
        for i, name in enumerate(scene.static_names):
            entities.append(
                SceneEntity(
                    timestamp=stamp,
                    frame_id=schema.ROOT_FRAME,
                    id=f"static/{name}",
                    cubes=[_box(st.centers[i], st.half[i], st.radius[i], st.yaw[i], _BOX_HEIGHT / 2, _STATIC_COLOR)],
                )
            )
        # the agent and the movers: boxes locked to their frames (moved by /tf), standing on the deck
        bodies = [(frame, entity, scene.agent_footprint, 0, pose, _AGENT_COLOR) for frame, entity, pose in agents]
        bodies += [
            (name, f"mover/{name}", scene.movers, i, mover_poses[i], _MOVER_COLOR)
            for i, name in enumerate(scene.mover_names)
        ]
        for name, entity, fp, i, pose, color in bodies:
            z = _BOX_HEIGHT / 2 - float(pose[2])
            entities.append(
                SceneEntity(
                    timestamp=stamp,
                    frame_id=name,
                    id=entity,
                    frame_locked=True,
                    cubes=[_box(fp.centers[i], fp.half[i], fp.radius[i], 0.0, z, color)],
                )
            )
        self._scene.log(
            SceneUpdate(
                deletions=[SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.All)],
                entities=entities,
            ),
            log_time=t_ns,
        )

    # -- lifetime ------------------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError(f"{self.path}: the recorder is closed")

    def close(self) -> None:
        """Finish the file (summary, indexes, footer). An episode still open stays incomplete in the log."""
        if self._closed:
            return
        self._closed = True
        self._writer.close()

    def __enter__(self) -> EpisodeRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
