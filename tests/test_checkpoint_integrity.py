"""Damaged checkpoints and contradicting resumes are refused in one line: each checkpoint carries its SHA-256 and
the one before it is kept (``checkpoint.prev.pt``), any corruption of the file raises ``CheckpointError`` naming it
(never a torch, pickle or zip error), a checkpoint without a checksum still loads with one warning, and
``deck-sim train --resume`` exits 2 naming each option that contradicts the saved run, or a budget below the steps
it has done, before anything is written. The same for DQN and A2C run folders."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import short_config
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from training.checkpoints import CHECKSUM_TAG, CheckpointError, load_checkpoint
from training.loop import Trainer

STOP, PREVIOUS_STEP, TOTAL = 15, 10, 30


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A DDPG run of ``TOTAL`` steps stopped at step ``STOP``: ``checkpoint.pt`` at ``STOP``,
    ``checkpoint.prev.pt`` at ``PREVIOUS_STEP``."""
    out = tmp_path_factory.mktemp("integrity") / "run"
    cfg = short_config(
        algo="ddpg", total_steps=TOTAL, num_envs=1, env_worker=False, demo_episodes=0, pretrain_updates=0,
        learning_starts=5, batch_size=8, log_every=5, checkpoint_every=PREVIOUS_STEP,
    )
    trainer = Trainer(cfg, out, progress=False)
    trainer.train(stop_at=STOP)
    trainer.close()
    return out


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder for the property tests' damaged files (hypothesis runs many examples per test call)."""
    return tmp_path_factory.mktemp("damaged")


def _copy(run: Path, where: Path) -> Path:
    copy = where / "run"
    shutil.copytree(run, copy)
    return copy


def _without_checksum(data: bytes) -> bytes:
    """A checkpoint's bytes as ``torch.save`` alone writes them: the zip comment cut off, its length 0 again."""
    size = len(CHECKSUM_TAG) + 64
    return data[: -size - 2] + b"\0\0"


def _corruptions() -> st.SearchStrategy:
    flips = st.lists(st.integers(min_value=0), min_size=1, max_size=3).map(lambda ks: ("flip", ks))
    cuts = st.integers(min_value=0).map(lambda k: ("truncate", k))
    junk = st.binary(max_size=4096).map(lambda b: ("random", b))
    spans = st.tuples(st.integers(min_value=0), st.binary(min_size=1, max_size=64)).map(lambda t: ("overwrite", t))
    return st.one_of(flips, cuts, junk, spans, st.just(("empty", None)))


def _corrupt(data: bytes, how: tuple) -> bytes:
    kind, arg = how
    if kind == "flip":  # each bit once (a bit flipped twice would be no flip)
        out = bytearray(data)
        for bit in {k % (8 * len(data)) for k in arg}:
            out[bit // 8] ^= 1 << (bit % 8)
        return bytes(out)
    if kind == "truncate":
        return data[: arg % len(data)]
    if kind == "random":
        return arg
    if kind == "overwrite":
        at, chunk = arg[0] % len(data), arg[1]
        return data[:at] + chunk + data[at + len(chunk) :]
    return b""


def _one_line_naming(err: BaseException, path: Path) -> None:
    text = str(err)
    assert "\n" not in text and text.startswith(str(path)), text


def test_each_checkpoint_carries_its_checksum_and_the_one_before_is_kept(run):
    data = (run / "checkpoint.pt").read_bytes()
    comment = data[-(len(CHECKSUM_TAG) + 64) :]
    assert comment.startswith(CHECKSUM_TAG)
    assert hashlib.sha256(_without_checksum(data)).hexdigest().encode() == comment[len(CHECKSUM_TAG) :]
    assert torch.load(run / "checkpoint.pt", weights_only=True)["step"] == STOP  # torch reads it as it is
    assert load_checkpoint(run / "checkpoint.pt")["step"] == STOP
    assert load_checkpoint(run / "checkpoint.prev.pt")["step"] == PREVIOUS_STEP
    assert not list(run.glob("*.tmp"))


def test_a_save_stopped_before_its_last_rename_leaves_the_checkpoint_it_was_replacing(run, tmp_path, monkeypatch):
    """A Ctrl-C (or a crash) between keeping the old checkpoint as ``checkpoint.prev.pt`` and putting the new one
    in place: ``checkpoint.pt`` is still there, the old one, and so is the new one's temporary file."""
    from training import checkpoints

    copy = _copy(run, tmp_path)
    real = checkpoints.os.replace

    def stopped_at_the_last_rename(src, dst):  # noqa: ANN001, ANN202
        if Path(dst).name == "checkpoint.pt":
            raise KeyboardInterrupt
        return real(src, dst)

    monkeypatch.setattr(checkpoints.os, "replace", stopped_at_the_last_rename)
    with pytest.raises(KeyboardInterrupt):
        checkpoints._write({"step": 99}, copy / "checkpoint.pt")
    monkeypatch.undo()
    assert load_checkpoint(copy / "checkpoint.pt")["step"] == STOP
    assert load_checkpoint(copy / "checkpoint.prev.pt")["step"] == STOP


def test_a_checkpoint_without_a_checksum_loads_with_one_warning(run, tmp_path, caplog):
    """The format of a plain ``torch.save``: run folders holding one keep resuming."""
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(_without_checksum((run / "checkpoint.pt").read_bytes()))
    signed = load_checkpoint(run / "checkpoint.pt")
    with caplog.at_level(logging.WARNING, logger="training.checkpoints"):
        plain = load_checkpoint(path)
        load_checkpoint(path)  # a resume reads it twice (its plan, then the trainer): warned once
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "\n" not in warnings[0] and str(path) in warnings[0]
    assert "without a checksum" in warnings[0]
    assert plain["step"] == signed["step"] == STOP
    assert torch.equal(plain["buffer"]["obs"], signed["buffer"]["obs"])
    assert torch.equal(plain["torch_rng"], signed["torch_rng"])
    for name, tensor in signed["agent"]["actor"].items():
        assert torch.equal(plain["agent"]["actor"][name], tensor), name


def test_eighty_single_bit_flips_spread_over_the_file_are_all_refused(run, tmp_path):
    data = (run / "checkpoint.pt").read_bytes()
    path = tmp_path / "checkpoint.pt"
    for i in range(80):
        bit = (i * 8 * len(data)) // 80 + i % 8
        damaged = bytearray(data)
        damaged[bit // 8] ^= 1 << (bit % 8)
        path.write_bytes(damaged)
        with pytest.raises(CheckpointError, match="not a readable checkpoint") as err:
            load_checkpoint(path)
        _one_line_naming(err.value, path)


@settings(max_examples=80, deadline=None)
@given(how=_corruptions())
def test_a_corrupted_checkpoint_raises_only_a_checkpoint_error(run, scratch, how):
    data = (run / "checkpoint.pt").read_bytes()
    damaged = _corrupt(data, how)
    assume(damaged != data)
    path = scratch / "checkpoint.pt"
    path.write_bytes(damaged)
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(path)
    _one_line_naming(err.value, path)


@settings(max_examples=30, deadline=None)
@given(how=_corruptions())
def test_a_corrupted_checkpoint_without_a_checksum_loads_or_raises_a_checkpoint_error(run, scratch, how):
    """Without a checksum a damaged tensor cannot be told from a good one; still, torch's own errors never
    pass through."""
    damaged = _corrupt(_without_checksum((run / "checkpoint.pt").read_bytes()), how)
    path = scratch / "plain.pt"
    path.write_bytes(damaged)
    try:
        assert isinstance(load_checkpoint(path), dict)
    except CheckpointError as err:
        _one_line_naming(err, path)


def test_random_bytes_and_an_empty_file_are_not_deck_sim_checkpoints(tmp_path):
    path = tmp_path / "checkpoint.pt"
    for data, detail in ((bytes(range(256)) * 8, "no checkpoint record at its end"), (b"", "an empty file")):
        path.write_bytes(data)
        with pytest.raises(CheckpointError, match=f"not a deck_sim training checkpoint \\({detail}") as err:
            load_checkpoint(path)
        _one_line_naming(err.value, path)


def _resume(out: Path, *options: str) -> list[str]:
    return ["train", "--out", str(out), "--resume", "--quiet", *options]


@pytest.mark.parametrize(
    "how",
    [("flip", [8 * 5000 + 3]), ("truncate", 40_000), ("random", b"\x80\x02}q"), ("empty", None)],
    ids=["bit-flip", "truncated", "random-bytes", "empty"],
)
def test_cli_resume_from_a_damaged_checkpoint_exits_2_in_one_line_naming_the_previous_one(run, tmp_path, capsys, how):
    from deck_sim.cli import main

    out = _copy(run, tmp_path)
    path = out / "checkpoint.pt"
    path.write_bytes(_corrupt(path.read_bytes(), how))
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(_resume(out)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"deck-sim train: error: {path}: not a readable checkpoint"), err
    assert f"the previous checkpoint (step {PREVIOUS_STEP}) is intact: to resume from it, mv " in err
    assert before == {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}  # nothing written


def test_cli_resume_refuses_options_that_contradict_the_run_before_writing(run, tmp_path, capsys):
    from deck_sim.cli import main

    out = _copy(run, tmp_path)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(_resume(out, "--algo", "mddpg", "--scene", "deck2", "--seed", "3", "--preset", "paper")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    for wrong in ("--algo mddpg (the run's algo: ddpg)", "--scene deck2 (the run's scene: deck1)",
                  "--seed 3 (the run's seed: 0)", "--preset paper (the run's preset: tuned)"):
        assert wrong in err
    assert main(_resume(out, "--recipe", "deck1")) == 2
    assert "--recipe deck1 (the run's recipe: none) contradicts it" in capsys.readouterr().err
    assert main(_resume(out, "--steps", str(STOP - 3))) == 2
    err = capsys.readouterr().err
    assert f"the run has done {STOP} steps; a budget of {STOP - 3} steps (total_steps, --steps) is below that" in err
    assert before == {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(_resume(out, "--algo", "ddpg", "--scene", "deck1", "--seed", "0", "--preset", "tuned",
                        "--print-config")) == 0  # the run's own values are fine
    assert json.loads(capsys.readouterr().out)["total_steps"] == TOTAL


def test_a_trainer_refuses_a_budget_below_the_steps_done(run, tmp_path):
    out = _copy(run, tmp_path)
    config = json.loads((out / "config.json").read_text())
    from training.config import TrainConfig

    cfg = TrainConfig.from_dict({**config, "total_steps": STOP - 5})
    with pytest.raises(CheckpointError, match=f"has done {STOP} steps; a budget of {STOP - 5} steps"):
        Trainer(cfg, out, resume=True, progress=False)
    assert json.loads((out / "config.json").read_text())["total_steps"] == TOTAL


@pytest.mark.slow
def test_cli_resumes_from_the_previous_checkpoint_once_moved_and_prints_the_runs_labels(run, tmp_path, capsys):
    from deck_sim.cli import main

    out = _copy(run, tmp_path)
    (out / "checkpoint.pt").write_bytes(b"garbage")
    assert main(_resume(out)) == 2
    capsys.readouterr()
    (out / "checkpoint.prev.pt").replace(out / "checkpoint.pt")  # the mv the message gives
    assert main(_resume(out)) == 0  # no --algo: the run's own (ddpg), not mddpg
    printed = capsys.readouterr().out
    assert printed.startswith(f"ddpg on deck1: {TOTAL} steps"), printed
    assert load_checkpoint(out / "checkpoint.pt")["step"] == TOTAL


@pytest.mark.slow
def test_the_console_script_prints_one_line_for_a_damaged_checkpoint(run, tmp_path):
    out = _copy(run, tmp_path)
    (out / "checkpoint.pt").write_bytes(bytes(range(256)) * 64)
    deck_sim = Path(sys.executable).with_name("deck-sim")
    done = subprocess.run([str(deck_sim), *_resume(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert "not a deck_sim training checkpoint" in done.stderr and str(out / "checkpoint.pt") in done.stderr


# -- DQN and A2C run folders --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dqn_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 32-step DQN run."""
    from training.baselines import train_baseline

    out = tmp_path_factory.mktemp("dqn") / "run"
    train_baseline("dqn", "deck1", 32, 0, out, progress=False, eval_every=0, eval_episodes=1, learning_starts=20,
                   buffer_size=1000)
    return out


@pytest.mark.slow
def test_cli_resume_of_a_dqn_run_refuses_contradictions_a_lower_budget_and_damaged_files(dqn_run, tmp_path, capsys):
    from deck_sim.cli import main

    out = _copy(dqn_run, tmp_path)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(_resume(out, "--scene", "deck2", "--seed", "1", "--algo", "a2c")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    for wrong in ("--algo a2c (the run's algo: dqn)", "--scene deck2 (the run's scene: deck1)",
                  "--seed 1 (the run's seed: 0)"):
        assert wrong in err
    assert main(_resume(out, "--recipe", "deck2")) == 2
    assert "--recipe deck2 (the run's scene: deck1) contradicts it" in capsys.readouterr().err
    assert main(_resume(out, "--set", "learning_rate=0.5")) == 2
    assert "learning_rate: the run's 0.0001, given 0.5" in capsys.readouterr().err
    assert main(_resume(out, "--steps", "16")) == 2
    assert "the run has done 32 steps; a budget of 16 steps" in capsys.readouterr().err
    assert before == {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    (out / "model.zip").write_bytes(bytes(range(256)) * 8)
    assert main(_resume(out, "--steps", "48")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / 'model.zip'}: not a readable dqn model" in err


@pytest.mark.slow
def test_a_resumed_dqn_run_keeps_its_config_and_prints_its_labels(dqn_run, tmp_path, capsys):
    from deck_sim.cli import main
    from training.baselines import train_baseline
    from training.config import ConfigError

    out = _copy(dqn_run, tmp_path)
    with pytest.raises(ConfigError, match="scene: the run's 'deck1', given 'deck2'"):
        train_baseline("dqn", "deck2", 48, 0, out, resume=True, progress=False)
    with pytest.raises(ConfigError, match="algo: the run in .* is a dqn run, not a2c"):
        train_baseline("a2c", "deck1", 48, 0, out, resume=True, progress=False)
    assert main(_resume(out, "--print-config")) == 0  # no --steps: the run's own budget, not the default's
    shown = json.loads(capsys.readouterr().out)
    assert shown["total_steps"] == 32 and shown["buffer_size"] == 1000 and shown["eval_episodes"] == 1
    assert main(_resume(out, "--steps", "48")) == 0
    assert capsys.readouterr().out.startswith("dqn on deck1: 48 steps")
