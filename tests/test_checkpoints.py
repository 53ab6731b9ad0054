"""Checkpoints and exact resume: a stopped and resumed run equals an unbroken one (also when resumed from the
previous checkpoint after a damaged one), an old checkpoint resumes with the new fields' defaults, bad checkpoints
give clear errors, and ``--resume`` may change only ``RESUMABLE_CHANGES``."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import short_config as _short
from training_runs import assert_same_run

from training.loop import CheckpointError, Trainer, load_checkpoint


@pytest.mark.slow
@pytest.mark.parametrize(
    "fields",
    [{"env_worker": True}, {"bc_weight_final": 2.0, "bc_slow_weight": 3.0, "learner_precision": "bfloat16"}],
    ids=["tuned", "schedule-bfloat16"],
)
def test_a_stopped_and_resumed_run_equals_an_unbroken_one(tmp_path, fields):
    """A run stopped mid-episode (its environments in the worker process) and resumed equals the unbroken run;
    also with a falling cloning weight, which the resumed run must take up at the step it stopped at (that run's
    updates in bfloat16, its environments inline)."""
    whole = Trainer(_short(**fields), tmp_path / "whole", progress=False)
    whole.train()
    first = Trainer(_short(**fields), tmp_path / "broken", progress=False)
    out = first.train(stop_at=70)  # mid-episode in both environments
    assert out["step"] == 70 and not (tmp_path / "broken" / "actor.npz").exists()
    assert any(len(s.actions) > 0 for s in first.slots)
    resumed = Trainer(_short(**fields), tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)


@pytest.mark.slow
def test_a_checkpoint_from_before_a_new_field_resumes_with_its_default(tmp_path):
    run = tmp_path / "run"
    cfg = _short(total_steps=60, demo_episodes=0, pretrain_updates=0)
    Trainer(cfg, run, progress=False).train(stop_at=40)
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    for key in ("bc_slow_weight", "bc_slow_below", "bc_weight_final", "bc_decay"):  # added after older runs
        del state["config"][key]
    torch.save(state, run / "checkpoint.pt")
    out = Trainer(cfg, run, resume=True, progress=False).train()
    assert out["step"] == 60


@pytest.mark.slow
def test_bad_checkpoints_give_clear_errors(tmp_path):
    run = tmp_path / "run"
    Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, progress=False).train()
    with pytest.raises(CheckpointError, match="already holds a run"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, progress=False)
    with pytest.raises(CheckpointError, match="another configuration.*hidden"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0, hidden=(16,)), run, resume=True)
    data = (run / "checkpoint.pt").read_bytes()
    (run / "checkpoint.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="checkpoint.pt: not a readable checkpoint"):
        load_checkpoint(run / "checkpoint.pt")
    (run / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, resume=True)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        Trainer(_short(), tmp_path / "empty", resume=True)
    assert json.loads((run / "config.json").read_text())["hidden"] == [32, 32]  # what was written survives


@pytest.mark.slow
def test_cli_resume_may_add_polishing_but_no_other_change(tmp_path, capsys):
    from deck_sim.cli import main

    out = tmp_path / "run"
    Trainer(_short(total_steps=60, demo_episodes=0, pretrain_updates=0), out, progress=False).train()
    base = ["train", "--algo", "mddpg", "--out", str(out), "--resume", "--quiet"]
    assert main([*base, "--set", "gamma=0.5"]) == 2
    err = capsys.readouterr().err
    assert "may change only total_steps, polish_epochs, polish_lr, polish_hidden, dagger_steps, not gamma" in err
    assert main([*base, "--set", "polish_epochs=2"]) == 0
    assert load_checkpoint(out / "checkpoint.pt")["polished"] is True


@pytest.mark.slow
def test_a_run_resumed_from_its_previous_checkpoint_equals_an_unbroken_one(tmp_path):
    """A damaged ``checkpoint.pt`` is refused, the message naming ``checkpoint.prev.pt``'s step; moved into its
    place, the previous checkpoint resumes the run exactly (its logs cut back to that step)."""
    whole = Trainer(_short(), tmp_path / "whole", progress=False)
    whole.train()
    run = tmp_path / "broken"
    Trainer(_short(), run, progress=False).train(stop_at=50)
    Trainer(_short(), run, resume=True, progress=False).train(stop_at=70)
    assert load_checkpoint(run / "checkpoint.prev.pt")["step"] == 50
    data = bytearray((run / "checkpoint.pt").read_bytes())
    data[len(data) // 2] ^= 1
    (run / "checkpoint.pt").write_bytes(data)
    with pytest.raises(CheckpointError, match=r"checksum .* previous checkpoint \(step 50\) is intact.*mv "):
        Trainer(_short(), run, resume=True, progress=False)
    (run / "checkpoint.prev.pt").replace(run / "checkpoint.pt")
    resumed = Trainer(_short(), run, resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
