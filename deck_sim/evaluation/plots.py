"""The evaluation's figures: learning curves from training run folders and top-down trajectories from the logs."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from deck_sim.evaluation.harness import EvalResults


def plot_learning_curves(runs: dict[str, str | os.PathLike[str]], out: str | os.PathLike[str], title: str = "") -> Path:
    """Average reward and success against training steps (the paper's Figs. 8-11) from training run folders.

    Args:
        runs: label -> a run folder written by ``deck-sim train`` (its ``eval.csv``: held-out evaluations).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4))
    FigureCanvasAgg(fig)
    ax_r, ax_s = fig.subplots(1, 2)
    for label, run in runs.items():
        path = Path(run) / "eval.csv"
        if not path.exists():
            raise FileNotFoundError(f"{path}: no evaluation log in run folder {run} (train with deck-sim train)")
        with open(path) as f:
            rows = list(csv.DictReader(f))
        if not rows:
            raise ValueError(f"{path} holds no evaluation rows")
        polished = [r for r in rows if r.get("polished") == "1"]  # the final cloning fit, at the last step
        rows = [r for r in rows if r.get("polished") != "1"]
        step = [float(r["step"]) for r in rows]
        (line,) = ax_r.plot(step, [float(r["reward"]) for r in rows], marker="o", ms=3, label=label)
        ax_s.plot(step, [100 * float(r["success"]) for r in rows], marker="o", ms=3, label=label)
        for r in polished:
            kw = {"marker": "*", "ms": 10, "color": line.get_color(), "linestyle": "none"}
            ax_r.plot([float(r["step"])], [float(r["reward"])], **kw)
            ax_s.plot([float(r["step"])], [100 * float(r["success"])], **kw)
    ax_r.set(xlabel="environment steps", ylabel="average episode reward (held-out)", title=title or "reward")
    ax_s.set(xlabel="environment steps", ylabel="success % (held-out)", title="success", ylim=(0, 100))
    for ax in (ax_r, ax_s):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out


def plot_trajectories(res: EvalResults, out_dir: str | os.PathLike[str], per_agent: int = 1) -> list[Path]:
    """A top-down PNG of the first ``per_agent`` logged episodes of every scene and agent (from the MCAP logs)."""
    from deck_sim.recording import EpisodeLog
    from deck_sim.recording.plot import plot_episode

    out_dir = Path(out_dir)
    written = []
    for path in map(Path, res.logs):
        if not path.stem.endswith("-0000"):  # the first unit of each scene and agent holds its first episodes
            continue
        episodes = EpisodeLog(path).episodes
        for ep in episodes[:per_agent]:
            dest = out_dir / f"{path.stem.removesuffix('-0000')}-episode{ep.index}.png"
            written.append(plot_episode(ep, dest, width_inches=12.0))
    return written

