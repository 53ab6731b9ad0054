"""Helpers of the training tests that compare run folders: CSV logs without their wall-clock columns, exported
actor arrays, and whole runs."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from training.loop import Trainer


def csv_rows(path: Path) -> list[dict[str, str]]:
    """A CSV log's rows without the columns that depend on the wall clock (``wall_s``, ``sps``)."""
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in ("wall_s", "sps")} for r in csv.DictReader(f)]


def actor_arrays(run_dir: Path) -> dict[str, np.ndarray]:
    """The weights of a run's ``actor.npz`` (its ``meta`` record left out)."""
    with np.load(run_dir / "actor.npz", allow_pickle=False) as d:
        return {k: d[k] for k in d.files if k != "meta"}


def assert_same_run(a: Trainer, b: Trainer) -> None:
    """Same logged losses and statistics, same exported actor, same replay content (actions and observations)."""
    assert csv_rows(a.run_dir / "progress.csv") == csv_rows(b.run_dir / "progress.csv")
    for k, v in actor_arrays(a.run_dir).items():
        np.testing.assert_array_equal(v, actor_arrays(b.run_dir)[k], err_msg=k)
    for name in ("action", "obs"):
        rows_a, rows_b = getattr(a.buffer, name)[: a.buffer.size], getattr(b.buffer, name)[: b.buffer.size]
        np.testing.assert_array_equal(rows_a, rows_b, err_msg=name)
