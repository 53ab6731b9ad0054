"""``benchmarks/collisions.py``: each collision classified by what was hit, whether a mover was moving and coming at
the aircraft, and where it lay; the counts agree with the evaluation harness on the same held-out episodes."""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.evaluation import EvalConfig, evaluate

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("collisions", ROOT / "benchmarks" / "collisions.py")
sys.path.insert(0, str(ROOT / "benchmarks"))
collisions = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(collisions)


def test_a_collision_is_static_standing_or_moving_and_lies_ahead_beside_or_behind():
    at = np.zeros(2)
    assert collisions.classify(None, None, at, 0.0, 0.5, 0.3) == ("static", False, "")
    # a mover 10 m ahead driving at the aircraft at 2 m/s; the same one driving away; one standing behind
    assert collisions.classify(np.array([11.0, 0.0]), np.array([10.0, 0.0]), at, 0.0, 0.5, 0.3) == \
        ("moving", True, "ahead")
    assert collisions.classify(np.array([9.0, 0.0]), np.array([10.0, 0.0]), at, 0.0, 0.5, 0.3) == \
        ("moving", False, "ahead")
    assert collisions.classify(np.array([-10.0, 0.0]), np.array([-10.05, 0.0]), at, 0.0, 0.5, 0.3) == \
        ("standing", False, "behind")
    # crossing the aircraft's path beside it (heading north, the mover to its east, driving north)
    assert collisions.classify(np.array([5.0, -1.0]), np.array([5.0, 0.0]), at, math.pi / 2, 0.5, 0.3) == \
        ("moving", False, "beside")


@given(
    before=st.tuples(st.floats(-30, 30), st.floats(-30, 30)),
    after=st.tuples(st.floats(-30, 30), st.floats(-30, 30)),
    heading=st.floats(-math.pi, math.pi),
    turn=st.floats(-math.pi, math.pi),
)
def test_turning_the_whole_scene_changes_no_classification(before, after, heading, turn):
    before, after = np.array(before), np.array(after)
    if np.linalg.norm(after) < 1e-3:  # (a mover on the aircraft's centre has no bearing)
        return
    c, s = math.cos(turn), math.sin(turn)
    rot = np.array([[c, -s], [s, c]])
    a = collisions.classify(before, after, np.zeros(2), heading, 0.5, 0.3)
    b = collisions.classify(rot @ before, rot @ after, np.zeros(2), heading + turn, 0.5, 0.3)
    assert a[:2] == b[:2]
    # (a bearing on the 45-degree borders may round either way)
    off = abs((math.atan2(after[1], after[0]) - heading + math.pi) % (2 * math.pi) - math.pi)
    if min(abs(off - math.pi / 4), abs(off - 3 * math.pi / 4)) > 1e-6:
        assert a[2] == b[2]


def test_the_table_counts_the_collisions_the_harness_finds_on_the_same_episodes():
    """The shipped reward-alone MDDPG on the first 8 held-out episodes of deck 1: one collision, with the taxiing
    aircraft."""
    harness = evaluate(EvalConfig(agents=("mddpg-reward",), scenes=("deck1",), episodes=8, workers=1, record="none"))
    hit = [r["collision_partner"] for r in harness.episodes if r["outcome"] == "collision"]
    assert hit == ["taxiing_0"]
    done = subprocess.run(
        [sys.executable, "benchmarks/collisions.py", "--policies", "mddpg-reward", "--episodes", "8"],
        cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable"}, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr
    row = next(line for line in done.stdout.splitlines() if line.startswith("| mddpg-reward |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "reward" and cells[2] == "8" and cells[3] == "1" and cells[11] == "taxiing 1"
    static, standing, moving = (int(c) for c in cells[4:7])
    assert static == 0 and standing + moving == 1 and sum(int(c) for c in cells[8:11]) == 1
    bad = subprocess.run([sys.executable, "benchmarks/collisions.py", "--policies", "nobody", "--episodes", "1"],
                         cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable"}, capture_output=True, text=True,
                         timeout=600)
    assert bad.returncode != 0 and "unknown policy 'nobody'" in bad.stderr and "Traceback" not in bad.stderr
