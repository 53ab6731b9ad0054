"""Training backends (``training.runners``, ``training.ray_backend``): worker processes and Ray actors that each step
and act for a group of the environments give the same run, bit for bit, for the same worker count; a Ray run is
reproducible and resumes exactly; bad backend options are refused in one line before anything is written."""

from __future__ import annotations

import os

import pytest
from conftest import short_config as _short
from training_runs import assert_same_run

from deck_sim.cli import main
from training.checkpoints import CheckpointError
from training.config import ConfigError
from training.loop import Trainer
from training.runners import groups

SHORT = {"total_steps": 80, "eval_every": 40, "checkpoint_every": 40}


@pytest.fixture(scope="session")
def ray_session():  # noqa: ANN201
    """One local Ray of 2 CPUs for the module's Ray tests (skipped where Ray is not installed)."""
    ray = pytest.importorskip("ray", reason="the Ray backend needs Ray: pip install 'deck-sim[ray]'")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    if started:
        ray.shutdown()


def _run(path, **runner) -> Trainer:  # noqa: ANN001
    trainer = Trainer(_short(**SHORT), path, progress=False, **runner)
    try:
        trainer.train()
    finally:
        trainer.close()
    return trainer


@pytest.fixture(scope="module")
def local_two(tmp_path_factory) -> Trainer:  # noqa: ANN001
    """A short run whose two environments step in two worker processes."""
    return _run(tmp_path_factory.mktemp("local2"), workers=2)


def test_groups_are_contiguous_and_balanced():
    assert groups(8, 3) == [range(0, 3), range(3, 6), range(6, 8)]
    assert groups(2, 1) == [range(0, 2)]
    with pytest.raises(ValueError, match="workers"):
        groups(2, 3)


@pytest.mark.slow
def test_ray_runs_are_reproducible_and_equal_the_local_workers(ray_session, local_two, tmp_path):
    """A Ray run of two actors gives the same numbers as two local worker processes (as does a resumed Ray run,
    below: two Ray runs agree through them); one Ray actor gives the inline run's."""
    a = _run(tmp_path / "ray_a", backend="ray", workers=2)
    assert_same_run(a, local_two)
    assert (a.run_dir / "eval.csv").read_text().count("\n") == 4  # step 0 (demonstrations), 40, 80 and the header
    assert any((a.run_dir / "tb").iterdir())
    assert_same_run(_run(tmp_path / "ray_1", backend="ray", workers=1), _run(tmp_path / "inline", workers=0))


@pytest.mark.slow
def test_a_resumed_ray_run_equals_an_unbroken_one(ray_session, local_two, tmp_path):
    first = Trainer(_short(**SHORT), tmp_path / "broken", progress=False, backend="ray", workers=2)
    try:
        assert first.train(stop_at=50)["step"] == 50
    finally:
        first.close()
    assert any(len(s.actions) > 0 for s in first.slots)  # mid-episode: the resume replays it in its actor
    resumed = _run(tmp_path / "broken", resume=True, backend="ray")  # the count of groups comes from the checkpoint
    assert resumed.workers == 2
    assert_same_run(resumed, local_two)


@pytest.mark.slow
def test_a_run_resumes_only_in_as_many_groups_as_it_acted_in(local_two, tmp_path):
    with pytest.raises(CheckpointError, match="resume it with --workers 2"):
        Trainer(_short(**SHORT), local_two.run_dir, resume=True, progress=False, workers=1)
    with pytest.raises(ConfigError, match="workers: at most num_envs"):
        Trainer(_short(**SHORT), tmp_path / "three", progress=False, workers=3)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--workers", "0"], "--workers must be at least 1, got 0"),
        (["--ray-address", "127.0.0.1:1"], "--ray-address needs --backend ray"),
        (["--backend", "ray", "--ray-address", "127.0.0.1:1"], "no Ray cluster answers there"),
        (["--algo", "dqn", "--workers", "2"], "--backend and --workers apply to mddpg and ddpg"),
    ],
)
def test_bad_backend_options_are_refused_in_one_line_before_anything_is_written(tmp_path, capsys, options, message):
    if "--backend" in options:
        pytest.importorskip("ray", reason="the Ray backend needs Ray: pip install 'deck-sim[ray]'")
    out = tmp_path / "run"
    assert main(["train", "--steps", "40", "--out", str(out), "--quiet", *options]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_the_ray_backend_without_ray_names_the_install_command(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "ray", None)  # import ray raises ImportError
    assert main(["train", "--steps", "40", "--out", str(tmp_path / "run"), "--quiet", "--backend", "ray"]) == 2
    err = capsys.readouterr().err.strip()
    assert "pip install 'deck-sim[ray]'" in err and len(err.splitlines()) == 1, err


@pytest.mark.slow
def test_an_unreachable_ray_address_is_refused_while_this_process_holds_a_ray(ray_session):
    """An address given while the process is already connected to a Ray is still checked: no silent use of the
    Ray it holds instead."""
    from deck_sim.evaluation import EvalError
    from deck_sim.evaluation.harness import init_ray

    assert ray_session.is_initialized()
    with pytest.raises(EvalError, match="no Ray cluster answers there"):
        init_ray(1, "127.0.0.1:9")
    assert ray_session.is_initialized()
