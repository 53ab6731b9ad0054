"""``benchmarks/saturation.py``: the actor's pre-tanh action read from a run's checkpoint and from an actor file,
and the critic's gradient through tanh."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import short_config

from deck_sim.policies import load_actor
from training.loop import Trainer

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("saturation", ROOT / "benchmarks" / "saturation.py")
sys.path.insert(0, str(ROOT / "benchmarks"))
saturation = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(saturation)


def _reward_run(tmp_path: Path, algo: str, steps: int) -> Path:
    """A seconds-long run without a teacher in ``tmp_path/run``, its checkpoint and actor written."""
    cfg = short_config(algo=algo, total_steps=steps, num_envs=2, demo_episodes=0, pretrain_updates=0, bc_weight=0.0,
                       expert_relabel=False)
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    trainer.train()
    trainer.close()
    return tmp_path / "run"


def test_the_shares_count_each_component_past_three_and_ten():
    u = np.array([[0.5, -12.0], [-4.0, 2.0], [20.0, -1.0], [1.0, 3.5]])
    s = saturation.shares(u)
    np.testing.assert_allclose(s["median"], [2.5, 2.75])
    np.testing.assert_allclose(s["over3"], [0.5, 0.5])
    np.testing.assert_allclose(s["over10"], [0.25, 0.25])


def test_a_runs_checkpoint_and_its_actor_file_are_read_and_a_missing_one_is_named(tmp_path):
    run = _reward_run(tmp_path, "mddpg", 300)
    policy = load_actor(run / "actor.npz")
    x = np.random.default_rng(0).normal(0.0, 30.0, size=(20, len(policy.norm_mean)))
    np.testing.assert_allclose(np.tanh(saturation.preactivation(policy, x)), policy.act_flat(x), atol=1e-12)
    (tmp_path / "empty").mkdir()
    done = subprocess.run(
        [sys.executable, "benchmarks/saturation.py", str(run), str(run / "actor.npz"), str(tmp_path / "empty"),
         str(tmp_path / "missing.npz"), "deck_sim/trained/deck1_mddpg.npz", "deck_sim/trained/deck1_dqn-reward.npz",
         "--samples", "50", "--episodes", "1", "--max-steps", "4"],
        cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}, capture_output=True,
        text=True, timeout=300,
    )
    assert done.returncode == 1
    assert f"{tmp_path / 'empty'}: no checkpoint.pt" in done.stderr
    assert f"{tmp_path / 'missing.npz'}: no such run folder or actor file" in done.stderr
    # a set actor (the taught deck 1 MDDPG) and a stable-baselines3 agent: refused by name, the others still read
    assert "deck1_mddpg.npz, member 0: not an MLP actor with a tanh head" in done.stderr
    assert "deck1_dqn-reward.npz: not an MLP actor with a tanh head" in done.stderr
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.strip("|").split("|")]
            for line in done.stdout.splitlines() if line.startswith("| run") or line.startswith("| actor.npz")}
    ckpt, actor = rows["run"], rows["actor.npz member 0"]
    assert ckpt[1] == "300" and ckpt[2] == "50" and actor[2] == "4"
    for cells in (ckpt, actor):
        assert len(cells) == 8
        assert all(0 <= float(v.rstrip("%")) <= 100 for col in (4, 5) for v in cells[col].split(" / "))
    assert all(float(v) >= 0.0 for col in (6, 7) for v in ckpt[col].split(" / "))
    assert actor[6] == actor[7] == "-"


def test_the_gradient_reaching_u_is_the_critics_gradient_times_tanhs_derivative(tmp_path):
    run = _reward_run(tmp_path, "ddpg", 200)
    r = saturation.run_saturation(run, samples=60)
    assert r["steps"] == 200 and r["states"] == 60
    assert np.all(r["dq_du"] <= r["dq_da"] + 1e-12) and np.all(r["dq_da"] > 0.0)
    assert np.all((0.0 <= r["over10"]) & (r["over10"] <= r["over3"]) & (r["over3"] <= 1.0))
