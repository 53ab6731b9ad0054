"""``benchmarks/learning.py``'s report: per-arm success with its interval over seeds, and the prediction ablation
(MDDPG minus DDPG, paired by seed), read from run folders without training (``--no-train``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEADER = "step,wall_s,episodes,success,collision,timeout,off_surface,reward\n"


@pytest.fixture()
def learning(monkeypatch):  # noqa: ANN201
    """``benchmarks/learning.py`` as a module, its commands run in this process (those that test Ctrl-C, or train
    in processes of their own, run as commands below), which keeps its own SIGINT handler."""
    import importlib.util

    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    for name, value in (("MUJOCO_GL", "disable"), ("OMP_NUM_THREADS", "1")):  # (the script sets them if unset)
        monkeypatch.setenv(name, os.environ.get(name, value))
    spec = importlib.util.spec_from_file_location("learning_report", ROOT / "benchmarks" / "learning.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "hear_ctrl_c", lambda: None)
    return module


def _report(learning, capsys, *args: str) -> str:  # noqa: ANN001
    """What ``learning.py *args`` prints (it must succeed)."""
    learning.main(list(args))
    return capsys.readouterr().out


def _run_folder(out: Path, name: str, successes: list[float]) -> None:
    run = out / name
    run.mkdir(parents=True)
    rows = [f"{50_000 * (i + 1)},{60.0 * (i + 1)},100,{s},{1 - s},0.0,0.0,{100 * s}\n" for i, s in enumerate(successes)]
    (run / "eval.csv").write_text(HEADER + "".join(rows))


def test_the_report_gives_intervals_over_seeds_and_the_paired_prediction_difference(tmp_path, learning, capsys):
    for seed, (m, d, q) in enumerate([(0.6, 0.5, 0.2), (0.7, 0.5, 0.3), (0.8, 0.6, 0.1)]):
        _run_folder(tmp_path, f"deck1-reward-mddpg-seed{seed}", [0.1, m])
        _run_folder(tmp_path, f"deck1-reward-ddpg-seed{seed}", [0.1, d])
        _run_folder(tmp_path, f"deck1-reward-dqn-seed{seed}", [0.1, q])
    out = _report(learning, capsys, "--recipe", "deck1-reward", "--no-train", "--out", str(tmp_path))
    assert "unfinished runs, reported at their latest evaluation: deck1-reward-mddpg-seed0 (at step 100000)" in out
    # mean 70 %, sd 10 points, t(2) = 4.303: 70 +- 24.8
    assert "| mddpg | 3 | 100000 | 2.0 min | 100 | 70.0 % | 45.2 to 94.8 % | 30.0 % |" in out
    # differences 10, 20, 20 points: mean 16.7, sd 5.77, half-width 14.3
    assert "mddpg - ddpg: success +16.7 points, paired over seeds 0, 1, 2 (95 % interval +2.3 to +31.0 points)" in out
    # the paper's ranking, neighbour by neighbour (A2C has no run here): DDPG - DQN = 30, 20, 50 points
    assert "ddpg - dqn: success +33.3 points, paired over seeds 0, 1, 2 (95 % interval -4.6 to +71.3 points)" in out
    assert "a2c" not in out.split("| arm |")[1]
    assert (tmp_path / "learning_deck1-reward.png").stat().st_size > 0


def test_shipped_logs_give_the_documented_tables_of_runs_that_finished_elsewhere(tmp_path, learning, capsys):
    """``--shipped`` reads each seed whose run folder is not here from the logs shipped beside the recipe's agent:
    deck 1's reward-alone recipe, whose twelve runs no checkout holds, prints the tables of docs/benchmarks.md; a
    seed with a run of its own here, or another budget, is not read from them."""

    def report(*extra: str) -> str:
        return _report(learning, capsys, "--recipe", "deck1-reward", "--no-train", "--shipped", "--out",
                       str(tmp_path), *extra)

    out = report()
    assert "deck1-reward-a2c-seed2: read from the shipped logs" in out and "unfinished" not in out
    rows = [line for line in out.splitlines() if line.startswith(("| mddpg", "| ddpg", "| dqn", "| a2c", "mddpg -",
                                                                  "ddpg -", "dqn -"))]
    assert len(rows) == 4 + 3 + 4 + 3
    documented = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    assert [row for row in rows if row not in documented] == []
    (tmp_path / "deck1-reward-mddpg-seed0").mkdir()
    (tmp_path / "deck1-reward-mddpg-seed0" / "checkpoint.pt").write_bytes(b"")  # a run of its own, under way
    out = report("--arms", "mddpg")
    assert "deck1-reward-mddpg-seed0: read from" not in out and "| mddpg | 2 |" in out
    assert "was trained with other total_steps; not read" in report("--arms", "ddpg", "--steps", "300000")
    assert "no shipped heldout_400.json of these episodes; left out" in report("--arms", "a2c", "--held-out", "400")
    with pytest.raises(SystemExit, match="--shipped reads the logs shipped with a recipe's agents"):
        learning.main(["--scene", "deck1", "--no-train", "--shipped", "--out", str(tmp_path)])


def test_unknown_recipe_is_refused_by_name(tmp_path, learning):
    with pytest.raises(SystemExit, match="unknown recipe 'harbour'"):
        learning.main(["--recipe", "harbour", "--no-train", "--out", str(tmp_path)])


def _learning(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "benchmarks/learning.py", *args], cwd=ROOT, env=ENV,
                          capture_output=True, text=True, timeout=600)


def test_jobs_train_runs_in_parallel_processes_with_the_same_numbers_and_name_a_failed_run(tmp_path, learning, capsys):
    """A run trained in its own process (``--jobs 2``) gives the numbers of the same run trained in the command's
    process; a run that cannot resume (a corrupt checkpoint) fails alone, named with its log, and the other run
    finishes."""
    tiny = ["--steps", "300", "--eval-every", "150", "--eval-episodes", "1"]
    assert "| paper-mddpg | 1 | 300 |" in _report(learning, capsys, "--arms", "paper-mddpg", *tiny, "--out",
                                                       str(tmp_path / "one"))
    bad = tmp_path / "two" / "deck1-paper-ddpg-seed0"
    bad.mkdir(parents=True)
    (bad / "checkpoint.pt").write_bytes(b"not a checkpoint")
    two = _learning("--arms", "paper-ddpg,paper-mddpg", *tiny, "--out", str(tmp_path / "two"), "--jobs", "2")
    assert two.returncode == 1, two.stderr
    assert "training 2 runs, 2 at a time" in two.stdout and "finished deck1-paper-mddpg-seed0 in" in two.stdout
    assert f"runs that failed: {bad} (exit code 1; see {bad}.log)" in two.stderr
    assert "checkpoint" in (tmp_path / "two" / "deck1-paper-ddpg-seed0.log").read_text()
    run = "deck1-paper-mddpg-seed0"
    assert "step 300: held-out success" in (tmp_path / "two" / f"{run}.log").read_text()
    assert (tmp_path / "two" / run / "actor.npz").exists()
    rows = [(tmp_path / out / run / "eval.csv").read_text().splitlines() for out in ("one", "two")]
    # every column but the wall-clock time is the same whichever process trained the run
    assert len(rows[0]) == 3  # (the header and the evaluations at 150 and 300 steps)
    assert [r.split(",")[:1] + r.split(",")[2:] for r in rows[0]] == \
           [r.split(",")[:1] + r.split(",")[2:] for r in rows[1]]


ENV = {**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}


def _ctrl_c(args: list[str], when: Callable[[int], bool], what: str, inherited: signal.Handlers = signal.SIG_DFL,
            twice: bool = False) -> tuple[int, str, str]:
    """Run ``learning.py`` with ``args`` in its own process group (as a terminal's foreground job), started with
    SIGINT ``inherited`` (``SIG_IGN``: as a script's background job), and send the group Ctrl-C once ``when(pid)``
    holds (``what`` names the wait in a failure), again 0.3 s later with ``twice``. Returns its exit code, output
    and error output."""
    proc = subprocess.Popen([sys.executable, "benchmarks/learning.py", *args], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, inherited))
    try:
        deadline = time.monotonic() + 300
        while not when(proc.pid):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, f"{what} within 300 s"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)
        if twice:
            time.sleep(0.3)
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:  # (everything had stopped already)
                pass
        out, err = proc.communicate(timeout=300)
    finally:
        try:  # (whatever of the group is left: a hung worker must not outlive the test)
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return proc.returncode, out, err


def _logged(*runs: Path) -> Callable[[int], bool]:
    """Whether every run has logged its first 1,000 steps (a row of ``progress.csv``)."""
    return lambda pid: all((r / "progress.csv").exists() and len((r / "progress.csv").read_text().splitlines()) > 1
                           for r in runs)


def _children(pid: int, marker: str) -> list[int]:
    """The processes whose parent is ``pid`` and whose command line holds ``marker`` (Linux's /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().decode(errors="replace")
        except (OSError, ValueError):
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and marker in cmdline:
            found.append(int(entry.name))
    return found


@pytest.mark.slow
def test_ctrl_c_stops_every_job_at_a_checkpoint_and_running_again_finishes_them(tmp_path):
    """Started with SIGINT ignored, as a script's background job is, Ctrl-C to the group still stops the command,
    not only its runs (reward-ddpg steps its 8 environments in a worker process, which Ctrl-C reaches too); an
    impatient second Ctrl-C while it waits changes nothing and prints no traceback."""
    args = ["--arms", "reward-ddpg", "--seeds", "0,1", "--steps", "2400", "--eval-every", "1200",
            "--eval-episodes", "1", "--out", str(tmp_path), "--jobs", "2"]
    runs = [tmp_path / f"deck1-reward-ddpg-seed{seed}" for seed in (0, 1)]
    code, out, err = _ctrl_c(args, _logged(*runs), "the runs logged no 1,000 steps", signal.SIG_IGN, twice=True)
    assert code == 130 and "Traceback" not in err, err
    assert "interrupted: waiting for the running runs to stop at their checkpoints" in out
    for run in runs:
        assert f"stopped {run.name} after" in out and "unfinished (run again to resume)" in out
        assert (run / "checkpoint.pt").exists() and not (run / "actor.npz").exists()
    again = _learning(*args)
    assert again.returncode == 0, again.stderr
    for run in runs:
        assert f"-> {run} (resuming)" in again.stdout and f"finished {run.name} in" in again.stdout
        assert (run / "actor.npz").exists()
        assert (run / "eval.csv").read_text().splitlines()[-1].startswith("2400,")


@pytest.mark.slow
def test_a_ctrl_c_while_the_runs_start_stops_them_without_a_failure(tmp_path):
    """The runs' interpreters are still importing when Ctrl-C reaches the group: each takes it once it can (it
    starts with SIGINT blocked), ends as a stopped run, and the same command then trains both."""
    args = ["--arms", "paper-ddpg", "--seeds", "0,1", "--steps", "300", "--eval-every", "150", "--eval-episodes", "1",
            "--out", str(tmp_path), "--jobs", "2"]
    code, out, err = _ctrl_c(args, lambda pid: len(_children(pid, "spawn_main")) >= 2,
                             "the runs' processes did not start")
    assert code == 130 and "Traceback" not in err and "FAILED" not in out, out + err
    assert out.count("unfinished (run again to resume)") == 2
    again = _learning(*args)
    assert again.returncode == 0, again.stderr
    for seed in (0, 1):
        assert (tmp_path / f"deck1-paper-ddpg-seed{seed}" / "actor.npz").exists()


@pytest.mark.slow
def test_ctrl_c_in_one_at_a_time_training_ends_the_command_before_the_next_run(tmp_path):
    args = ["--arms", "paper-ddpg,paper-mddpg", "--steps", "3000", "--eval-every", "1500", "--eval-episodes", "1",
            "--out", str(tmp_path)]
    first = tmp_path / "deck1-paper-ddpg-seed0"
    code, out, err = _ctrl_c(args, _logged(first), "the first run logged no 1,000 steps")
    assert code == 130, err
    assert "stopped deck1-paper-ddpg-seed0, unfinished: run the command again to resume it" in out
    assert (first / "checkpoint.pt").exists() and not (tmp_path / "deck1-paper-mddpg-seed0").exists()


@pytest.mark.slow
@pytest.mark.parametrize("inherited", [signal.SIG_DFL, signal.SIG_IGN], ids=["foreground", "background"])
def test_ctrl_c_during_the_held_out_measurement_ends_the_command_and_names_the_way_on(tmp_path, inherited):
    """A Ctrl-C while the finished runs' actors are measured on the held-out episodes (no training left) ends the
    command with code 130 and a line saying to run it again, not with a traceback, also when it was started with
    SIGINT ignored (a script's background job)."""
    import json

    from deck_sim.policies import TRAINED_DIR, load_actor

    _run_folder(tmp_path, "deck1-planner-ddpg-seed0", [0.9])
    run = tmp_path / "deck1-planner-ddpg-seed0"
    (run / "config.json").write_text(json.dumps({"scene": "deck1", "seed": 0, "total_steps": 50_000}))
    load_actor(TRAINED_DIR / "deck1_ddpg.npz").members[0].save(run / "actor.npz")  # (one actor, as a run writes)
    args = ["--recipe", "deck1-planner", "--arms", "ddpg", "--seeds", "0", "--no-train", "--out", str(tmp_path)]

    def measuring(pid: int) -> bool:  # (the evaluation's worker processes, forked, have started)
        return len(_children(pid, "learning.py")) >= 1

    code, out, err = _ctrl_c(args, measuring, "the held-out measurement did not start", inherited)
    assert code == 130 and "Traceback" not in err, err
    assert "stopped during the held-out measurement: run the command again to go on" in out
    assert not list(run.glob("heldout_*.json"))


def test_the_held_out_difference_adds_the_interval_over_seeds_and_episodes(capsys, learning):
    # three seeds each 5 points apart (85 against 80 of 100 held-out episodes): no width over seeds
    ddpg = [int(i < 80) for i in range(100)]
    mddpg = [int(i < 70 or 80 <= i < 95) for i in range(100)]
    summary = {"mddpg": {"seeds": [0, 1, 2], "success_each": [0.85] * 3, "goal_each": [mddpg] * 3},
               "ddpg": {"seeds": [0, 1, 2], "success_each": [0.80] * 3, "goal_each": [ddpg] * 3}}
    learning.print_differences(summary, ["mddpg", "ddpg"])
    line = capsys.readouterr().out.strip()
    assert line.startswith("mddpg - ddpg: success +5.0 points, paired over seeds 0, 1, 2 (every seed +5.0 points, "
                           "no spread over seeds to give an interval; over seeds and episodes, paired by episode, -")
    # without per-episode records (the seed-500 stream) only the interval over seeds
    for arm in summary.values():
        del arm["goal_each"]
    learning.print_differences(summary, ["mddpg", "ddpg"])
    assert capsys.readouterr().out.strip().endswith(
        "(every seed +5.0 points, no spread over seeds to give an interval)")
