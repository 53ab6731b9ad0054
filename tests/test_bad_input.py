"""Bad input at each entry point gets the project's own error naming the field or file, and the command line exits 2
with one line: actions (``InvalidActionError``), the Gymnasium env's step order (``ResetNeeded``), actor files
(``PolicyFileError``), episode logs (``LogError``; a damaged summary section is read past and ``recover`` rebuilds
it), the sizes, names and counts of ``deck-sim render`` and ``log video``, the folder of ``deck-sim run`` and its
Ctrl-C. Property tests (hypothesis, the deterministic profile of conftest.py) throw generated junk at each."""

import csv
import io
import json
import os
import signal
import struct
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
from conftest import NEAR
from gymnasium.error import ResetNeeded
from hypothesis import given, settings
from hypothesis import strategies as st

import deck_sim
from deck_sim.cli import main
from deck_sim.policies import PolicyFileError, load_actor, make_policy, policy_overrides, shipped_policy_path
from deck_sim.policies.actors import ACTOR_FORMAT
from deck_sim.recording import EpisodeLog, LogError, recover
from deck_sim.rollout import open_recorder, run_episode
from deck_sim.tasks.actions import InvalidActionError, _real_action
from deck_sim.wrappers import DeckSimEnv

LIMIT = 5.0  # s: the small log's episodes (10 decisions each)


# -- fixtures ------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env():
    """One deck 1 environment for the whole module, reset once: bad actions never change it."""
    e = deck_sim.load("deck1", seed=0)
    e.reset()
    return e


def _write_actor(path):
    """A small format-1 actor (3 inputs, 4 hidden units) as ``training`` writes one: a compressed ``.npz``."""
    rng = np.random.default_rng(0)
    meta = {"format": ACTOR_FORMAT, "scene": "deck1", "predictor": "none", "observation_keys": ["target", "heading"],
            "observation_shapes": {"target": [2], "heading": [1]}}
    arrays = {"w0": rng.normal(size=(4, 3)), "b0": np.zeros(4), "w1": rng.normal(size=(2, 4)), "b1": np.zeros(2),
              "norm_enabled": np.array(True), "norm_mean": np.zeros(3), "norm_std": np.ones(3),
              "norm_clip": np.array(5.0)}
    np.savez_compressed(path, meta=np.array(json.dumps(meta)), **arrays)
    return path


@pytest.fixture(scope="module")
def actor_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("actors")
    _write_actor(folder / "actor.npz")
    return folder


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """A log of two scripted episodes of 5 s in 4 KiB chunks, and the live results."""
    path = tmp_path_factory.mktemp("log") / "episodes.mcap"
    e = deck_sim.load("deck1", seed=2, episode__time_limit=LIMIT)
    policy = make_policy("scripted", e, seed=2)
    with open_recorder(path, e, seed=2, policy="scripted", chunk_size=4096) as rec:
        live = [run_episode(e, policy, episode=k, recorder=rec) for k in range(2)]
    return path, live


def _summary_start(data: bytes) -> int:
    """Where the summary section begins, read from the footer (opcode, length, then summary_start; then the
    summary offset start, the summary CRC and the 8 closing magic bytes)."""
    footer = len(data) - 8 - (1 + 8 + 8 + 8 + 4)
    assert data[footer] == 0x02  # the footer's opcode
    return struct.unpack_from("<Q", data, footer + 9)[0]


def _one_line_error(capsys, argv, *words):
    """``deck-sim argv`` exits 2 with one line on stderr naming every one of ``words``, and no traceback."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"deck-sim {argv[0]}: error: ") and "\n" not in err and "Traceback" not in err, err
    for word in words:
        assert str(word) in err, (word, err)
    return err


# -- actions -------------------------------------------------------------------------------------------------------
BAD_ACTIONS = [
    (["0.5", "0.5"], "real numbers"),
    ([True, False], "real numbers"),
    ([0.5 + 3j, 0], "real numbers"),
    (["a", "b"], "real numbers"),
    ({"x": 1}, "real numbers"),
    (None, "real numbers"),
    ([True, 0.5], "real numbers"),
    ([None, 0.5], "real numbers"),
    ([[1], [2, 3]], "real numbers"),
    (np.array([True, False]), "dtype bool"),
    (np.array([0.5, 0.5], dtype=complex), "dtype complex128"),
    (np.array(["0.5", "0.5"]), "dtype <U3"),
    (np.array([0.5, 0.5], dtype=object), "dtype object"),
    ([10**400, 0], r"\[-1, 1\]"),
    ([1.5, 0.0], r"\[-1, 1\]"),
    ([np.nan, 0.0], "finite"),
    ([0.0, -np.inf], "finite"),
    (np.zeros(3), "shape"),
    ([[0.1, 0.2]], "shape"),
    (0.5, "shape"),
]


@pytest.mark.parametrize(("action", "match"), BAD_ACTIONS, ids=[repr(a)[:30] for a, _ in BAD_ACTIONS])
def test_a_bad_action_is_an_invalid_action_error(env, action, match):
    with pytest.raises(InvalidActionError, match=match):
        env.step(action)


def test_real_actions_of_every_numeric_type_are_read_as_before(env):
    valid = [
        np.array([0.25, -0.5]), np.array([0.25, -0.5], dtype=np.float32), np.array([0.25, -0.5], dtype=np.float16),
        np.array([0.25, -0.5], dtype=np.longdouble), np.array([1, 0]), np.array([1, 0], dtype=np.uint8),
        [0.25, -0.5], (1, 0), [np.float32(0.25), np.float64(-0.5)], [np.int64(1), 0.5], [np.float16(0.3), 1],
    ]
    for action in valid:
        got = _real_action(action)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, np.asarray(action, dtype=np.float64))
    env.step(valid[0])
    env.reset()


def _maybe_valid(action) -> bool:
    """Whether a generated action could be a valid one (two real numbers in [-1, 1])."""
    return (
        isinstance(action, list)
        and len(action) == 2
        and all(type(x) in (int, float) and abs(x) <= 1.0 for x in action)
    )


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=8,
)
_BAD_NUMBER = st.one_of(
    st.booleans(),
    st.text(max_size=4),
    st.none(),
    st.complex_numbers(max_magnitude=1.0),
    st.sampled_from([float("nan"), float("inf"), -float("inf")]),
    st.integers(min_value=2) | st.integers(max_value=-2),
    st.floats(min_value=1.001, allow_infinity=False) | st.floats(max_value=-1.001, allow_infinity=False),
    st.lists(st.floats(-1, 1), min_size=1, max_size=2),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
)
_BAD_ACTIONS = st.one_of(
    _JSON.filter(lambda a: not _maybe_valid(a)),
    st.tuples(_BAD_NUMBER, st.floats(-1, 1), st.booleans()).map(lambda t: [t[0], t[1]] if t[2] else [t[1], t[0]]),
    st.lists(st.floats(-1, 1), max_size=5).filter(lambda a: len(a) != 2),
    st.lists(st.floats(-1, 1), min_size=2, max_size=2).map(lambda a: [a]),
    st.tuples(st.sampled_from([bool, complex, str, object]), st.lists(st.floats(-1, 1), min_size=2, max_size=2)).map(
        lambda t: np.array(t[1]).astype(t[0])
    ),
)


@settings(max_examples=150, deadline=None)
@given(action=_BAD_ACTIONS)
def test_generated_bad_actions_raise_only_invalid_action_error(env, action):
    with pytest.raises(InvalidActionError):
        env.step(action)


# -- the Gymnasium environment -------------------------------------------------------------------------------------
def test_the_gym_env_steps_only_inside_an_episode():
    env = DeckSimEnv("deck1", **NEAR)
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="real numbers"):
        env.step(["0.5", "0.5"])
    terminated = truncated = False
    while not (terminated or truncated):  # straight ahead, off the deck's edge
        _, reward, terminated, truncated, _ = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert terminated and np.isfinite(reward)
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=1)
    env.step(np.zeros(2, dtype=np.float32))  # an episode again
    env.close()

    short = DeckSimEnv("deck1", episode__time_limit=1.0)
    short.reset(seed=0)
    truncated = False
    while not truncated:
        _, _, terminated, truncated, _ = short.step(np.zeros(2, dtype=np.float32))
        assert not terminated
    with pytest.raises(ResetNeeded):
        short.step(np.zeros(2, dtype=np.float32))
    short.close()


# -- actor files ---------------------------------------------------------------------------------------------------
def _flip_member_data(data: bytes, path, member: str, count: int = 8) -> bytes:
    """``data`` (the bytes of the zip at ``path``) with ``count`` bytes in the middle of ``member``'s compressed
    data inverted."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    name_len, extra_len = struct.unpack_from("<HH", data, info.header_offset + 26)
    start = info.header_offset + 30 + name_len + extra_len + info.compress_size // 2
    out = bytearray(data)
    for i in range(start, start + count):
        out[i] ^= 0xFF
    return bytes(out)


def test_a_bit_flipped_actor_file_is_a_policy_file_error_naming_it(actor_dir, tmp_path, capsys):
    shipped = shipped_policy_path("mddpg", "deck1")
    flipped = tmp_path / "flipped.npz"
    flipped.write_bytes(_flip_member_data(shipped.read_bytes(), shipped, "m0/w0.npy"))
    with pytest.raises(PolicyFileError, match="not a readable actor file") as err:
        load_actor(flipped)
    assert str(flipped) in str(err.value)
    _one_line_error(capsys, ["run", "--policy", flipped, "--episodes", 1, "--quiet", "--out", tmp_path / "run"],
                    flipped, "not a readable actor file")
    assert not (tmp_path / "run").exists()
    # deck-sim ensemble reads its actors with the same reader
    small = actor_dir / "actor.npz"
    small_flipped = tmp_path / "small.npz"
    small_flipped.write_bytes(_flip_member_data(small.read_bytes(), small, "w0.npy", count=4))
    _one_line_error(capsys, ["ensemble", small, small_flipped, "--out", tmp_path / "joined.npz"], small_flipped)
    assert not (tmp_path / "joined.npz").exists()


def test_a_malformed_record_or_array_fails_on_loading(actor_dir, tmp_path):
    with np.load(actor_dir / "actor.npz") as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    cases = {
        "overrides": ({**meta, "scene_overrides": [1, 2]}, arrays),
        "shape": ({**meta, "observation_shapes": {"target": [float("inf")], "heading": [1]}}, arrays),
        "complex": (meta, {**arrays, "w0": arrays["w0"] * (1 + 1j)}),
        "text": (meta, {**arrays, "norm_std": np.array(["1", "1", "1"])}),
    }
    for name, (m, a) in cases.items():
        path = tmp_path / f"{name}.npz"
        np.savez(path, meta=np.array(json.dumps(m)), **a)
        with pytest.raises(PolicyFileError) as err:
            load_actor(path)
        assert str(path) in str(err.value), name


_DAMAGE = st.one_of(
    st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
                                         min_size=1, max_size=4)),
    st.tuples(st.just("overwrite"), st.tuples(st.floats(0, 1, exclude_max=True), st.binary(min_size=1, max_size=64))),
    st.tuples(st.just("cut"), st.floats(0, 1, exclude_max=True)),
    st.tuples(st.just("junk"), st.binary(max_size=256)),
)


def _damaged(data: bytes, damage, start: int = 0) -> bytes:
    """``data`` with one generated damage (``_DAMAGE``) at or after byte ``start``."""
    kind, what = damage
    span = len(data) - start
    if kind == "junk":
        return what
    if kind == "cut":
        return data[: start + int(what * span)]
    out = bytearray(data)
    if kind == "flip":
        for where, bit in what:
            out[start + int(where * span)] ^= 1 << bit
        return bytes(out)
    at = start + int(what[0] * span)
    out[at : at + len(what[1])] = what[1][: len(data) - at]
    return bytes(out)


@settings(max_examples=120, deadline=None)
@given(damage=_DAMAGE)
def test_generated_damage_to_an_actor_file_is_only_a_policy_file_error(actor_dir, damage):
    good = actor_dir / "actor.npz"
    path = actor_dir / "damaged.npz"
    path.write_bytes(_damaged(good.read_bytes(), damage))
    try:
        policy = load_actor(path)
    except PolicyFileError as err:
        assert str(path) in str(err)
    else:  # damage the zip's checks let pass (a timestamp, a comment) leaves the actor as it was
        expected = load_actor(good).act({"target": np.ones(2), "heading": np.ones(1)})
        np.testing.assert_array_equal(policy.act({"target": np.ones(2), "heading": np.ones(1)}), expected)


# -- episode logs --------------------------------------------------------------------------------------------------
def test_a_damaged_summary_section_is_read_past_and_recover_rebuilds_it(small_log, tmp_path, capsys):
    path, live = small_log
    data = path.read_bytes()
    start = _summary_start(data)
    damaged = bytearray(data)
    for i in range(start + 40, start + 56):  # inside the summary's first schema record
        damaged[i] ^= 0xFF
    bad = tmp_path / "summary.mcap"
    bad.write_bytes(bytes(damaged))
    cut = tmp_path / "cut-summary.mcap"
    cut.write_bytes(data[: start + 100])  # the writer killed while it wrote the summary
    for source in (bad, cut):
        log = EpisodeLog(source)
        assert log.summary_damage and not log.truncated
        assert [ep.rescore().result for ep in log.episodes] == live

    assert main(["log", "info", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "summary   damaged" in out and "2 complete" in out
    assert main(["log", "export", str(bad), "--csv", "--out", str(tmp_path / "csv")]) == 0
    with open(tmp_path / "csv" / "summary_episodes.csv") as f:
        assert [float(row["path_length"]) for row in csv.DictReader(f)] == [r.path_length for r in live]

    rec = recover(bad, tmp_path / "fixed.mcap")
    assert rec.summary_damage and not rec.was_truncated
    assert (rec.episodes_complete, rec.episodes_incomplete) == (2, 0)
    fixed = EpisodeLog(rec.path)
    assert not fixed.summary_damage and [ep.rescore().result for ep in fixed.episodes] == live
    assert main(["log", "recover", str(bad), "--out", str(tmp_path / "fixed2.mcap")]) == 0
    assert "summary section damaged" in capsys.readouterr().out


def test_a_chunk_declaring_a_huge_size_is_damage_not_a_memory_error(small_log, tmp_path):
    path, live = small_log
    data = bytearray(path.read_bytes())
    at, chunks = 8, []  # walk the records after the magic: opcode (1 byte), length (8), content
    while data[at] != 0x0F:  # up to the data end record
        length = struct.unpack_from("<Q", data, at + 1)[0]
        if data[at] == 0x06:
            chunks.append(at)
        at += 9 + length
    # a chunk's content: start and end times (8 bytes each), then its uncompressed size
    struct.pack_into("<Q", data, chunks[3] + 9 + 16, 1 << 62)
    bad = tmp_path / "huge.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(LogError, match="damaged .*decompresses to"):
        EpisodeLog(bad)
    rec = recover(bad, tmp_path / "fixed.mcap")
    assert rec.was_truncated and 0 < rec.messages
    for ep in EpisodeLog(rec.path).episodes:
        if ep.complete:
            assert ep.rescore().result == live[ep.index]


def test_a_chunk_whose_data_length_claims_petabytes_is_damage_not_a_memory_error(small_log, tmp_path):
    """The mcap package reads a chunk's data length and then that many bytes: one flipped bit there must read as a
    file cut short, not ask the allocator for 2^48 bytes."""
    path, _ = small_log
    data = bytearray(path.read_bytes())
    at = 8
    while data[at] != 0x06:  # the first chunk record: opcode (1 byte), length (8), content
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    # its content: start and end times, uncompressed size (8 bytes each), CRC (4), compression (4 + its bytes),
    # then the data length (8)
    text = struct.unpack_from("<I", data, at + 9 + 28)[0]
    struct.pack_into("<Q", data, at + 9 + 32 + text, 1 << 48)
    bad = tmp_path / "petabytes.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(LogError, match=str(bad)):
        EpisodeLog(bad)


@settings(max_examples=60, deadline=None)
@given(damage=_DAMAGE, summary_only=st.booleans())
def test_generated_damage_to_a_log_is_only_a_log_error_or_a_faithful_partial_read(small_log, damage, summary_only):
    path, live = small_log
    data = path.read_bytes()
    bad = path.with_name("damaged.mcap")
    bad.write_bytes(_damaged(data, damage, _summary_start(data) if summary_only else 0))
    for allow_truncated in (False, True):
        try:
            log = EpisodeLog(bad, allow_truncated=allow_truncated)
        except LogError as err:
            assert str(bad) in str(err)
            continue
        for ep in log.episodes:  # whatever is read is what was written: the CRCs hold the rest back
            assert [s.step for s in ep.steps] == list(range(len(ep.steps)))
            if ep.complete:
                assert ep.rescore().result == live[ep.index]
    try:
        rec = recover(bad, path.with_name("recovered.mcap"))
    except LogError as err:
        assert str(bad) in str(err) or "recovered.mcap" in str(err)
    else:
        for ep in EpisodeLog(rec.path).episodes:
            if ep.complete:
                assert ep.rescore().result == live[ep.index]


# -- deck-sim render and log video ---------------------------------------------------------------------------------
def test_render_and_log_video_check_their_arguments_before_any_work(small_log, tmp_path, capsys):
    log, _ = small_log
    video = tmp_path / "v.mp4"
    _one_line_error(capsys, ["render", "--out", tmp_path / "noext"], "--out", ".mp4")
    _one_line_error(capsys, ["render", "--out", tmp_path / "v.png"], "--out", ".mp4")
    _one_line_error(capsys, ["render", "--out", video, "--png", tmp_path / "top"], "--png", ".png")
    _one_line_error(capsys, ["render", "--out", video, "--width", 0], "--width", "at least 16")
    _one_line_error(capsys, ["render", "--out", video, "--height", -5], "--height", "at least 16")
    _one_line_error(capsys, ["render", "--out", video, "--steps", -1], "--steps", "at least 1")
    _one_line_error(capsys, ["render", "--out", video, "--speedup", "nan"], "--speedup")
    _one_line_error(capsys, ["log", "video", log, "--out", video, "--width", 0], "--width", "at least 16")
    _one_line_error(capsys, ["log", "video", log, "--out", video, "--max-steps", 0], "--max-steps")
    _one_line_error(capsys, ["log", "video", log, "--out", tmp_path / "noext"], "--out", ".mp4")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_render_and_log_video_check_the_camera_and_sizes_before_the_first_frame(small_log, tmp_path, capsys):
    log, _ = small_log
    video = tmp_path / "v.mp4"
    _one_line_error(capsys, ["render", "--out", video, "--width", 5000], "5000x360", "2400x1200")
    _one_line_error(capsys, ["render", "--out", video, "--top-height", 900], "--top-height", "2400x1200")
    _one_line_error(capsys, ["log", "video", log, "--out", video, "--camera", "nope"],
                    "'nope'", "top, follow, agent/chase")
    _one_line_error(capsys, ["log", "video", log, "--out", video, "--width", 4000], "2400x1200")
    assert list(tmp_path.iterdir()) == []


# -- deck-sim run ----------------------------------------------------------------------------------------------------
def test_run_checks_its_folder_before_the_first_episode(tmp_path, capsys, monkeypatch):
    import deck_sim.rollout

    def never(*args, **kwargs):
        raise AssertionError("an episode was played")

    monkeypatch.setattr(deck_sim.rollout, "run_episode", never)
    afile = tmp_path / "afile"
    afile.write_text("")
    base = ["run", "--policy", "zero", "--episodes", 2, "--quiet", "--no-record"]
    _one_line_error(capsys, [*base, "--out", afile / "sub"], "--out", afile / "sub", "cannot write")
    _one_line_error(capsys, [*base, "--episodes", 0, "--out", tmp_path / "x"], "--episodes")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_episodes_csv_written_as_episodes_end_is_what_a_whole_run_wrote(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["run", "--scene", "deck1", "--policy", "random", "--episodes", "3", "--seed", "5", "--quiet",
            "--no-record", "--out", str(out), "--predictor", "none", "--scene-set", "episode.time_limit=5"]
    assert main(args) == 0
    assert "stopped" not in json.loads((out / "summary.json").read_text())
    # the same episodes, their table written at the end as one piece
    overrides = {**policy_overrides("random", "deck1"), "episode__predictor": "none", "episode__time_limit": 5}
    env = deck_sim.load("deck1", seed=5, **overrides)
    policy = make_policy("random", env, seed=5)
    results = [run_episode(env, policy, episode=k) for k in range(3)]
    assert len({r.outcome for r in results}) > 1 or len({r.reward for r in results}) == 3  # rows that differ
    whole = io.StringIO(newline="")
    writer = csv.DictWriter(whole, fieldnames=list(results[0].as_dict()))
    writer.writeheader()
    writer.writerows(r.as_dict() for r in results)
    assert (out / "episodes.csv").read_bytes() == whole.getvalue().encode()


def _start_run(out):
    """``deck-sim run`` of many scripted episodes in a child process that takes SIGINT as a terminal's Ctrl-C."""
    cmd = [sys.executable, "-m", "deck_sim.cli", "run", "--scene", "deck1", "--policy", "scripted", "--episodes",
           "200", "--seed", "3", "--out", str(out)]
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "MUJOCO_GL": "disable"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a shell's background job ignores it
    )


def _wait_for_rows(child, table, rows: int) -> None:
    """Until ``table`` holds ``rows`` episodes (the child runs on)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if table.exists() and table.read_text().count("\n") >= rows + 1:
            return
        assert child.poll() is None, child.communicate()
        time.sleep(0.05)
    child.kill()
    raise AssertionError(f"no {rows} rows in {table} within 120 s")


def _rows(table):
    with open(table, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_ctrl_c_stops_a_run_and_keeps_the_finished_episodes(tmp_path):
    out = tmp_path / "run"
    child = _start_run(out)
    try:
        _wait_for_rows(child, out / "episodes.csv", 1)
        child.send_signal(signal.SIGINT)
        stdout, stderr = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 130, stderr
    assert "Traceback" not in stderr and "stopped (Ctrl-C) after" in stderr.strip().splitlines()[-1]
    rows = _rows(out / "episodes.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"] is True and summary["episodes_finished"] == len(rows) >= 1
    assert summary["episodes"] == 200 and summary["summary"]["episodes"] == len(rows)
    assert "Stopped by Ctrl-C" in (out / "results.md").read_text() and "wrote" in stdout
    log = EpisodeLog(out / "episodes.mcap")  # closed: a valid file, its last episode incomplete
    assert not log.truncated and [ep.complete for ep in log.episodes][: len(rows)] == [True] * len(rows)
    for row, ep in zip(rows, log.episodes, strict=False):
        assert (ep.rescore().result.outcome, ep.rescore().result.steps) == (row["outcome"], int(row["steps"]))


@pytest.mark.slow
def test_a_killed_run_keeps_the_rows_of_its_finished_episodes(tmp_path):
    out = tmp_path / "run"
    child = _start_run(out)
    try:
        _wait_for_rows(child, out / "episodes.csv", 2)
    finally:
        child.kill()
        child.communicate(timeout=60)
    assert child.returncode == -signal.SIGKILL
    text = (out / "episodes.csv").read_text()
    assert text.endswith("\n")  # whole rows only
    rows = _rows(out / "episodes.csv")
    assert len(rows) >= 2 and not (out / "summary.json").exists()
    log = EpisodeLog(recover(out / "episodes.mcap").path)
    for row in rows:  # every row's episode is whole in the log too
        result = log.rescore(int(row["episode"])).result
        assert (result.outcome, result.steps, repr(result.reward)) == (row["outcome"], int(row["steps"]),
                                                                        row["reward"])
