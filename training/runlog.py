"""A training run's logs: ``progress.csv``, ``eval.csv`` and the same scalars for TensorBoard under ``tb/``.

``progress.csv`` gets a row of training statistics every ``log_every`` environment steps (``PROGRESS_FIELDS``),
``eval.csv`` one per held-out evaluation (``EVAL_FIELDS``). TensorBoard gets every column of both but the step,
which is its x axis: ``train/<column>`` and ``eval/<column>``, and the final cloning fit's loss per epoch as
``polish/bc_loss``. A resumed run cuts both CSV files back to its checkpoint's step and TensorBoard hides what was
logged after it.
"""

from __future__ import annotations

import csv
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

PROGRESS_FIELDS = (
    "step",
    "episodes",
    "wall_s",
    "sps",
    "ep_reward",
    "success",
    "collision",
    "timeout",
    "critic_loss",
    "q",
    "actor_loss",
    "bc_loss",
    "noise_sigma",
    "stage",
    "updates",
)
EVAL_FIELDS = (
    "step",
    "wall_s",
    "episodes",
    "success",
    "collision",
    "timeout",
    "reward",
    "path_ratio",
    "turning_deg",
    "polished",
)


def eval_row(step: int, wall: float, summary: dict[str, float], polished: bool = False) -> dict[str, Any]:
    """One ``eval.csv`` row (``EVAL_FIELDS``) from ``deck_sim.metrics.summarize``'s summary of an evaluation;
    ``polished`` marks the evaluation after ``polish_epochs`` (the same step as the last online one)."""
    return {
        "step": step,
        "wall_s": round(wall, 2),
        "episodes": int(summary["episodes"]),
        "success": summary["goal_rate"],
        "collision": summary["collision_rate"],
        "timeout": summary["timeout_rate"],
        "reward": summary["mean_reward"],
        "path_ratio": summary["path_ratio"],
        "turning_deg": summary["turning_angle_deg"],
        "polished": int(polished),
    }


@dataclass
class EpisodeStats:
    """The training statistics a progress row reports: the outcomes and returns of the last 50 episodes, the
    episodes finished so far and the learner's latest update statistics (losses, Q)."""

    recent: deque[tuple[str, float]] = field(default_factory=lambda: deque(maxlen=50))
    """(outcome, unscaled return) of the last 50 finished episodes."""
    episodes: int = 0
    """Training episodes finished so far, over all environments."""
    updates: dict[str, float] = field(default_factory=dict)
    """The latest value of each statistic ``DDPGAgent.update`` returns."""

    def episode_end(self, outcome: str, ret: float) -> None:
        """Count a finished episode of ``outcome`` (``deck_sim.metrics.outcome_of``) and return ``ret``."""
        self.recent.append((outcome, ret))
        self.episodes += 1


def progress_row(
    stats: EpisodeStats, step: int, wall: float, sps: float, noise_sigma: float, stage: int, updates: int
) -> dict[str, Any]:
    """One ``progress.csv`` row (``PROGRESS_FIELDS``): ``wall`` seconds of the run, ``sps`` environment steps per
    second since the last row, ``stage`` the curriculum stage of the first environment, ``updates`` the agent's
    gradient updates so far."""
    outcomes = [o for o, _ in stats.recent]
    n = max(len(outcomes), 1)
    s = stats.updates
    return {
        "step": step,
        "episodes": stats.episodes,
        "wall_s": round(wall, 2),
        "sps": round(sps, 1),
        "ep_reward": float(np.mean([r for _, r in stats.recent])) if stats.recent else 0.0,
        "success": outcomes.count("goal") / n,
        "collision": outcomes.count("collision") / n,
        "timeout": outcomes.count("timeout") / n,
        "critic_loss": s.get("critic_loss", float("nan")),
        "q": s.get("q", float("nan")),
        "actor_loss": s.get("actor_loss", float("nan")),
        "bc_loss": s.get("bc_loss", float("nan")),
        "noise_sigma": noise_sigma,
        "stage": stage,
        "updates": updates,
    }


class RunLog:
    """The CSV logs and the TensorBoard writer of the run in ``run_dir``."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self._tb: Any = None

    def open_csv(self, truncate_after: int | None) -> bool:
        """Start the CSV logs, keeping the rows up to step ``truncate_after`` (a resumed run; None: a new run,
        headers only); whether ``eval.csv`` kept a row at exactly that step."""
        evaluated = False
        for name, fields in (("progress.csv", PROGRESS_FIELDS), ("eval.csv", EVAL_FIELDS)):
            path = self.run_dir / name
            kept: list[dict[str, str]] = []
            if truncate_after is not None and path.exists():
                with open(path, newline="") as f:
                    kept = [r for r in csv.DictReader(f) if int(r["step"]) <= truncate_after]
                evaluated = evaluated or (name == "eval.csv" and any(int(r["step"]) == truncate_after for r in kept))
            with open(path, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=fields)
                w.writeheader()
                w.writerows(kept)
        return evaluated

    def open_tensorboard(self, step: int) -> None:
        """Start writing TensorBoard events at environment step ``step``: what an earlier process logged after
        that step (a run resumed from its checkpoint) is hidden, as the CSV logs are cut back."""
        from torch.utils.tensorboard import SummaryWriter

        self._tb = SummaryWriter(str(self.run_dir / "tb"), purge_step=step + 1 if step else None)

    def close_tensorboard(self) -> None:
        """Flush and close the TensorBoard writer; later rows go to the CSV files only."""
        if self._tb is not None:
            self._tb.close()
            self._tb = None

    def scalar(self, tag: str, value: float, step: int) -> None:
        """One TensorBoard scalar (none while no writer is open)."""
        if self._tb is not None:
            self._tb.add_scalar(tag, value, step)

    def progress(self, row: dict[str, Any]) -> None:
        """Append a ``progress_row`` to ``progress.csv`` and each of its columns to TensorBoard as ``train/``."""
        self._append("progress.csv", PROGRESS_FIELDS, row)
        for k in PROGRESS_FIELDS[1:]:
            self.scalar(f"train/{k}", row[k], row["step"])

    def evaluation(self, row: dict[str, Any]) -> None:
        """Append an ``eval_row`` to ``eval.csv`` and each of its columns to TensorBoard as ``eval/``."""
        self._append("eval.csv", EVAL_FIELDS, row)
        for k in EVAL_FIELDS[1:]:
            self.scalar(f"eval/{k}", row[k], row["step"])

    def _append(self, name: str, fields: tuple[str, ...], row: dict[str, Any]) -> None:
        with open(self.run_dir / name, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=fields).writerow({k: row.get(k, "") for k in fields})
