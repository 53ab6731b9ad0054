"""Episode logs (MCAP): schemas and counts read back with the plain mcap reader, exact re-scoring, metadata and
attachments, determinism, crash recovery from a killed child process, clear errors on bad files, the CLI."""

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap
import tomllib

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

import deck_sim
from deck_sim.cli import main
from deck_sim.metrics import prediction_errors
from deck_sim.policies import make_policy
from deck_sim.recording import EpisodeLog, EpisodeRecorder, LogError, RecordingError, TruncatedLogError, recover
from deck_sim.recording.schema import TOPICS
from deck_sim.rollout import open_recorder, run_attachments, run_episode, run_metadata, task_frames
from deck_sim.scenes import parse_scene

SEED = 2
LIMIT = 30.0  # s: with seed 2 the episodes end in a goal, a collision and a timeout


def _load(seed=SEED):
    return deck_sim.load("deck1", seed=seed, episode__time_limit=LIMIT)


def _record(path, episodes=3, seed=SEED, chunk_size=None):
    """Record ``episodes`` episodes (scripted and random policies in turn); return live results and frames."""
    env = _load(seed)
    policies = [make_policy("scripted", env, seed=seed), make_policy("random", env, seed=seed)]
    frames = task_frames(env)
    live, steps = [], []
    kwargs = {} if chunk_size is None else {"chunk_size": chunk_size}
    config = {"scene": "deck1", "seed": seed, "time_limit": LIMIT}
    with open_recorder(path, env, seed=seed, policy="scripted/random", config=config, **kwargs) as rec:
        for k in range(episodes):
            count = [0]

            def on_step(env, ts, action, k=k, count=count):
                steps.append(frames.step(ts, action, k, count[0]))
                count[0] += 1

            live.append(run_episode(env, policies[k % 2], episode=k, on_step=on_step, recorder=rec))
    return env, live, steps


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("log") / "episodes.mcap"
    env, live, steps = _record(path)
    return path, env, live, steps


def test_the_episodes_cover_every_kind_of_ending(recorded):
    _, _, live, _ = recorded
    assert [r.outcome for r in live] == ["goal", "collision", "timeout"]


def test_schemas_channels_and_counts_read_back_with_the_mcap_reader(recorded):
    path, _, live, _ = recorded
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == set(TOPICS)
        for topic, channel in channels.items():
            sch = summary.schemas[channel.schema_id]
            assert sch.name == TOPICS[topic]
            if topic == "/agent/state":
                assert (sch.encoding, channel.message_encoding) == ("jsonschema", "json")
            else:
                assert (sch.encoding, channel.message_encoding) == ("protobuf", "protobuf")
        counts = {topic: 0 for topic in channels}
        for _, channel, _ in reader.iter_messages():
            counts[channel.topic] += 1
        assert reader.get_header().library.startswith("foxglove-sdk-python")
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
    by_id = {c.id: c.topic for c in summary.channels.values()}
    assert {by_id[i]: n for i, n in summary.statistics.channel_message_counts.items()} == counts
    steps = sum(r.steps + 1 for r in live)  # the reset and every step
    assert counts["/tf"] == counts["/prediction"] == counts["/agent/path"] == counts["/agent/state"] == steps
    assert counts["/scene"] == len(live)
    assert counts["/events"] == 3 * len(live)  # start, outcome, end (the constant-velocity predictor never fails)


def test_every_logged_step_equals_the_frame_recorded(recorded):
    path, _, _, steps = recorded
    logged = list(EpisodeLog(path).steps())
    assert len(logged) == len(steps)
    for a, b in zip(logged, steps, strict=True):
        for name in vars(b):
            x, y = getattr(a, name), getattr(b, name)
            if isinstance(y, np.ndarray):
                assert x.dtype == np.float64 and np.array_equal(x, y), name
            else:
                assert x == y and type(x) is type(y), name


def test_rescored_metrics_equal_the_live_ones_exactly(recorded):
    path, _, live, steps = recorded
    log = EpisodeLog(path)
    assert [ep.index for ep in log.episodes] == [0, 1, 2] and all(ep.complete for ep in log.episodes)
    for r in live:
        score = log.rescore(r.episode)
        assert score.result == r  # every field, floats compared with ==
        mine = [s for s in steps if s.episode == r.episode]
        ade, fde, n = prediction_errors(np.stack([s.prediction for s in mine]), np.stack([s.mover_xy for s in mine]))
        assert (score.ade, score.fde, score.prediction_samples) == (ade, fde, n)
        assert n > 0 and 0 < score.ade < score.fde


def _decode(message_type, data):
    """Decode protobuf bytes with the schema foxglove-sdk ships for ``message_type``."""
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    sch = message_type.get_schema()
    record = Schema(id=1, data=sch.data, encoding=sch.encoding, name=sch.name)
    return DecoderFactory().decoder_for("protobuf", record)(data)


def test_numpy_encoding_is_byte_identical_to_the_sdk():
    from foxglove.messages import (
        Color,
        FrameTransform,
        FrameTransforms,
        LinePrimitive,
        Point3,
        Pose,
        Quaternion,
        SceneEntity,
        SceneUpdate,
        Timestamp,
        Vector3,
    )

    from deck_sim.recording import _lines

    rng = np.random.default_rng(1)
    color = Color(r=0.2, g=0.6, b=1.0, a=1.0)
    pose = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    ids = ["prediction/tractor_0", "prediction/taxiing_0"]
    lines = _lines.LineStrips("deck", ids, pose.encode(), 0.4, color.encode())
    frames = _lines.Transforms("deck", ["agent", "tractor_0"])
    for t_ns in (0, 1, 12_500_000_000, 3_000_000_000, 10**18 + 7):
        stamp = Timestamp(t_ns // 10**9, t_ns % 10**9)
        pts = rng.normal(size=(2, 150, 3)) * 100
        sdk = SceneUpdate(
            entities=[
                SceneEntity(
                    timestamp=stamp,
                    frame_id="deck",
                    id=ident,
                    lines=[
                        LinePrimitive(
                            pose=pose, thickness=0.4, color=color, points=[Point3(x=x, y=y, z=z) for x, y, z in p]
                        )
                    ],
                )
                for ident, p in zip(ids, pts.tolist(), strict=True)
            ]
        ).encode()
        assert lines.encode(_lines.stamp(t_ns), [_lines.points(p) for p in pts]) == sdk
        poses = rng.normal(size=(2, 7))
        sdk = FrameTransforms(
            transforms=[
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id="deck",
                    child_frame_id=child,
                    translation=Vector3(x=p[0], y=p[1], z=p[2]),
                    rotation=Quaternion(w=p[3], x=p[4], y=p[5], z=p[6]),
                )
                for child, p in zip(["agent", "tractor_0"], poses.tolist(), strict=True)
            ]
        ).encode()
        assert frames.encode(_lines.stamp(t_ns), poses) == sdk
    # zeros are written explicitly (the SDK omits them): they decode alike, a negative zero keeps its sign
    pts = np.array([[0.0, -0.0, 1.0], [2.0, 0.0, -0.0]])
    update = _decode(SceneUpdate, lines.encode(_lines.stamp(0), [_lines.points(pts), _lines.points(pts[:1])]))
    got = np.array([[(q.x, q.y, q.z) for q in e.lines[0].points] for e in update.entities[:1]])[0]
    assert np.array_equal(got, pts) and np.array_equal(np.signbit(got), np.signbit(pts))
    assert [e.id for e in update.entities] == ids and update.entities[0].lines[0].thickness == 0.4
    tf = _decode(FrameTransforms, frames.encode(_lines.stamp(5), np.zeros((2, 7))))
    assert [t.child_frame_id for t in tf.transforms] == ["agent", "tractor_0"] and tf.transforms[1].timestamp.nanos == 5


def test_prediction_errors_by_hand():
    actual = np.zeros((4, 1, 2))
    actual[:, 0, 0] = [0.0, 1.0, 2.0, 3.0]  # one mover along x at 1 m per step
    predicted = np.zeros((4, 1, 2, 2))
    predicted[0, 0] = [[1.0, 0.0], [2.0, 4.0]]  # errors 0 and 4
    predicted[1, 0] = [[2.0, 3.0], [3.0, 0.0]]  # errors 3 and 0
    predicted[2:, 0] = 99.0  # horizons past the end: not scored
    assert prediction_errors(predicted, actual) == (7.0 / 4.0, 2.0, 2)
    assert np.isnan(prediction_errors(np.zeros((4, 1, 0, 2)), actual)[0])


def test_events_name_the_outcome_and_episodes_do_not_overlap(recorded):
    path, _, live, _ = recorded
    log = EpisodeLog(path)
    kinds = [[e.kind for e in ep.events] for ep in log.episodes]
    assert kinds == [["episode_start", r.outcome, "episode_end"] for r in live]
    collision = next(e for e in log.events(1) if e.kind == "collision")
    assert live[1].collision_partner in collision.message and collision.level == "ERROR"
    for a, b in zip(log.episodes, log.episodes[1:], strict=False):
        end = a.start_ns + round(a.duration * 1e9)
        assert b.start_ns > end and b.start_ns % 1_000_000_000 == 0
        assert a.steps[-1].time == a.duration  # log time is simulation time


def test_metadata_and_attachments_round_trip(recorded):
    path, env, _, _ = recorded
    log = EpisodeLog(path)
    expected = run_metadata(env, SEED, "scripted/random")
    assert log.metadata == {**expected, "format": "deck_sim.episode_log/1"}
    for key in ("scene", "seed", "predictor", "policy", "checkpoint", "deck_sim_version", "git_commit"):
        assert key in log.metadata
    assert log.metadata["reward.collision"] == "-50.0" and log.metadata["predictor"] == "constant_velocity"
    config = {"scene": "deck1", "seed": SEED, "time_limit": LIMIT}
    for a in run_attachments(env, config):
        assert log.attachments[a.name] == (a.media_type, a.data)
    assert json.loads(log.attachments["run.json"][1]) == config
    assert parse_scene(tomllib.loads(log.attachments["scene.toml"][1].decode())) == env.task.spec
    model = mujoco.MjModel.from_xml_string(log.attachments["model.xml"][1].decode())
    live_model = env.physics.model
    assert (model.nbody, model.ngeom, model.nu) == (live_model.nbody, live_model.ngeom, live_model.nu)


def test_two_runs_with_one_seed_write_identical_messages(tmp_path):
    paths = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    for p in paths:
        _record(p, episodes=1)
    contents = []
    for p in paths:
        with open(p, "rb") as f:
            reader = make_reader(f)
            contents.append([(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in reader.iter_messages()])
    assert len(contents[0]) > 50 and contents[0] == contents[1]
    assert paths[0].read_bytes() == paths[1].read_bytes()  # no wall-clock field anywhere in the file


_CHILD = textwrap.dedent(
    """
    import json, sys, time
    import deck_sim
    from deck_sim.policies import make_policy
    from deck_sim.rollout import open_recorder, run_episode

    env = deck_sim.load("deck1", seed={seed}, episode__time_limit={limit})
    policy = make_policy("scripted", env, seed={seed})
    rec = open_recorder(sys.argv[1], env, seed={seed}, policy="scripted", chunk_size=4096)
    print("done", json.dumps(run_episode(env, policy, episode=0, recorder=rec).as_dict()), flush=True)

    def on_step(env, ts, action, count=[0]):
        count[0] += 1
        if count[0] == 21:  # the reset and 20 steps of episode 1 are recorded: wait to be killed
            print("waiting", flush=True)
            time.sleep(120)

    run_episode(env, policy, episode=1, recorder=rec, on_step=on_step)
    print("not killed", flush=True)
    """
)


def test_a_child_killed_mid_episode_leaves_a_recoverable_log(tmp_path):
    path = tmp_path / "killed.mcap"
    code = _CHILD.format(seed=SEED, limit=LIMIT)
    env = {**os.environ, "MUJOCO_GL": "disable"}
    child = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        done = child.stdout.readline()
        assert done.startswith("done "), done
        assert child.stdout.readline() == "waiting\n"
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    live = json.loads(done[5:])

    with pytest.raises(TruncatedLogError, match="recover"):
        EpisodeLog(path)
    rec = recover(path)
    assert rec.was_truncated and rec.episodes_complete == 1
    log = EpisodeLog(rec.path)
    assert not log.truncated
    assert log.rescore(0).result.as_dict() == live
    # the chunks of episode 1 that were closed (4 KiB each, about a step) survive: only its tail is lost
    assert rec.episodes_incomplete == 1
    partial = log.episode(1)
    assert not partial.complete and partial.outcome is None
    assert 15 <= len(partial.steps) <= 21 and [s.step for s in partial.steps] == list(range(len(partial.steps)))
    with pytest.raises(LogError, match="incomplete"):
        partial.rescore()
    partial_log = EpisodeLog(path, allow_truncated=True)
    assert partial_log.truncated and partial_log.episode(0).complete


def _bad_files(tmp_path, good):
    data = good.read_bytes()
    files = {
        "missing": tmp_path / "missing.mcap",
        "empty": tmp_path / "empty.mcap",
        "garbage": tmp_path / "garbage.mcap",
        "head": tmp_path / "head.mcap",
        "half": tmp_path / "half.mcap",
        "flipped": tmp_path / "flipped.mcap",
    }
    files["empty"].write_bytes(b"")
    files["garbage"].write_bytes(np.random.default_rng(0).bytes(5000))
    files["head"].write_bytes(data[:12])
    files["half"].write_bytes(data[: len(data) // 2])
    flipped = bytearray(data)
    flipped[len(data) // 3] ^= 0xFF
    files["flipped"].write_bytes(bytes(flipped))
    return files


def test_bad_files_give_a_clear_error_naming_the_file(recorded, tmp_path, capsys):
    path, _, _, _ = recorded
    expected = {
        "missing": "no such file",
        "empty": "empty file",
        "garbage": "not an MCAP file",
        "head": "truncated",
        "half": "truncated",
        "flipped": "damaged",
    }
    for name, p in _bad_files(tmp_path, path).items():
        kind = TruncatedLogError if expected[name] == "truncated" else LogError
        with pytest.raises(kind, match=expected[name]) as err:
            EpisodeLog(p)
        assert str(p) in str(err.value)
        assert main(["log", "info", str(p)]) == 2
        captured = capsys.readouterr()
        assert "error" in captured.err and expected[name] in captured.err and "Traceback" not in captured.err
    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    with pytest.raises(LogError, match="not a deck_sim episode log"):
        EpisodeLog(other)
    with pytest.raises(LogError, match="not an MCAP file"):
        recover(tmp_path / "garbage.mcap")


def test_a_log_cut_anywhere_is_recovered_up_to_its_last_whole_chunk(recorded, tmp_path):
    path, _, live, _ = recorded
    data = path.read_bytes()
    kept = []
    for fraction in (0.3, 0.6, 0.95):
        cut = tmp_path / f"cut{fraction}.mcap"
        cut.write_bytes(data[: int(len(data) * fraction)])
        rec = recover(cut, tmp_path / f"fixed{fraction}.mcap")
        log = EpisodeLog(rec.path)
        for ep in log.episodes:
            if ep.complete:
                assert ep.rescore().result == live[ep.index]
        kept.append(rec.messages)
    assert kept == sorted(kept) and kept[-1] > 0


def test_the_recorder_refuses_misuse(recorded, tmp_path):
    path, env, _, steps = recorded
    with pytest.raises(FileExistsError):
        EpisodeRecorder(path, metadata={})
    with EpisodeRecorder(tmp_path / "x.mcap", metadata={"scene": "deck1"}) as rec:
        with pytest.raises(RecordingError, match="begin_episode"):
            rec.record_step(steps[1])
    with pytest.raises(RecordingError, match="closed"):
        rec.record_step(steps[1])


def test_the_recording_package_needs_no_mujoco():
    code = (
        "import sys; import deck_sim.recording, deck_sim.recording.plot; "
        "print(sorted(m for m in ('mujoco', 'dm_control', 'deck_sim.tasks') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_cli_info_plot_export_and_recover(recorded, tmp_path, capsys):
    path, _, live, _ = recorded
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out
    for word in ("/tf", "foxglove.FrameTransforms", "deck_sim.AgentState", "3 complete", "collision", "timeout"):
        assert word in out
    png = tmp_path / "ep.png"
    assert main(["log", "plot", str(path), "--episode", "1", "--out", str(png), "--steps", "5,15"]) == 0
    import imageio.v3 as iio

    image = iio.imread(png)
    assert image.ndim == 3 and image.shape[1] > 2 * image.shape[0]  # the deck is long
    assert main(["log", "plot", str(path), "--steps", "9999", "--out", str(png)]) == 2
    assert "no step [9999]" in capsys.readouterr().err

    assert main(["log", "export", str(path), "--csv", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "episodes_steps.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == sum(r.steps + 1 for r in live)
    assert float(rows[1]["x"]) == EpisodeLog(path).episodes[0].steps[1].agent_xy[0]
    with open(tmp_path / "episodes_episodes.csv") as f:
        episodes = list(csv.DictReader(f))
    assert [float(e["path_length"]) for e in episodes] == [r.path_length for r in live]

    half = tmp_path / "half.mcap"
    half.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert main(["log", "recover", str(half), "--out", str(tmp_path / "fixed.mcap")]) == 0
    assert "truncated at byte" in capsys.readouterr().out
    assert EpisodeLog(tmp_path / "fixed.mcap").episodes


@pytest.mark.slow
def test_run_records_every_episode_by_default(tmp_path):
    out = tmp_path / "run"
    args = ["run", "--scene", "deck1", "--policy", "zero", "--episodes", "2", "--seed", "1", "--quiet"]
    args += ["--predictor", "none", "--out", str(out)]
    assert main([*args, "--no-record", "--episodes", "1"]) == 0
    assert not (out / "episodes.mcap").exists()
    assert main(args) == 0
    log = EpisodeLog(out / "episodes.mcap")
    assert "/prediction" not in log.topics or log.topics["/prediction"].count == 0  # predictor none: no prediction
    with open(out / "episodes.csv") as f:
        rows = list(csv.DictReader(f))
    for row, ep in zip(rows, log.episodes, strict=True):
        r = ep.rescore().result
        assert (r.outcome, r.steps, r.path_length, r.reward) == (
            row["outcome"],
            int(row["steps"]),
            float(row["path_length"]),
            float(row["reward"]),
        )
    assert json.loads(log.attachments["run.json"][1])["policy"] == "zero"


@pytest.mark.slow
def test_log_video_renders_the_logged_states(recorded, tmp_path):
    path, _, _, _ = recorded
    video = tmp_path / "ep.mp4"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [sys.executable, "-m", "deck_sim.cli", "log", "video", str(path), "--episode", "0"]
    cmd += ["--out", str(video), "--max-steps", "2", "--width", "160"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    import imageio.v3 as iio

    frames = iio.imread(video)
    assert frames.shape[0] == 3 and frames.shape[2] == 160
    assert frames[0].std() > 5  # a picture, not a blank frame
