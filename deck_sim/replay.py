"""Show a logged episode in MuJoCo again: rebuild the scene from the log, pose every body from the logged states,
render (``deck-sim log video``).

Only poses are replayed, not dynamics: the agent's and movers' root bodies take their logged 3D poses, the static
obstacles and the target their logged places; wheels and steering stay as the reset left them.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path

import mujoco
import numpy as np
from dm_control import composer, mjcf
from dm_control.mujoco.engine import TextOverlay

from deck_sim.entities import Pedestrian
from deck_sim.environment import make_environment
from deck_sim.recording import EpisodeLog, LogError, LoggedEpisode
from deck_sim.scenes import SceneSpecError, parse_scene
from deck_sim.types import SceneFrame, StepFrame, TeamStepFrame

_PATH_RGBA = np.array([0.85, 0.15, 0.1, 1.0], dtype=np.float32)
_PREDICTION_RGBA = np.array([0.2, 0.6, 1.0, 1.0], dtype=np.float32)

VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov", ".avi", ".gif")
"""File extensions a video is written with (``render_episode``, ``deck-sim render``, ``deck-sim log video``)."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
"""File extensions a picture is written with (``deck-sim render --png``)."""
MIN_FRAME = 16
"""Pixels: the smallest side of a rendered frame (the video encoder works on blocks of 16 pixels)."""


def check_suffix(name: str, path: str | os.PathLike[str], suffixes: tuple[str, ...]) -> Path:
    """``path`` if its extension is one of ``suffixes`` (any case); ``ValueError`` naming ``name`` otherwise."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise ValueError(
            f"{name} {str(path)!r}: the file name needs one of the extensions {', '.join(suffixes)} "
            "(the extension chooses the format)"
        )
    return path


def check_count(name: str, value: int | None, least: int = 1) -> None:
    """``ValueError`` naming ``name`` unless ``value`` is ``None`` or an integer of at least ``least``."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least):
        raise ValueError(f"{name} must be an integer of at least {least}, got {value!r}")


def check_speedup(name: str, value: float) -> None:
    """``ValueError`` naming ``name`` unless ``value`` (playback speed over simulated time) is finite and positive."""
    if not (isinstance(value, int | float | np.number) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number (playback speed over simulated time), got {value!r}")


def camera_names(physics: mjcf.Physics) -> tuple[str, ...]:
    """The named cameras of the compiled model (``top``, ``follow``, ``agent/chase`` in deck_sim's scenes)."""
    model = physics.model
    return tuple(model.id2name(i, "camera") for i in range(model.ncam))


def check_view(physics: mjcf.Physics, camera: str, frames: dict[str, tuple[int, int]]) -> None:
    """``ValueError`` unless ``camera`` is a camera of the model and every frame (``what -> (width, height)``,
    pixels) fits MuJoCo's offscreen buffer (``<visual><global offwidth offheight>`` of the scene's XML)."""
    names = camera_names(physics)
    if camera not in names:
        raise ValueError(f"camera {camera!r} is not in the scene; its cameras are {', '.join(names)}")
    glob = physics.model.vis.global_
    for what, (width, height) in frames.items():
        if not (MIN_FRAME <= width <= glob.offwidth and MIN_FRAME <= height <= glob.offheight):
            raise ValueError(
                f"{what} of {width}x{height} pixels does not fit: each side must be at least {MIN_FRAME} and at most "
                f"the scene's offscreen buffer of {glob.offwidth}x{glob.offheight} pixels"
            )


def replay_environment(log: EpisodeLog) -> composer.Environment:
    """A fresh environment of the log's scene (from its ``scene.toml`` attachment), reset once."""
    if "scene.toml" not in log.attachments:
        raise LogError(f"{log.path}: no scene.toml attachment; cannot rebuild the scene")
    try:
        spec = parse_scene(tomllib.loads(log.attachments["scene.toml"][1].decode()), f"{log.path.name}:scene.toml")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, SceneSpecError) as err:
        raise LogError(f"{log.path}: its scene.toml does not load: {err}") from None
    env = make_environment(spec, seed=0)
    env.reset()
    return env


def pose_bodies(env: composer.Environment, scene: SceneFrame, step: StepFrame | TeamStepFrame) -> None:
    """Place the aircraft, movers, static obstacles and targets of ``env`` as logged, then update the kinematics."""
    task, physics = env.task, env.physics
    names = tuple(m.mjcf_model.model for m in task.movers)
    if names != scene.mover_names:
        raise LogError(f"the log's movers {scene.mover_names} are not the scene's {names}")
    if isinstance(step, TeamStepFrame):
        if tuple(task.agent_names) != scene.agent_names:
            raise LogError(f"the log's aircraft {scene.agent_names} are not the scene's {tuple(task.agent_names)}")
        aircraft = list(zip(task.agents, (a.pose for a in step.aircraft), strict=True))
        targets = [(f"target_{i}", xy) for i, xy in enumerate(scene.targets_xy)]
    else:
        aircraft, targets = [(task.agent, step.agent_pose)], [("target", scene.target_xy)]
    for entity, pose in (*aircraft, *zip(task.movers, step.mover_poses, strict=True)):
        if isinstance(entity, Pedestrian):  # slide joints in the attachment frame
            frame = physics.bind(mjcf.get_attachment_frame(entity.mjcf_model))
            physics.bind(list(entity.joints)).qpos = pose[:2] - frame.pos[:2]
        else:
            entity.set_pose(physics, position=pose[:3], quaternion=pose[3:7])
    for prop, (x, y, yaw) in zip(task.statics, scene.static_poses, strict=False):
        prop.set_pose(physics, np.array([x, y, 0.0]), np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
    for name, xy in targets:
        physics.bind(task.root_entity.mjcf_model.find("body", name)).pos = [*xy, 0.0]
    physics.forward()


def _segments(scn: mujoco.MjvScene, points: np.ndarray, width: float, rgba: np.ndarray) -> None:
    """Add capsules joining consecutive 3D points to the scene (as many as it has room for)."""
    for a, b in zip(points[:-1], points[1:], strict=True):
        if scn.ngeom >= scn.maxgeom or np.allclose(a, b):
            continue
        scn.ngeom += 1  # the geoms view covers the first ngeom entries
        geom = scn.geoms[scn.ngeom - 1]
        mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.zeros(9), rgba)
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, width, a, b)


def _tracks(s: StepFrame | TeamStepFrame) -> tuple[list[np.ndarray], list[bool], np.ndarray]:
    """Where each aircraft's path stands at step ``s`` and whether the aircraft is done, and where each predicted
    vehicle stands (movers, then aircraft; NaN for an aircraft that is done: its forecast is not drawn)."""
    if isinstance(s, TeamStepFrame):
        aircraft = np.array([np.full(2, np.nan) if a.done else a.pose[:2] for a in s.aircraft])
        return [a.track_xy for a in s.aircraft], [a.done for a in s.aircraft], np.vstack([s.mover_xy, aircraft])
    return [s.agent_xy], [False], s.mover_xy


def render_episode(
    episode: LoggedEpisode,
    env: composer.Environment,
    out: str | os.PathLike[str],
    width: int = 640,
    height: int | None = None,
    camera: str = "top",
    speedup: float = 4.0,
    max_steps: int | None = None,
) -> tuple[Path, int, float]:
    """Write an MP4 of ``episode`` posed in ``env`` (from ``replay_environment``), with the agent's path so far
    (red) and the movers' predictions (blue) drawn in.

    Args:
        out: The video file; its extension (``VIDEO_SUFFIXES``) chooses the format.
        width: Frame width in pixels (rounded to a multiple of 16).
        height: Frame height; default: the width over the top view's aspect (``camera="top"``) or 3/4 of it.
        camera: ``top`` (the whole surface from above), ``follow`` or ``agent/chase``.
        speedup: Playback speed over simulated time.
        max_steps: Render at most this many steps (default: all).

    Returns:
        (path, frames, frames per second).

    Raises:
        ValueError: ``out`` has no video extension, a size, ``speedup`` or ``max_steps`` is out of range, or
            ``camera`` is not one of the scene's (checked before anything is rendered).
        LogError: the episode holds no step.
    """
    import imageio.v3 as iio

    out = check_suffix("out", out, VIDEO_SUFFIXES)
    check_count("width", width, MIN_FRAME)
    check_count("height", height, MIN_FRAME)
    check_speedup("speedup", speedup)
    check_count("max_steps", max_steps)
    logged = episode.team_steps if episode.team else episode.steps
    steps = logged if max_steps is None else logged[: max_steps + 1]
    if not steps:
        raise LogError(f"episode {episode.index} holds no steps to render")
    width = max(16, int(round(width / 16)) * 16)
    if height is None:
        height = width / env.task.top_view_aspect if camera == "top" else 0.75 * width
    height = max(16, int(round(height / 16)) * 16)
    check_view(env.physics, camera, {"a frame": (width, height)})
    z = 0.6
    frames = []
    paths: list[list[np.ndarray]] = [[] for _ in _tracks(steps[0])[0]]
    ended = [False] * len(paths)
    for s in steps:
        pose_bodies(env, episode.scene, s)
        tracks, done, now = _tracks(s)
        for i, xy in enumerate(tracks):
            if not ended[i]:  # a path ends where its aircraft was done
                paths[i].append(np.array([*xy, z]))
            ended[i] = done[i]

        def draw(
            physics: object, scn: mujoco.MjvScene, s: StepFrame | TeamStepFrame = s, now: np.ndarray = now
        ) -> None:
            for path in paths:
                _segments(scn, np.array(path), 0.35, _PATH_RGBA)
            for i in range(s.prediction.shape[0]):
                if np.isnan(now[i, 0]):
                    continue
                line = np.vstack([now[i][None], s.prediction[i]])
                _segments(scn, np.column_stack([line, np.full(len(line), z)]), 0.25, _PREDICTION_RGBA)

        text = TextOverlay(
            title=f"episode {episode.index}", body=f"{s.time:.1f} s", style="normal", position="bottom left"
        )
        frames.append(env.physics.render(height, width, camera_id=camera, overlays=(text,), scene_callback=draw))
    fps = speedup / episode.scene.dt
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, np.stack(frames), fps=fps, codec="libx264", macro_block_size=16)
    return out, len(frames), fps
