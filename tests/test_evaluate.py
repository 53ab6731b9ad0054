"""Task-suite evaluation: backends agree, reports hold what was measured, bad requests fail clearly."""

import csv
import json

import pytest

from deck_sim.cli import main
from deck_sim.evaluation import EvalConfig, EvalError, EvalResults, evaluate, same_results, write_report
from deck_sim.scenes import SceneSpecError

SMALL = dict(agents=("mddpg", "apf"), scenes=("deck1",), episodes=3, chunk=2, workers=2, record="none")


@pytest.fixture(scope="module")
def serial():
    return evaluate(EvalConfig(backend="serial", **SMALL))


@pytest.mark.slow
def test_process_pool_gives_the_serial_results_and_each_unit_its_log(serial, tmp_path):
    from deck_sim.recording import EpisodeLog

    pooled = evaluate(EvalConfig(backend="process", **{**SMALL, "record": "all", "out": str(tmp_path)}))
    assert same_results(pooled.episodes, serial.episodes)
    assert same_results(pooled.summaries, serial.summaries)
    names = sorted(p.name for p in (tmp_path / "logs").glob("*.mcap"))
    assert names == ["deck1-apf-0000.mcap", "deck1-apf-0002.mcap", "deck1-mddpg-0000.mcap", "deck1-mddpg-0002.mcap"]
    assert [len(EpisodeLog(tmp_path / "logs" / n).episodes) for n in names] == [2, 1, 2, 1]
    logged = EpisodeLog(tmp_path / "logs" / "deck1-mddpg-0002.mcap").episodes[0].rescore().result
    assert logged.reward == serial.episodes[2]["reward"]  # the logged episode is the one measured


@pytest.mark.slow
def test_ray_gives_the_serial_results_and_each_unit_its_log(serial, tmp_path):
    pytest.importorskip("ray")
    from deck_sim.recording import EpisodeLog

    remote = evaluate(EvalConfig(backend="ray", **{**SMALL, "record": "all", "out": str(tmp_path)}))
    assert same_results(remote.episodes, serial.episodes)
    assert same_results(remote.summaries, serial.summaries)
    names = sorted(p.name for p in (tmp_path / "logs").glob("*.mcap"))  # each Ray worker wrote its units' logs
    assert names == ["deck1-apf-0000.mcap", "deck1-apf-0002.mcap", "deck1-mddpg-0000.mcap", "deck1-mddpg-0002.mcap"]
    logged = EpisodeLog(tmp_path / "logs" / "deck1-apf-0002.mcap").episodes[0].rescore().result
    assert logged.reward == next(e for e in serial.episodes if e["agent"] == "apf" and e["episode"] == 2)["reward"]


def test_a_failing_unit_stops_the_pool_with_its_error():
    """An actor made for another scene fails inside its units: the run stops with that error, and the units still
    waiting are dropped (at most the four good ones finish)."""
    from deck_sim.policies import PolicyFileError

    finished = []
    cfg = EvalConfig(
        agents=("apf", "wrong=deck_sim/trained/deck2_mddpg.npz"),
        scenes=("deck1",),
        episodes=4,
        chunk=1,
        workers=2,
        record="none",
        backend="process",
    )
    with pytest.raises(PolicyFileError, match=r"trained on \(9, 2\)"):
        evaluate(cfg, progress=lambda done, total, records: finished.append(records[0]["agent"]))
    assert len(finished) <= 4 and set(finished) <= {"apf"}


def test_results_compare_nan_as_equal():
    assert same_results([{"x": float("nan"), "y": 1.0}], [{"x": float("nan"), "y": 1.0}])
    assert not same_results([{"x": float("nan")}], [{"x": 0.0}])


def test_episodes_are_seeded_per_index_and_below_training_seeds(serial):
    from training.config import TRAIN_SEED_BASE

    rows = serial.episodes
    assert [(r["agent"], r["episode"]) for r in rows] == [(a, i) for a in ("mddpg", "apf") for i in range(3)]
    assert [r["seed"] for r in rows[:3]] == [100_000, 100_001, 100_002]
    # the same seed is the same layout for every agent
    assert [r["start_target_distance"] for r in rows[:3]] == [r["start_target_distance"] for r in rows[3:]]
    assert all(r["seed"] < TRAIN_SEED_BASE for r in rows)
    with pytest.raises(EvalError, match="below every training seed"):
        EvalConfig(agents=("apf",), scenes=("deck1",), seed=TRAIN_SEED_BASE - 1, episodes=2).validate()


def test_an_episode_replays_alone_from_its_random_state():
    """Nothing carries from one episode to the next (the physics, the movers, the MPC predictor's warm start, the
    actors): an episode of a stream played again alone, from the random state it started from, ends the same. So an
    episode reseeded by the evaluation and one met in a ``deck-sim run`` stream are draws of the same kind."""
    import deck_sim
    from deck_sim.policies import make_policy, policy_overrides
    from deck_sim.rollout import run_episode

    overrides = policy_overrides("mddpg", "deck1")
    stream = deck_sim.load("deck1", seed=7, **overrides)
    policy = make_policy("mddpg", stream)
    states, results = [], []
    for k in range(3):
        states.append(stream.random_state.get_state())
        results.append(run_episode(stream, policy, episode=k).as_dict())
    alone = deck_sim.load("deck1", seed=0, **overrides)
    fresh = make_policy("mddpg", alone)
    for k in (2, 0):  # the last one first: a different episode before each
        alone.random_state.set_state(states[k])
        assert same_results([run_episode(alone, fresh, episode=k).as_dict()], [results[k]])
    assert len({r["reward"] for r in results}) == 3  # three different episodes


def test_summaries_follow_the_episodes(serial):
    for s in serial.summaries:
        mine = [r for r in serial.episodes if r["agent"] == s["agent"]]
        wins = [r for r in mine if r["outcome"] == "goal"]
        assert s["goal_rate"] == len(wins) / len(mine)
        lo, hi = s["goal_ci"]
        assert 0.0 <= lo <= s["goal_rate"] <= hi <= 1.0
        if wins:
            assert s["shortest_ratio"] == pytest.approx(
                sum(r["path_length"] / r["shortest_path"] for r in wins) / len(wins)
            )
            assert s["shortest_ratio"] >= 0.98  # the reference is a lower bound (up to the graph's 5 cm node margin)
        assert s["predictor"] == "mpc"
        assert s["ade"] > 0 and s["fde"] >= s["ade"]


def test_the_report_files_hold_the_results(serial, tmp_path):
    paths = write_report(serial, tmp_path)
    data = json.loads(paths["summary.json"].read_text())
    assert data["config"]["episodes"] == 3 and len(data["episodes"]) == 6
    assert data["evaluated"] == [["deck1", "mddpg"], ["deck1", "apf"]]
    with open(paths["episodes.csv"]) as f:
        rows = list(csv.DictReader(f))
    assert [float(r["reward"]) for r in rows] == [r["reward"] for r in serial.episodes]
    md = paths["results.md"].read_text()
    mddpg = serial.summary("deck1", "mddpg")
    lo, hi = mddpg["goal_ci"]
    # ours with its interval, then the paper's deck 1 MDDPG success (Table 1)
    assert f"| mddpg | {100 * mddpg['goal_rate']:.1f} ({100 * lo:.0f}-{100 * hi:.0f}) | 98 |" in md
    assert "| apf | " in md and "| deck1 ours | deck1 paper |" in md
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize(
    "change,error,match",
    [
        ({"agents": ("telepathic",)}, EvalError, "unknown agent 'telepathic'"),
        ({"agents": ("apf", "apf")}, EvalError, "repeat"),
        ({"scenes": ("deck1", "deck1")}, EvalError, "scenes repeat"),
        ({"scenes": ("deck9",)}, SceneSpecError, "deck9"),
        ({"episodes": 0}, EvalError, "episodes"),
        ({"backend": "slurm"}, EvalError, "unknown backend 'slurm'"),
        ({"record": "some"}, EvalError, "record"),
    ],
)
def test_bad_requests_name_the_problem(change, error, match):
    cfg = EvalConfig(**{**dict(agents=("apf",), scenes=("deck1",), episodes=2), **change})
    with pytest.raises(error, match=match):
        cfg.validate()


def test_a_missing_actor_file_fails_before_any_episode(tmp_path):
    from deck_sim.policies import PolicyFileError

    with pytest.raises(PolicyFileError, match="no such actor file"):
        evaluate(EvalConfig(agents=(f"mine={tmp_path / 'none.npz'}",), scenes=("deck1",), episodes=1))


@pytest.mark.slow
def test_cli_eval_writes_tables_logs_and_trajectory_plots(tmp_path, capsys):
    out = tmp_path / "ev"
    rc = main(
        ["eval", "--agents", "astar,random", "--scenes", "deck1", "--episodes", "2", "--record", "1",
         "--backend", "serial", "--out", str(out), "--quiet"]
    )  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    assert "Success rate" in text and "| astar |" in text
    for name in ("summary.json", "summary.csv", "episodes.csv", "results.md"):
        assert (out / name).exists()
    logs = sorted(p.name for p in (out / "logs").glob("*.mcap"))
    assert logs == ["deck1-astar-0000.mcap", "deck1-random-0000.mcap"]
    assert sorted(p.name for p in (out / "trajectories").glob("*.png")) == [
        "deck1-astar-episode0.png",
        "deck1-random-episode0.png",
    ]
    from deck_sim.recording import EpisodeLog

    assert len(EpisodeLog(out / "logs" / "deck1-astar-0000.mcap").episodes) == 1
    summary = json.loads((out / "summary.json").read_text())
    random = next(s for s in summary["summaries"] if s["agent"] == "random")
    if random["goal_rate"] == 0:  # no success: no path length, written as null (JSON has no NaN)
        assert random["path_length"] is None


def test_cli_eval_rejects_a_bad_agent_with_exit_code_2(capsys):
    assert main(["eval", "--agents", "apf,nope", "--scenes", "deck1", "--episodes", "1", "--quiet"]) == 2
    assert "unknown agent 'nope'" in capsys.readouterr().err


def test_cli_eval_checks_curve_folders_before_running(tmp_path, capsys):
    rc = main(["eval", "--agents", "apf", "--scenes", "deck1", "--episodes", "1", "--quiet",
               "--curves", f"mine={tmp_path / 'nothing'}", "--out", str(tmp_path / "ev")])  # fmt: skip
    assert rc == 2
    assert "eval.csv does not exist" in capsys.readouterr().err
    assert not (tmp_path / "ev").exists()  # nothing ran, nothing written


def test_a_scene_file_is_reported_under_its_spec_name(tmp_path):
    from deck_sim.scenes import dump_scene, load_scene

    path = tmp_path / "mydeck.toml"
    path.write_text(dump_scene(load_scene("deck1")))
    res = evaluate(EvalConfig(agents=("zero",), scenes=(str(path),), episodes=1, backend="serial", record="none"))
    assert res.summary("deck1", "zero")["episodes"] == 1


def test_the_report_states_the_direction_of_each_mddpg_ddpg_difference():
    from deck_sim.evaluation.report import prediction_differences

    def summary(agent, length, turning):
        return {"scene": "deck1", "agent": agent, "path_length": length, "path_length_ci": [length - 1, length + 1],
                "turning_deg": turning, "turning_deg_ci": [turning - 5, turning + 5]}

    res = EvalResults(EvalConfig(**SMALL), [], [summary("mddpg", 120.0, 100.0), summary("ddpg", 125.0, 60.0)])
    lines = prediction_differences(res, ["deck1", "deck2"])
    apart = "(the intervals are apart)"
    paper = "the paper's: 0.02 Unity units shorter."
    assert f"- deck1: MDDPG drives a path 5.0 m shorter than DDPG {apart}; {paper}" in lines
    assert f"- deck1: MDDPG turns 40.0 deg more than DDPG {apart}; the paper's: 0.16 deg less." in lines
    assert not prediction_differences(EvalResults(EvalConfig(**SMALL), [], [summary("mddpg", 1.0, 1.0)]), ["deck1"])
    tie = EvalResults(EvalConfig(**SMALL), [], [summary("mddpg", 120.04, 60.0), summary("ddpg", 120.0, 60.0)])
    lines = prediction_differences(tie, ["deck1"])
    assert "- deck1: MDDPG drives a path as long as DDPG's (within 0.05 m; the intervals overlap); the paper's: " \
        "0.02 Unity units shorter." in lines
    assert "- deck1: MDDPG turns as much as DDPG (within 0.05 deg; the intervals overlap); the paper's: 0.16 deg " \
        "less." in lines
