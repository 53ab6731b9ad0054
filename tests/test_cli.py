"""The command line: scenes, run (metrics and files), render (in a subprocess with EGL), clear errors."""

import json
import os
import subprocess
import sys

import pytest

from deck_sim.cli import main


def test_scenes_lists_every_scene(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("deck1", "deck2", "square"):
        assert name in out


def test_run_prints_metrics_and_writes_results(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        main(
            [
                "run",
                "--scene",
                "deck1",
                "--policy",
                "zero",
                "--episodes",
                "1",
                "--seed",
                "1",
                "--quiet",
                "--out",
                str(out),
                "--predictor",
                "none",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    for word in ("success", "collision", "timeout", "path length", "turning angle"):
        assert word in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["summary"]["timeout_rate"] == 1.0  # standing still never arrives
    assert (out / "episodes.csv").read_text().count("\n") == 2


def test_run_overrides_fields_of_the_scene_file(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["run", "--scene", "deck1", "--policy", "zero", "--episodes", "1", "--quiet", "--no-record"]
    sets = ["--scene-set", "episode.time_limit=3", "--scene-set", "movers.tractors=2"]
    assert main([*args, "--out", str(out), *sets]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene_set"] == {"episode__time_limit": 3, "movers__tractors": 2}
    episode = (out / "episodes.csv").read_text().splitlines()
    row = dict(zip(episode[0].split(","), episode[1].split(","), strict=True))
    assert row["outcome"] == "timeout" and float(row["sim_time"]) == 3.0  # 3 s, not deck 1's time limit
    capsys.readouterr()
    assert main([*args, "--scene-set", "movers.agent_yield_braking=-1"]) == 2
    assert "[movers].agent_yield_braking: must be >= 0, got -1" in capsys.readouterr().err
    assert main([*args, "--scene-set", "time_limit=3"]) == 2
    assert "--scene-set expects section.field=value" in capsys.readouterr().err
    assert main([*args, "--scene-set", "episode.time_limit"]) == 2
    assert "--scene-set expects field=value" in capsys.readouterr().err
    assert main([*args, "--scene-set", "mover.yield_distance=3"]) == 2
    assert "no section [mover]; the sections are agent, static, movers, reward, episode" in capsys.readouterr().err
    # what a policy or --predictor needs is not overridden behind its back
    assert main([*args, "--predictor", "none", "--scene-set", "episode.predictor=mpc"]) == 2
    assert "contradicts --predictor, which needs 'none'" in capsys.readouterr().err
    mddpg = ["run", "--policy", "mddpg", "--episodes", "1", "--quiet", "--no-record"]
    assert main([*mddpg, "--scene-set", "episode.mover_size=false"]) == 2
    assert "contradicts policy 'mddpg', which needs True" in capsys.readouterr().err


def test_bad_scene_and_policy_give_a_clear_error(capsys):
    assert main(["run", "--scene", "deck7", "--episodes", "1", "--quiet"]) == 2
    assert "unknown scene 'deck7'" in capsys.readouterr().err
    assert main(["run", "--scene", "deck1", "--policy", "wishful", "--episodes", "1", "--quiet"]) == 2
    assert "unknown policy 'wishful'" in capsys.readouterr().err


@pytest.mark.slow
def test_render_writes_a_video_and_a_png(tmp_path):
    video = tmp_path / "ep.mp4"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "deck_sim.cli",
            "render",
            "--scene",
            "deck1",
            "--out",
            str(video),
            "--steps",
            "3",
            "--width",
            "160",
            "--height",
            "120",
            "--top-height",
            "120",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    import imageio.v3 as iio

    frames = iio.imread(video)
    assert frames.shape[0] == 4 and frames.shape[1:] == (120, 160, 3)
    png = iio.imread(video.with_suffix(".png"))
    assert png.shape[0] == 120 and png.shape[1] > 3 * 120  # the deck is long


def test_version_and_every_subcommand_help_opens_with_what_it_does(capsys):
    from deck_sim import __version__

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.strip() == f"deck-sim {__version__}"
    for command in (["scenes"], ["run"], ["render"], ["eval"], ["log", "info"], ["log", "recover"], ["train"],
                    ["ensemble"]):
        with pytest.raises(SystemExit):
            main([*command, "--help"])
        text = capsys.readouterr().out
        first = text.split("\n\n")[1]  # after the usage block: the description
        assert first[0].isupper() and first.rstrip().endswith("."), (command, first)
        if command == ["run"]:
            assert "(default: deck1)" in text and "(default: 20)" in text


@pytest.mark.slow
def test_progress_is_plain_lines_when_stderr_is_not_a_terminal(tmp_path):
    err = tmp_path / "stderr.txt"
    with open(err, "w") as f:
        proc = subprocess.run(
            [sys.executable, "-m", "deck_sim.cli", "run", "--scene", "deck1", "--policy", "zero", "--episodes", "2",
             "--predictor", "none", "--no-record", "--out", str(tmp_path / "run")],
            stdout=subprocess.PIPE, stderr=f, text=True, timeout=300, env={**os.environ, "MUJOCO_GL": "disable"},
        )
    assert proc.returncode == 0, err.read_text()
    text = err.read_text()
    assert "\r" not in text
    assert "deck1 zero: 2/2 ep (100 %)" in text  # the final line


def test_an_unreachable_ray_address_fails_fast_and_clearly(capsys):
    import time

    t0 = time.monotonic()
    code = main(["eval", "--agents", "zero", "--scenes", "deck1", "--episodes", "1", "--backend", "ray",
                 "--ray-address", "127.0.0.1:9", "--quiet", "--record", "none"])
    assert code == 2 and time.monotonic() - t0 < 30
    assert "no Ray cluster answers there" in capsys.readouterr().err
