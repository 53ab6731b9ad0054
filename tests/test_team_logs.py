"""Episode logs of several aircraft: every aircraft's frame, path and state, the forecasts of the movers and of the
aircraft, and re-scoring from the log alone that gives the live run's numbers bit for bit; ``deck-sim run`` writes
them and ``deck-sim log info|plot|video|export|recover`` read them."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import astuple

import numpy as np
import pytest

import deck_sim
from deck_sim.policies import make_team_policy, team_policy_overrides
from deck_sim.recording import EpisodeLog, LogError, recover
from deck_sim.rollout import open_recorder, run_team_episode


def _same(a: object, b: object) -> bool:
    """Equal field for field, a NaN equal to a NaN (the makespan of an episode not everyone finished)."""
    def flat(x):  # noqa: ANN001, ANN202
        return [v for v in (astuple(x) if hasattr(x, "__dataclass_fields__") else x)]

    for u, v in zip(flat(a), flat(b), strict=True):
        if isinstance(u, float) and isinstance(v, float) and math.isnan(u) and math.isnan(v):
            continue
        if u != v:
            return False
    return True


@pytest.fixture(scope="module")
def team_log(tmp_path_factory):
    """Three episodes of deck1-multi (three aircraft), the shipped single-aircraft MDDPG acting for each."""
    path = tmp_path_factory.mktemp("team") / "team.mcap"
    overrides = {**team_policy_overrides("mddpg", "deck1-multi"), "agents__count": 3}
    env = deck_sim.load("deck1-multi", seed=12, **overrides)
    policy = make_team_policy("mddpg", env)
    with open_recorder(path, env, seed=12, policy="mddpg", config={"policy": "mddpg"}) as rec:
        live = [run_team_episode(env, policy, episode=k, recorder=rec) for k in range(3)]
    return path, live


def test_rescoring_a_team_log_gives_the_live_numbers_bit_for_bit(team_log):
    path, live = team_log
    log = EpisodeLog(path)
    assert [ep.index for ep in log.episodes] == [0, 1, 2] and all(ep.team and ep.complete for ep in log.episodes)
    for ep, result in zip(log.episodes, live, strict=True):
        again = ep.rescore_team()
        assert _same(again, result), (again, result)
        for a, b in zip(again.aircraft, result.aircraft, strict=True):
            assert _same(a, b)
        assert len(ep.team_steps) == max(r.steps for r in result.aircraft) + 1
        for name, r in zip(ep.scene.agent_names, result.aircraft, strict=True):  # per aircraft
            assert _same(log.rescore(ep.index, aircraft=name).result, r)
        assert _same(log.rescore_team(ep.index), result)
        with pytest.raises(LogError, match="name one to score"):
            ep.rescore()
    outcomes = {r.outcome for team in live for r in team.aircraft}
    assert "goal" in outcomes and len(outcomes) > 1  # the episodes cover more than one kind of ending


def test_a_team_log_holds_every_aircraft_and_every_forecast(team_log):
    path, live = team_log
    log = EpisodeLog(path)
    names = ["aircraft_0", "aircraft_1", "aircraft_2"]
    for name in names:
        assert {f"/agent/{name}/path", f"/agent/{name}/state"} <= set(log.topics)
    ep = log.episode(0)
    assert ep.scene.agent_names == tuple(names) and ep.scene.targets_xy.shape == (3, 2)
    step = ep.team_steps[1]
    n = len(ep.scene.mover_names)
    assert step.prediction.shape[0] == n + 3  # the movers', then every aircraft's forecast
    assert [a.name for a in step.aircraft] == names
    assert all(a.action is not None for a in step.aircraft) and ep.team_steps[0].aircraft[0].action is None
    # one outcome event per aircraft, naming it
    outcomes = [e for e in ep.events if e.kind in ("goal", "collision", "timeout", "off_surface", "diverged")]
    assert sorted(name for e in outcomes for name in names if name in e.message) == names
    with pytest.raises(LogError, match="3 aircraft: read its team_steps"):
        _ = ep.steps


def test_the_recorder_refuses_to_mix_one_and_several_aircraft(team_log, tmp_path):
    from deck_sim.recording import EpisodeRecorder, RecordingError

    path, _ = team_log
    ep = EpisodeLog(path).episode(0)
    with EpisodeRecorder(tmp_path / "x.mcap", metadata={}) as rec:
        with pytest.raises(RecordingError, match="call begin_team_episode"):
            rec.begin_episode(ep.scene, ep.team_steps[0])
        rec.begin_team_episode(ep.scene, ep.team_steps[0])
        with pytest.raises(RecordingError, match="call record_team_step"):
            rec.record_step(ep.team_steps[1])
    assert "team=True" in repr(ep) and ep.outcome is None  # each aircraft has its own outcome (rescore_team)


def test_a_killed_team_run_keeps_its_finished_episodes(team_log, tmp_path):
    path, live = team_log
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    rec = recover(cut)
    log = EpisodeLog(rec.path)
    complete = [ep for ep in log.episodes if ep.complete]
    assert complete and rec.episodes_incomplete <= 1
    for ep in complete:
        assert _same(ep.rescore_team(), live[ep.index])
    for ep in log.episodes:
        if not ep.complete:
            with pytest.raises(LogError, match="incomplete"):
                ep.rescore_team()


def _cli(*args: str, gl: str = "disable") -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": gl}
    return subprocess.run([sys.executable, "-m", "deck_sim.cli", *args], env=env, capture_output=True, text=True,
                          timeout=600)


@pytest.mark.slow
def test_deck_sim_run_logs_every_aircraft_and_the_log_commands_read_it(tmp_path):
    out = tmp_path / "run"
    proc = _cli("run", "--scene", "deck1-multi", "--scene-set", "agents.count=2", "--policy", "prioritised",
                "--episodes", "1", "--seed", "4", "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    log_path = out / "episodes.mcap"
    assert "episode log of every aircraft" in proc.stdout
    info = _cli("log", "info", str(log_path))
    assert info.returncode == 0, info.stderr
    assert "aircraft_0" in info.stdout and "aircraft_1" in info.stdout and "/agent/aircraft_1/state" in info.stdout
    rows = list(__import__("csv").DictReader(open(out / "episodes.csv", newline="")))
    for row in rows:  # the live table's outcomes are the log's
        assert any(line.split()[:2] == [row["aircraft"], row["outcome"]] for line in info.stdout.splitlines())
    plot = _cli("log", "plot", str(log_path), "--out", str(tmp_path / "p.png"))
    assert plot.returncode == 0 and (tmp_path / "p.png").stat().st_size > 10_000, plot.stderr
    export = _cli("log", "export", str(log_path), "--csv", "--out", str(tmp_path / "csv"))
    assert export.returncode == 0, export.stderr
    episodes = list(__import__("csv").DictReader(open(tmp_path / "csv" / "episodes_episodes.csv", newline="")))
    assert [(r["aircraft"], r["outcome"]) for r in episodes] == [(r["aircraft"], r["outcome"]) for r in rows]
    video = _cli("log", "video", str(log_path), "--out", str(tmp_path / "v.mp4"), "--max-steps", "2", "--width",
                 "160", gl="egl")
    assert video.returncode == 0, video.stderr
    import imageio.v3 as iio

    frames = iio.imread(tmp_path / "v.mp4")
    assert frames.shape[0] == 3 and frames[0].std() > 5
    np.testing.assert_array_less(0, frames.shape)
