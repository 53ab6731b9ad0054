"""``benchmarks/forecast_use.py``: a shipped MDDPG actor fed another predictor's forecast on the same held-out
episodes, its difference paired by episode; an actor without a forecast and an unknown predictor refused by name."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}
TRAINED = ROOT / "deck_sim" / "trained"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "benchmarks/forecast_use.py", *args], cwd=ROOT, env=ENV,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_an_mddpg_actor_is_measured_with_its_own_and_a_swapped_forecast_on_the_same_episodes():
    done = _run("--actors", str(TRAINED / "deck1_mddpg-reward.npz"), "--episodes", "3",
                "--predictors", "constant_velocity,mpc", "--workers", "1")
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "trained with mpc): 3 held-out episodes" in out
    own = re.search(r"^  mpc +success +([\d.]+)%", out, re.M)
    swapped = re.search(r"^  constant_velocity +success +([\d.]+)%.*; minus mpc: ([+-][\d.]+) points", out, re.M)
    assert own and swapped, out
    assert float(swapped.group(2)) == pytest.approx(float(swapped.group(1)) - float(own.group(1)), abs=0.1)
    assert out.index("  mpc ") < out.index("  constant_velocity ")  # the actor's own forecast first


def test_an_actor_without_a_forecast_and_an_unknown_predictor_are_refused_by_name():
    ddpg = _run("--actors", str(TRAINED / "deck1_ddpg-reward.npz"), "--episodes", "3")
    assert ddpg.returncode == 1 and "was trained without a forecast (DDPG)" in ddpg.stderr
    bad = _run("--actors", str(TRAINED / "deck1_mddpg-reward.npz"), "--predictors", "crystal_ball")
    assert bad.returncode == 1 and "--predictors: expected names of" in bad.stderr and "crystal_ball" in bad.stderr
