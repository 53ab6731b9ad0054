"""Cost of recording episode logs (MCAP): per control step, as a fraction of a deck 2 control step, bytes per
simulated minute, and foxglove-sdk's writer against the pure-Python mcap-protobuf writer.

1. Plays ``--episodes`` episodes of deck 2 with the full-knowledge ``ScriptedPolicy`` and the scene's own
   predictor (constant velocity, so that every step has a prediction to log), timing ``env.step`` and the
   reading of the task into frames (``deck_sim.rollout.TaskFrames``), and keeps the frames.
2. Writes the kept frames ``--repeats`` times with ``EpisodeRecorder`` (foxglove-sdk, zstd, the default chunk
   size) and with an equivalent pure-Python writer (mcap + mcap-protobuf-support + foxglove-schemas-protobuf,
   same topics, schemas and message content; checked by re-scoring both files with ``EpisodeLog``); the fastest
   repeat of each is reported.
3. Times deck 2 control steps with predictor ``none`` the way ``benchmarks/prediction.py`` does (the reference
   step), and prints recording (reading frames + writing) as a fraction of it; target <= 10 %.

    python benchmarks/recording.py [--episodes 6] [--seed 7000] [--repeats 5]

Needs the ``bench`` extra (``pip install -e .[bench]``: foxglove-schemas-protobuf) for the writer comparison.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from importlib.metadata import version  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from common import machine  # noqa: E402
from foxglove.messages import Color, Pose, Quaternion, Vector3  # noqa: E402
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms  # noqa: E402
from foxglove_schemas_protobuf.Log_pb2 import Log  # noqa: E402
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate  # noqa: E402
from mcap.writer import CompressionType, Writer  # noqa: E402
from mcap_protobuf.schema import register_schema  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.metrics import outcome_of  # noqa: E402
from deck_sim.policies import ScriptedPolicy  # noqa: E402
from deck_sim.recording import DEFAULT_CHUNK_SIZE, EpisodeLog, EpisodeRecorder, _lines, schema  # noqa: E402
from deck_sim.rollout import TaskFrames, run_metadata  # noqa: E402
from deck_sim.types import SceneFrame, StepFrame  # noqa: E402

Episode = tuple[SceneFrame, list[StepFrame]]


def play(seed: int, episodes: int) -> tuple[list[Episode], list[float], list[float], dict[str, str]]:
    """Play deck 2 episodes; return their frames, the ``env.step`` times and the frame-reading times (s)."""
    env = deck_sim.load("deck2", seed=seed)
    policy = ScriptedPolicy(env)
    frames = TaskFrames(env)
    out: list[Episode] = []
    step_s: list[float] = []
    read_s: list[float] = []
    for k in range(episodes):
        ts = env.reset()
        policy.reset()
        scene, steps = frames.scene(k), [frames.step(ts, None, k, 0)]
        while not ts.last():
            action = policy.act(ts.observation)
            t0 = time.perf_counter()
            ts = env.step(action)
            t1 = time.perf_counter()
            steps.append(frames.step(ts, action, k, len(steps)))
            t2 = time.perf_counter()
            step_s.append(t1 - t0)
            read_s.append(t2 - t1)
        out.append((scene, steps))
    return out, step_s, read_s, run_metadata(env, seed, "scripted", commit="benchmark")


def write_sdk(path: Path, episodes: list[Episode], metadata: dict[str, str]) -> float:
    """Seconds to write every frame with ``EpisodeRecorder`` (foxglove-sdk)."""
    t0 = time.perf_counter()
    with EpisodeRecorder(path, metadata=metadata, overwrite=True) as rec:
        for scene, steps in episodes:
            rec.begin_episode(scene, steps[0])
            for s in steps[1:]:
                rec.record_step(s)
    return time.perf_counter() - t0


class PurePythonRecorder:
    """The messages of ``EpisodeRecorder`` written with mcap's pure-Python writer (zstd, same chunk size), built
    with foxglove-schemas-protobuf objects or (``numpy_encoding``) with ``EpisodeRecorder``'s own numpy encoders.
    The comparisons of this benchmark; not used by deck_sim."""

    def __init__(self, path: Path, metadata: dict[str, str], numpy_encoding: bool = False) -> None:
        self._numpy = numpy_encoding
        self._file = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._w = Writer(self._file, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="benchmark mcap-protobuf")
        ids = {}
        for topic, cls in ((schema.TF, FrameTransforms), (schema.EVENTS, Log)):
            ids[topic] = self._w.register_channel(topic, "protobuf", register_schema(self._w, cls))
        scene_schema = register_schema(self._w, SceneUpdate)
        for topic in (schema.SCENE, schema.PREDICTION, schema.PATH):
            ids[topic] = self._w.register_channel(topic, "protobuf", scene_schema)
        state_schema = self._w.register_schema(
            schema.TOPICS[schema.STATE], "jsonschema", json.dumps(schema.STATE_SCHEMA).encode()
        )
        ids[schema.STATE] = self._w.register_channel(schema.STATE, "json", state_schema)
        self._ids = ids
        self._w.add_metadata(schema.METADATA_NAME, {**metadata, "format": schema.FORMAT})
        self._next_base = 0

    def _add(self, topic: str, t_ns: int, data: bytes) -> None:
        self._w.add_message(self._ids[topic], t_ns, data, t_ns)

    def _event(self, t_ns: int, kind: str, level: int, text: str) -> None:
        m = Log(level=level, message=text, name=kind)
        m.timestamp.FromNanoseconds(t_ns)
        self._add(schema.EVENTS, t_ns, m.SerializeToString())

    def episode(self, scene: SceneFrame, steps: list[StepFrame]) -> None:
        base = self._next_base
        t0 = schema.log_time(base, steps[0].time)
        self._event(t0, "episode_start", Log.INFO, f"episode {scene.episode} start")
        update = SceneUpdate()
        update.deletions.add(type=1).timestamp.FromNanoseconds(t0)
        deck = update.entities.add(frame_id=schema.ROOT_FRAME, id="deck")
        deck.timestamp.FromNanoseconds(t0)
        deck.metadata.add(key="scene_frame", value=schema.scene_to_json(scene))
        (x0, y0), (x1, y1) = scene.bounds.tolist()
        cube = deck.cubes.add()
        cube.pose.position.x, cube.pose.position.y, cube.pose.orientation.w = (x0 + x1) / 2, (y0 + y1) / 2, 1.0
        cube.size.x, cube.size.y, cube.size.z = x1 - x0, y1 - y0, 0.1
        st = scene.statics
        for i, name in enumerate(scene.static_names):
            e = update.entities.add(frame_id=schema.ROOT_FRAME, id=f"static/{name}")
            c = e.cubes.add()
            c.pose.position.x, c.pose.position.y, c.pose.position.z = *st.centers[i].tolist(), 1.5
            c.pose.orientation.z, c.pose.orientation.w = np.sin(st.yaw[i] / 2), np.cos(st.yaw[i] / 2)
            c.size.x, c.size.y, c.size.z = *(2 * (st.half[i] + st.radius[i])).tolist(), 3.0
        for name in (schema.AGENT_FRAME, *scene.mover_names):
            e = update.entities.add(frame_id=name, id=name, frame_locked=True)
            e.cubes.add().size.z = 3.0
        self._add(schema.SCENE, t0, update.SerializeToString())
        path = SceneUpdate()
        line = path.entities.add(frame_id=schema.ROOT_FRAME, id="agent_path").lines.add(thickness=0.5)
        line.pose.orientation.w = 1.0
        names = [schema.AGENT_FRAME, *scene.mover_names]
        if self._numpy:
            self._numpy_steps(base, scene, steps)
        for s in [] if self._numpy else steps:
            t_ns = schema.log_time(base, s.time)
            tf = FrameTransforms()
            for name, p in zip(names, np.vstack([s.agent_pose[None], s.mover_poses]).tolist(), strict=True):
                t = tf.transforms.add(parent_frame_id=schema.ROOT_FRAME, child_frame_id=name)
                t.timestamp.FromNanoseconds(t_ns)
                t.translation.x, t.translation.y, t.translation.z = p[0], p[1], p[2]
                t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z = p[3], p[4], p[5], p[6]
            self._add(schema.TF, t_ns, tf.SerializeToString())
            pred = SceneUpdate()
            for name, p0, pts in zip(scene.mover_names, s.mover_xy.tolist(), s.prediction.tolist(), strict=True):
                e = pred.entities.add(frame_id=schema.ROOT_FRAME, id=f"prediction/{name}")
                e.timestamp.FromNanoseconds(t_ns)
                ln = e.lines.add(thickness=0.4)
                ln.pose.orientation.w = 1.0
                for x, y in (p0, *pts):
                    ln.points.add(x=x, y=y, z=0.3)
            self._add(schema.PREDICTION, t_ns, pred.SerializeToString())
            line.points.add(x=float(s.agent_pose[0]), y=float(s.agent_pose[1]), z=0.3)
            path.entities[0].timestamp.FromNanoseconds(t_ns)
            self._add(schema.PATH, t_ns, path.SerializeToString())
            self._add(schema.STATE, t_ns, json.dumps(schema.state_record(s)).encode())
        last, t_end = steps[-1], schema.log_time(base, steps[-1].time)
        truncated = last.discount is not None and last.discount > 0 and not last.reached_goal
        flags = {"diverged": last.diverged, "collision": last.collision, "left_surface": last.left_surface}
        outcome = outcome_of({**flags, "reached_goal": last.reached_goal}, truncated)
        self._event(t_end, outcome, Log.INFO, f"episode {scene.episode}: {outcome}")
        self._event(t_end, "episode_end", Log.INFO, f"episode {scene.episode} end")
        self._next_base = schema.next_base(base, t_end)

    def _numpy_steps(self, base: int, scene: SceneFrame, steps: list[StepFrame]) -> None:
        identity, blue, red = (
            Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)).encode(),
            Color(r=0.2, g=0.6, b=1.0, a=1.0).encode(),
            Color(r=0.85, g=0.15, b=0.1, a=1.0).encode(),
        )
        transforms = _lines.Transforms(schema.ROOT_FRAME, [schema.AGENT_FRAME, *scene.mover_names])
        ids = [f"prediction/{name}" for name in scene.mover_names]
        prediction = _lines.LineStrips(schema.ROOT_FRAME, ids, identity, 0.4, blue)
        path_line = _lines.LineStrips(schema.ROOT_FRAME, ["agent_path"], identity, 0.5, red)
        path = bytearray()
        for s in steps:
            t_ns = schema.log_time(base, s.time)
            stamp = _lines.stamp(t_ns)
            self._add(schema.TF, t_ns, transforms.encode(stamp, np.vstack([s.agent_pose[None], s.mover_poses])))
            n, horizon = s.prediction.shape[:2]
            xyz = np.empty((n, horizon + 1, 3))
            xyz[:, 0, :2], xyz[:, 1:, :2], xyz[..., 2] = s.mover_xy, s.prediction, 0.3
            fields = _lines.points(xyz)
            size = len(fields) // n
            parts = [fields[i * size : (i + 1) * size] for i in range(n)]
            self._add(schema.PREDICTION, t_ns, prediction.encode(stamp, parts))
            path += _lines.points([s.agent_pose[0], s.agent_pose[1], 0.3])
            self._add(schema.PATH, t_ns, path_line.encode(stamp, [bytes(path)]))
            self._add(schema.STATE, t_ns, json.dumps(schema.state_record(s)).encode())

    def close(self) -> None:
        self._w.finish()
        self._file.close()


def write_pure(path: Path, episodes: list[Episode], metadata: dict[str, str], numpy_encoding: bool = False) -> float:
    """Seconds to write every frame with ``PurePythonRecorder``."""
    t0 = time.perf_counter()
    rec = PurePythonRecorder(path, metadata, numpy_encoding)
    for scene, steps in episodes:
        rec.episode(scene, steps)
    rec.close()
    return time.perf_counter() - t0


def reference_step(seed: int, steps: int, batches: int = 5) -> tuple[float, float]:
    """(fastest, median) over batches of the mean ``env.step`` seconds of deck 2, predictor ``none``, as in
    ``benchmarks/prediction.py``."""
    env = deck_sim.load("deck2", seed=seed, episode__predictor="none")
    policy = ScriptedPolicy(env)
    ts = env.reset()
    policy.reset()
    times = []
    for i in range(steps + 20):
        action = policy.act(ts.observation)
        t0 = time.perf_counter()
        ts = env.step(action)
        dt = time.perf_counter() - t0
        if ts.first():
            policy.reset()
        elif i >= 20:
            times.append(dt)
    means = [float(np.mean(b)) for b in np.array_split(np.array(times), batches)]
    return float(np.min(means)), float(np.median(means))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=6, help="deck 2 episodes to record (default 6)")
    ap.add_argument("--seed", type=int, default=7000, help="environment seed (default 7000)")
    ap.add_argument("--repeats", type=int, default=5, help="writes of the same frames per writer (default 5)")
    ap.add_argument("--reference-steps", type=int, default=1000, help="steps timed for the reference step")
    args = ap.parse_args(argv)

    print(
        "machine:",
        machine(
            mujoco=version("mujoco"),
            foxglove_sdk=version("foxglove-sdk"),
            mcap=version("mcap"),
            mcap_protobuf=version("mcap-protobuf-support"),
        ),
    )
    episodes, step_s, read_s, metadata = play(args.seed, args.episodes)
    n_steps = sum(len(steps) for _, steps in episodes)  # messages per step are written for the reset too
    sim_s = sum(steps[-1].time for _, steps in episodes)
    outcomes = [outcome_of({"reached_goal": s[-1].reached_goal, "collision": s[-1].collision,
                            "left_surface": s[-1].left_surface, "diverged": s[-1].diverged},
                           s[-1].discount is not None and s[-1].discount > 0 and not s[-1].reached_goal)
                for _, s in episodes]  # fmt: skip
    print(
        f"recorded: deck2, {len(episodes)} episodes ({', '.join(outcomes)}), {n_steps} steps, "
        f"{sim_s:.1f} s simulated, 9 movers, horizon {episodes[0][1][0].prediction.shape[1]}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        paths = {k: Path(tmp) / f"{k}.mcap" for k in ("sdk", "pure", "mixed")}
        times: dict[str, list[float]] = {k: [] for k in paths}
        for _ in range(args.repeats):  # interleaved, so that a burst of load elsewhere hits all alike
            times["sdk"].append(write_sdk(paths["sdk"], episodes, metadata))
            times["pure"].append(write_pure(paths["pure"], episodes, metadata))
            times["mixed"].append(write_pure(paths["mixed"], episodes, metadata, numpy_encoding=True))
        best = {k: min(v) for k, v in times.items()}
        size = {k: p.stat().st_size for k, p in paths.items()}
        logs = {k: EpisodeLog(p) for k, p in paths.items()}
        same = all(
            logs[k].rescore(e).result == logs["sdk"].rescore(e).result
            and len(list(logs[k].steps(e))) == len(list(logs["sdk"].steps(e)))
            for k in logs
            for e in range(len(episodes))
        )
    ref_fast, ref_median = reference_step(args.seed + 1, args.reference_steps)
    read_us = 1e6 * float(np.median(read_s))
    per_step = {k: 1e6 * v / n_steps for k, v in best.items()}
    record_us = read_us + per_step["sdk"]
    cv_step_us = 1e6 * float(np.median(step_s))

    print(f"writers ({n_steps} steps x 6 topics, zstd, {DEFAULT_CHUNK_SIZE // 1024} KiB chunks, fastest of "
          f"{args.repeats}; same re-scored content in all three: {'yes' if same else 'NO'}):")  # fmt: skip
    rows = (
        ("sdk", "EpisodeRecorder: foxglove-sdk writer, numpy encoding"),
        ("mixed", "mcap pure-Python writer, the same numpy encoding"),
        ("pure", "mcap-protobuf: pure-Python writer, protobuf objects"),
    )
    for key, label in rows:
        print(f"  {label:54s} {per_step[key]:6.1f} us/step  {size[key] / 1024:7.1f} KiB")
    print(
        f"  pure Python (protobuf objects) / EpisodeRecorder: {best['pure'] / best['sdk']:.2f}x the time; "
        f"pure-Python writer / SDK writer, same encoding: {best['mixed'] / best['sdk']:.2f}x"
    )
    sdk_bytes = size["sdk"]
    print(f"bytes per simulated minute (SDK log): {sdk_bytes / sim_s * 60 / 1024:.1f} KiB")
    print(f"reading the task into frames: {read_us:.1f} us/step (median); recording in all: {record_us:.1f} us/step")
    print(
        f"deck 2 control step, predictor none: {1e6 * ref_fast:.0f} us fastest batch, {1e6 * ref_median:.0f} us "
        f"median; with the constant-velocity predictor (the recorded run): {cv_step_us:.0f} us median"
    )
    frac_fast, frac_median = record_us / (1e6 * ref_fast), record_us / (1e6 * ref_median)
    print(
        f"recording cost: {100 * frac_fast:.1f} % of the fastest, {100 * frac_median:.1f} % of the median deck 2 "
        f"control step (target <= 10 %: {'met' if frac_fast <= 0.10 else 'NOT met'})"
    )


if __name__ == "__main__":
    main()
