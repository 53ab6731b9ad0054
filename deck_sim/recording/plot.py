"""Top-down picture of a logged episode, like the paper's trajectory figures (matplotlib, no MuJoCo).

The surface, the static obstacles (rounded footprints), every mover's path (its footprint drawn where it ended),
the agent's path from its start to its end, the target, and the movers' predicted paths at chosen steps.
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
    """Write a top-down PNG of ``episode`` to ``out``.

    Args:
        prediction_steps: Steps whose predictions are drawn (default: four spread over the episode); steps the
            log lacks raise ``LogError``.
        width_inches: Figure width; the height follows the surface's aspect.
        dpi: Resolution.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    steps = episode.steps
    if not steps:
        raise LogError(f"episode {episode.index} holds no steps to plot")
    scene = episode.scene
    by_step = {s.step: s for s in steps}
    if prediction_steps is None:
        prediction_steps = default_prediction_steps(len(steps))
    missing = [k for k in prediction_steps if k not in by_step]
    if missing:
        raise LogError(f"episode {episode.index} has steps 0..{steps[-1].step}; no step {missing}")
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

    first_pred = True
    for k in prediction_steps:
        s = by_step[k]
        if s.prediction.shape[1] == 0:
            continue
        for i in range(len(scene.mover_names)):
            line = np.vstack([s.mover_xy[i][None], s.prediction[i]])
            ax.plot(
                line[:, 0],
                line[:, 1],
                "--",
                color="#1a73e8",
                lw=1.1,
                marker=".",
                ms=3,
                zorder=4,
                label="predicted (at marked steps)" if first_pred else None,
            )
            first_pred = False
        ax.plot(s.mover_xy[:, 0], s.mover_xy[:, 1], "o", mfc="none", mec="#1a73e8", ms=5, zorder=4)
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

    goal = np.linspace(0, 2 * np.pi, 60)
    tx, ty = scene.target_xy
    ax.fill(
        tx + scene.goal_radius * np.cos(goal),
        ty + scene.goal_radius * np.sin(goal),
        facecolor="#34a853",
        edgecolor="#0d652d",
        alpha=0.7,
        zorder=7,
        label="target",
    )

    outcome = episode.outcome or "incomplete"
    ax.set_title(
        f"{scene.scene}, episode {episode.index}: {outcome} after {end.step} steps ({end.time:.1f} s), "
        f"agent path {path_length(xy):.1f} m",
        fontsize=11,
    )
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


def _polygon(points: np.ndarray | list, face: str, edge: str, alpha: float, zorder: int):  # noqa: ANN202
    from matplotlib.patches import Polygon

    return Polygon(np.asarray(points), closed=True, facecolor=face, edgecolor=edge, alpha=alpha, zorder=zorder)
