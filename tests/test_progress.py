"""Progress lines in a log file: counts as a person reads them."""

from __future__ import annotations

import io

from deck_sim.progress import LineProgress


def test_a_progress_line_prints_whole_counts_in_full():
    out = io.StringIO()
    with LineProgress(total=1_000_000, desc="mddpg deck1", unit="step", file=out) as bar:
        bar.update(2_500_000 // 2)
    line = out.getvalue().strip().splitlines()[-1]
    assert line.startswith("mddpg deck1: 1250000/1000000 step (125 %) in ")
    out = io.StringIO()
    with LineProgress(total=None, unit="s", file=out) as bar:
        bar.update(0.25)
    assert out.getvalue().startswith(": 0.25 s in ")
