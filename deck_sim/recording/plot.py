"""Top-down picture of a logged episode, like the paper's trajectory figures (matplotlib, no MuJoCo).

The surface, the static obstacles (rounded footprints), every mover's path (its footprint drawn where it ended),
the agent's path from its start to its end, the target, and the movers' predicted paths at chosen steps; for
several aircraft, every aircraft's path to where it was done and its target, each in its colour.
Metres on both axes, x to the right (on the deck: towards the bow), y up (to port).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from deck_sim.geometry import Footprints
from deck_sim.metrics import path_length
from deck_sim.recording.reader import LogError, LoggedEpisode


def footprint_outline(center: np.ndarray, half: np.ndarray, yaw: float, radius: float, arc: int = 6) -> np.ndarray:
    """(k, 2) closed polygon (metres) of a rounded rectangle: half-extents ``half`` grown by ``radius``, rotated
    by ``yaw`` (radians) about ``center``."""
    corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float) * np.asarray(half, dtype=float)
    if radius > 0:
        pts = []
        for i, c in enumerate(corners):
            a = np.linspace(i * np.pi / 2, (i + 1) * np.pi / 2, arc)
            pts.append(c + radius * np.stack([np.cos(a), np.sin(a)], axis=1))
        local = np.concatenate(pts)
    else:
        local = corners
    cy, sy = np.cos(yaw), np.sin(yaw)
    world = local @ np.array([[cy, sy], [-sy, cy]]) + np.asarray(center, dtype=float)
    return np.vstack([world, world[:1]])


def quaternion_yaw(quat: np.ndarray) -> np.ndarray:
    """Yaw (radians) of quaternions (..., 4) ordered w, x, y, z."""
    w, x, y, z = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def default_prediction_steps(steps: int, count: int = 4) -> list[int]:
    """``count`` steps spread evenly over an episode of ``steps`` steps (the reset and the end excluded)."""
    if steps < 2:
        return []
    return sorted({int(round(s)) for s in np.linspace(0, steps - 1, count + 2)[1:-1]})


def plot_episode(
    episode: LoggedEpisode,
    out: str | os.PathLike[str],
    prediction_steps: Sequence[int] | None = None,
    width_inches: float = 16.0,
    dpi: int = 120,
) -> Path:
    """Write a top-down PNG of ``episode`` to ``out`` (an episode of several aircraft: every aircraft's path to
    where it was done, each in its colour with its target).

    Args:
        prediction_steps: Steps whose predictions are drawn (default: four spread over the episode); steps the
            log lacks raise ``LogError``.
        width_inches: Figure width; the height follows the surface's aspect.
        dpi: Resolution.
    """
    steps = episode.team_steps if episode.team else episode.steps
    if not steps:
        raise LogError(f"episode {episode.index} holds no steps to plot")
    scene = episode.scene
    by_step = {s.step: s for s in steps}
    if prediction_steps is None:
        prediction_steps = default_prediction_steps(len(steps))
    missing = [k for k in prediction_steps if k not in by_step]
    if missing:
        raise LogError(f"episode {episode.index} has steps 0..{steps[-1].step}; no step {missing}")
    fig, ax = _canvas(scene, width_inches, dpi)
    movers = np.stack([s.mover_poses for s in steps])  # (T, n, 7)
    colors = ["#f9ab00", "#e37400", "#a142f4", "#12b5cb", "#795548", "#ff63b8", "#9aa0a6", "#9e9d24", "#3949ab"]
    yaw_end = quaternion_yaw(movers[-1, :, 3:7])
    for i, name in enumerate(scene.mover_names):
        c = colors[i % len(colors)]
        ax.plot(movers[:, i, 0], movers[:, i, 1], color=c, lw=1.3, zorder=3, label=name)
        ax.plot(movers[0, i, 0], movers[0, i, 1], "o", color=c, ms=3.5, zorder=3)
        fp = scene.movers
        rot = np.array([[np.cos(yaw_end[i]), -np.sin(yaw_end[i])], [np.sin(yaw_end[i]), np.cos(yaw_end[i])]])
        center = movers[-1, i, :2] + rot @ fp.centers[i]
        ax.add_patch(_polygon(footprint_outline(center, fp.half[i], yaw_end[i], fp.radius[i]), c, c, 0.45, zorder=3))
    if episode.team:
        title = _team_paths(ax, episode, steps, prediction_steps, by_step)
    else:
        title = _agent_path(ax, episode, steps, prediction_steps, by_step)
    ax.set_title(title, fontsize=11)
    (x0, y0), (x1, y1) = scene.bounds
    margin = 0.04 * (x1 - x0)
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim(y0 - margin, y1 + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    return out


def _canvas(scene, width_inches: float, dpi: int):  # noqa: ANN001, ANN202 - (matplotlib Figure, Axes)
    """A figure of the surface's aspect with the surface and the static obstacles drawn."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    (x0, y0), (x1, y1) = scene.bounds
    margin = 0.04 * (x1 - x0)
    aspect = (y1 - y0 + 2 * margin) / (x1 - x0 + 2 * margin)
    fig = Figure(figsize=(width_inches, max(3.0, 0.8 * width_inches * aspect + 1.2)), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.add_patch(_polygon([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], "#d9dadc", "#6b6e73", 1.0, zorder=0))
    st: Footprints = scene.statics
    for i in range(len(st)):
        outline = footprint_outline(st.centers[i], st.half[i], st.yaw[i], st.radius[i])
        ax.add_patch(_polygon(outline, "#5f6368", "#3c4043", 0.6, zorder=1))
    return fig, ax


def _predictions(ax, lines: Sequence[tuple[np.ndarray, np.ndarray]], first: bool) -> bool:  # noqa: ANN001
    """Draw predicted paths (each: where the vehicle is now, its predicted positions); whether the legend's entry
    is still to be drawn."""
    for now, future in lines:
        line = np.vstack([now[None], future])
        ax.plot(line[:, 0], line[:, 1], "--", color="#1a73e8", lw=1.1, marker=".", ms=3, zorder=4,
                label="predicted (at marked steps)" if first else None)
        ax.plot(*now, "o", mfc="none", mec="#1a73e8", ms=5, zorder=4)
        first = False
    return first


def _target(ax, xy: np.ndarray, radius: float, color: str, label: str) -> None:  # noqa: ANN001
    goal = np.linspace(0, 2 * np.pi, 60)
    ax.fill(xy[0] + radius * np.cos(goal), xy[1] + radius * np.sin(goal), facecolor=color, edgecolor="#0d652d",
            alpha=0.7, zorder=7, label=label)


def _agent_path(ax, episode: LoggedEpisode, steps, prediction_steps, by_step) -> str:  # noqa: ANN001
    """One aircraft: its path, its body where it ended, the movers' predictions and its target; the title."""
    scene = episode.scene
    first = True
    for k in prediction_steps:
        s = by_step[k]
        if s.prediction.shape[1] == 0:
            continue
        first = _predictions(ax, [(s.mover_xy[i], s.prediction[i]) for i in range(len(scene.mover_names))], first)
        ax.plot(*s.agent_xy, "o", color="#1a73e8", mec="white", ms=6, zorder=6)
        ax.annotate(f"t={s.time:.0f} s", s.agent_xy, xytext=(4, 6), textcoords="offset points", fontsize=8, zorder=6)
    xy = np.stack([s.agent_xy for s in steps])
    ax.plot(xy[:, 0], xy[:, 1], color="#d93025", lw=2.4, zorder=5, label="agent")
    ax.plot(*xy[0], "s", color="#d93025", mec="white", ms=7, zorder=6)
    end = steps[-1]
    yaw = quaternion_yaw(end.agent_pose[3:7])
    afp = scene.agent_footprint
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    outline = footprint_outline(end.agent_xy + rot @ afp.centers[0], afp.half[0], float(yaw), afp.radius[0])
    ax.add_patch(_polygon(outline, "#d93025", "#d93025", 0.5, zorder=5))
    _target(ax, scene.target_xy, scene.goal_radius, "#34a853", "target")
    outcome = episode.outcome or "incomplete"
    return (f"{scene.scene}, episode {episode.index}: {outcome} after {end.step} steps ({end.time:.1f} s), "
            f"agent path {path_length(xy):.1f} m")


_AIRCRAFT_COLORS = ["#d93025", "#1e8e3e", "#1967d2", "#9334e6", "#e8710a", "#c5221f", "#188038", "#174ea6"]


def _team_paths(ax, episode: LoggedEpisode, steps, prediction_steps, by_step) -> str:  # noqa: ANN001
    """Several aircraft: each one's path to where it was done and its target, in its colour, and the predictions
    of the movers and of the aircraft still taxiing at the marked steps; the title."""
    scene = episode.scene
    n = len(scene.mover_names)
    first = True
    for k in prediction_steps:
        s = by_step[k]
        if s.prediction.shape[1] == 0:
            continue
        lines = [(s.mover_xy[i], s.prediction[i]) for i in range(n)]
        lines += [(a.track_xy, s.prediction[n + i]) for i, a in enumerate(s.aircraft) if not a.done]
        first = _predictions(ax, lines, first)
    reached = 0
    for i, name in enumerate(scene.agent_names):
        c = _AIRCRAFT_COLORS[i % len(_AIRCRAFT_COLORS)]
        track = []
        for s in steps:
            track.append(s.aircraft[i].track_xy)
            if s.aircraft[i].done:
                break
        xy = np.stack(track)
        end = steps[-1].aircraft[i]
        reached += end.reached_goal
        outcome = "reached" if end.reached_goal else (f"hit {end.collision}" if end.collision else
                                                      "left the deck" if end.left_surface else "taxiing")
        ax.plot(xy[:, 0], xy[:, 1], color=c, lw=2.4, zorder=5, label=f"{name} ({outcome})")
        ax.plot(*xy[0], "s", color=c, mec="white", ms=7, zorder=6)
        ax.plot(*xy[-1], "X" if end.collision else "o", color=c, mec="white", ms=8, zorder=6)
        _target(ax, scene.targets_xy[i], scene.goal_radius, c, f"{name} target")
    end = steps[-1]
    return (f"{scene.scene}, episode {episode.index}: {reached} of {len(scene.agent_names)} aircraft reached their "
            f"targets, {end.step} steps ({end.time:.1f} s)")


def _polygon(points: np.ndarray | list, face: str, edge: str, alpha: float, zorder: int):  # noqa: ANN202
    from matplotlib.patches import Polygon

    return Polygon(np.asarray(points), closed=True, facecolor=face, edgecolor=edge, alpha=alpha, zorder=zorder)
