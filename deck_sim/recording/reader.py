"""``EpisodeLog``: read an episode log back (steps, episodes, events), re-score it offline, and ``recover`` a log
whose writer was killed.

Built on the ``mcap`` package: one sequential pass over the file's data section (``mcap.stream_reader.StreamReader``)
collects schemas, channels, messages, metadata and attachments; protobuf messages are decoded with the schemas
stored in the file (``mcap_protobuf.decoder.DecoderFactory``), so reading needs no Foxglove package. Every
failure of the file itself (missing, empty, not MCAP, truncated, corrupt, not a deck_sim log) raises ``LogError``
naming the file and the problem, except damage confined to the summary section (the index that follows the data,
checked against its CRC): the data is read in full, with a warning, and ``recover`` writes a copy with a new
summary.
"""

from __future__ import annotations

import bisect
import json
import logging
import os
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Message
from mcap.writer import CompressionType, Writer
from mcap_protobuf.decoder import DecoderFactory

from deck_sim.metrics import (
    EpisodeResult,
    TeamEpisodeResult,
    outcome_of,
    path_length,
    prediction_errors,
    shortest_path,
    turning_angle,
)
from deck_sim.recording import schema
from deck_sim.recording.records import (
    DECODE_ERRORS,
    LogError,
    read_records,
)
from deck_sim.types import AircraftStep, SceneFrame, StepFrame, TeamSceneFrame, TeamStepFrame

_logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LogEvent:
    """One ``/events`` message.

    Attributes:
        time_ns: Log time, ns (simulation time on the log's time base).
        episode: Index of the episode it belongs to.
        kind: One of ``schema.EVENT_KINDS``.
        level: Foxglove log level name (``INFO``, ``WARNING``, ``ERROR``, ...).
        message: The human-readable text.
    """

    time_ns: int
    episode: int
    kind: str
    level: str
    message: str


@dataclass(frozen=True)
class TopicInfo:
    """A topic of the log: its schema and encodings and how many messages it holds."""

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    count: int


@dataclass(frozen=True)
class EpisodeScore:
    """An episode re-scored from its log alone.

    Attributes:
        result: The same ``EpisodeResult`` as ``deck_sim.rollout.run_episode`` returned live.
        ade: Average displacement error of the movers' predictions, m (NaN without prediction).
        fde: Final displacement error at the horizon, m (NaN without prediction).
        prediction_samples: (step, mover) pairs scored for ADE and FDE.
    """

    result: EpisodeResult
    ade: float
    fde: float
    prediction_samples: int


class LoggedEpisode:
    """One episode of a log: its scene, steps and events (steps are decoded on first use).

    Attributes:
        index: The episode's index in its run.
        start_ns: Log time of its start, ns.
        complete: Whether the log holds its end (a killed writer leaves the last one incomplete).
        scene: What stayed fixed during it.
        events: Its ``/events`` messages.
    """

    def __init__(
        self,
        index: int,
        start_ns: int,
        scene: SceneFrame,
        events: list[LogEvent],
        messages: dict[str, list[tuple[Message, Any]]],
        decode: Callable[[Message], Any],
    ) -> None:
        self.index = index
        self.start_ns = start_ns
        self.scene = scene
        self.events = events
        self.complete = any(e.kind == "episode_end" for e in events)
        self._messages = messages
        self._decode = decode
        self._steps: list[StepFrame] | None = None
        self._team_steps: list[TeamStepFrame] | None = None

    def __repr__(self) -> str:
        steps = len(self.team_steps if self.team else self.steps)
        return f"LoggedEpisode(index={self.index}, complete={self.complete}, steps={steps}, team={self.team})"

    @property
    def team(self) -> bool:
        """Whether the episode has several aircraft (read ``team_steps`` and ``rescore_team``)."""
        return isinstance(self.scene, TeamSceneFrame)

    @property
    def steps(self) -> list[StepFrame]:
        """Every step whose messages the log holds whole, step 0 (the reset) first."""
        if self.team:
            raise LogError(f"episode {self.index} has {len(self.scene.agent_names)} aircraft: read its team_steps "
                           "(and rescore_team)")
        if self._steps is None:
            self._steps = self._decode_steps()
        return self._steps

    @property
    def team_steps(self) -> list[TeamStepFrame]:
        """Every step of an episode of several aircraft whose messages the log holds whole, step 0 first."""
        if not self.team:
            raise LogError(f"episode {self.index} has one aircraft: read its steps (and rescore)")
        if self._team_steps is None:
            self._team_steps = self._decode_team_steps()
        return self._team_steps

    def _poses(self, m: Message, frames: list[str]) -> np.ndarray:
        """(len(frames), 7) the poses of ``frames`` in the ``/tf`` message ``m``."""
        transforms = self._decode(m)
        poses = {
            t.child_frame_id: (t.translation.x, t.translation.y, t.translation.z, t.rotation.w, t.rotation.x,
                               t.rotation.y, t.rotation.z)
            for t in transforms.transforms
        }
        try:
            return np.array([poses[name] for name in frames], dtype=np.float64).reshape(len(frames), 7)
        except KeyError as err:
            raise LogError(f"episode {self.index}: /tf at {m.log_time} ns lacks frame {err}") from None

    def _lines(self, m: Message | None, names: list[str]) -> np.ndarray:
        """(len(names), N, 2) the predicted positions of ``names`` in the ``/prediction`` message ``m``."""
        if m is None:
            return np.zeros((len(names), 0, 2))
        lines = {e.id: e.lines[0].points for e in self._decode(m).entities}
        return np.array(
            [[(q.x, q.y) for q in lines[f"prediction/{name}"][1:]] for name in names], dtype=np.float64
        ).reshape(len(names), -1, 2)

    def _decode_team_steps(self) -> list[TeamStepFrame]:
        scene = self.scene
        names, movers = list(scene.agent_names), list(scene.mover_names)
        tf = {m.log_time: m for m, _ in self._messages.get(schema.TF, [])}
        pred = {m.log_time: m for m, _ in self._messages.get(schema.PREDICTION, [])}
        states = [{m.log_time: state for m, state in self._messages.get(schema.agent_state_topic(name), [])}
                  for name in names]
        steps = []
        for t in sorted(states[0]):
            if t not in tf or any(t not in s for s in states):  # lost with a truncated tail
                continue
            poses = self._poses(tf[t], [*names, *movers])
            aircraft = []
            for i, name in enumerate(names):
                st = states[i][t]
                action = None if st["action_x"] is None else np.array([st["action_x"], st["action_y"]])
                aircraft.append(
                    AircraftStep(
                        name=name,
                        action=action,
                        pose=poses[i],
                        heading=float(st["heading"]),
                        speed=float(st["speed"]),
                        track_xy=np.array([st["x"], st["y"]], dtype=np.float64),
                        reward_terms={k: float(st[k]) for k in ("r1", "r2", "r3", "r4", "total")},
                        distance_to_goal=schema.from_number(st["distance_to_goal"]),
                        min_clearance=schema.from_number(st["min_clearance"]),
                        collision=st["collision"],
                        reached_goal=bool(st["reached_goal"]),
                        left_surface=bool(st["left_surface"]),
                        done=bool(st["done"]),
                        discount=None if st["discount"] is None else float(st["discount"]),
                    )
                )
            first = states[0][t]
            steps.append(
                TeamStepFrame(
                    episode=int(first["episode"]),
                    step=int(first["step"]),
                    time=float(first["time"]),
                    aircraft=tuple(aircraft),
                    mover_poses=poses[len(names):],
                    prediction=self._lines(pred.get(t), [*movers, *names]),
                    predictor_fallbacks=int(first["predictor_fallbacks"]),
                    diverged=bool(first["diverged"]),
                    last=bool(first["last"]),
                )
            )
        return steps

    def rescore_team(self) -> TeamEpisodeResult:
        """Every aircraft's outcome, path, turning angle, reward and clearance, and the team's makespan and
        aircraft-aircraft collisions, from the log alone: equal, field for field, to what
        ``deck_sim.rollout.run_team_episode`` measured live (same float64 inputs, same functions, same order).

        Raises:
            LogError: the episode has one aircraft, or is incomplete.
        """
        if not self.complete:
            raise LogError(f"episode {self.index} is incomplete (the log stops before its end): it cannot be scored")
        steps = self.team_steps
        if not steps or [s.step for s in steps] != list(range(len(steps))):
            raise LogError(f"episode {self.index}: the log's steps are not 0..{len(steps) - 1} in order")
        scene, last = self.scene, steps[-1]
        names = list(scene.agent_names)
        fallbacks = sum(s.predictor_fallbacks for s in steps[1:])
        body_width = float(np.min(scene.agent_footprint.half[0]) + scene.agent_footprint.radius[0])
        results, shortest = [], []
        for i in range(len(names)):
            track, total, done_before = [steps[0].aircraft[i]], 0.0, False
            min_clear = steps[0].aircraft[i].min_clearance
            for s in steps[1:]:
                a = s.aircraft[i]
                total += float(a.reward_terms["total"])
                if not done_before:
                    track.append(a)
                    min_clear = min(min_clear, a.min_clearance)
                done_before = done_before or a.done
            end = last.aircraft[i]
            xy = np.array([a.track_xy for a in track])
            start, target = xy[0], scene.targets_xy[i]
            shortest.append(
                max(shortest_path(scene.statics, body_width, scene.bounds, start, target) - scene.goal_radius, 0.0)
            )
            flags = {"reached_goal": end.reached_goal, "collision": end.collision, "left_surface": end.left_surface,
                     "diverged": last.diverged and not end.done}
            results.append(
                EpisodeResult(
                    scene=scene.scene,
                    episode=self.index,
                    outcome=outcome_of(flags, truncated=not end.done),
                    steps=len(xy) - 1,
                    sim_time=float(steps[len(track) - 1].time if end.done else last.time),
                    reward=total,
                    path_length=path_length(xy),
                    start_target_distance=float(np.linalg.norm(target - start)),
                    turning_angle_deg=float(np.degrees(turning_angle(xy))),
                    min_clearance=float(min_clear),
                    collision_partner=end.collision,
                    predictor_fallbacks=int(fallbacks),
                )
            )
        pairs = {frozenset((name, r.collision_partner)) for name, r in zip(names, results, strict=True)
                 if r.collision_partner in names}
        reached = [r.sim_time for r in results if r.outcome == "goal"]
        return TeamEpisodeResult(
            scene=scene.scene,
            episode=self.index,
            aircraft=tuple(results),
            shortest=tuple(shortest),
            makespan=float(max(reached)) if len(reached) == len(names) else float("nan"),
            aircraft_collisions=len(pairs),
        )

    @property
    def duration(self) -> float:
        """Simulated seconds from the reset to the last step logged."""
        steps = self.team_steps if self.team else self.steps
        return steps[-1].time if steps else 0.0

    @property
    def outcome(self) -> str | None:
        """The outcome event's kind (goal, collision, timeout, off_surface, diverged); ``None`` if incomplete, and
        for an episode of several aircraft (each has its own: ``rescore_team``)."""
        if self.team:
            return None
        for e in self.events:
            if e.kind in ("goal", "collision", "timeout", "off_surface", "diverged"):
                return e.kind
        return None

    def _decode_steps(self) -> list[StepFrame]:
        scene = self.scene
        tf = {m.log_time: m for m, _ in self._messages.get(schema.TF, [])}
        pred = {m.log_time: m for m, _ in self._messages.get(schema.PREDICTION, [])}
        steps = []
        for m, state in self._messages.get(schema.STATE, []):
            if m.log_time not in tf:  # the step's /tf was lost with a truncated tail
                continue
            poses = self._poses(tf[m.log_time], [schema.AGENT_FRAME, *scene.mover_names])
            agent, movers = poses[0], poses[1:]
            prediction = self._lines(pred.get(m.log_time), list(scene.mover_names))
            action = None if state["action_x"] is None else np.array([state["action_x"], state["action_y"]])
            steps.append(
                StepFrame(
                    episode=int(state["episode"]),
                    step=int(state["step"]),
                    time=float(state["time"]),
                    action=action,
                    agent_pose=agent,
                    heading=float(state["heading"]),
                    speed=float(state["speed"]),
                    mover_poses=movers,
                    prediction=prediction,
                    reward_terms={k: float(state[k]) for k in ("r1", "r2", "r3", "r4", "total")},
                    distance_to_goal=schema.from_number(state["distance_to_goal"]),
                    min_clearance=schema.from_number(state["min_clearance"]),
                    predictor_fallbacks=int(state["predictor_fallbacks"]),
                    collision=state["collision"],
                    reached_goal=bool(state["reached_goal"]),
                    left_surface=bool(state["left_surface"]),
                    diverged=bool(state["diverged"]),
                    last=bool(state["last"]),
                    discount=None if state["discount"] is None else float(state["discount"]),
                )
            )
        return steps

    def rescore(self, aircraft: str | None = None) -> EpisodeScore:
        """Success, path length, turning angle, clearance and prediction ADE/FDE from the log alone.

        The result equals, field for field, what ``run_episode`` measured live (same float64 inputs, same
        functions, same order of summation). In an episode of several aircraft, ``aircraft`` names the one to score:
        its result is its row of ``rescore_team`` (the live ``run_team_episode``'s), without prediction errors
        (NaN: what it saw forecast were the others' choices).

        Raises:
            LogError: the episode is incomplete, or ``aircraft`` is missing or unknown in an episode of several (or
                given in an episode of one).
        """
        if self.team:
            names = list(self.scene.agent_names)
            if aircraft not in names:
                raise LogError(f"episode {self.index} has aircraft {', '.join(names)}: name one to score "
                               f"(rescore(aircraft=...)), or score them all with rescore_team(), not {aircraft!r}")
            result = self.rescore_team().aircraft[names.index(aircraft)]
            return EpisodeScore(result=result, ade=float("nan"), fde=float("nan"), prediction_samples=0)
        if aircraft is not None:
            raise LogError(f"episode {self.index} has one aircraft: rescore() takes no aircraft, got {aircraft!r}")
        if not self.complete:
            raise LogError(f"episode {self.index} is incomplete (the log stops before its end): it cannot be scored")
        steps = self.steps
        if not steps or steps[0].step != 0 or [s.step for s in steps] != list(range(len(steps))):
            raise LogError(f"episode {self.index}: the log's steps are not 0..{len(steps) - 1} in order")
        xy = np.array([s.agent_xy for s in steps])
        total = 0.0
        min_clear = steps[0].min_clearance
        fallbacks = 0
        for s in steps[1:]:
            total += float(s.reward_terms["total"])
            min_clear = min(min_clear, s.min_clearance)
            fallbacks += s.predictor_fallbacks
        last = steps[-1]
        truncated = last.discount is not None and last.discount > 0 and not last.reached_goal
        flags = {
            "diverged": last.diverged,
            "collision": last.collision,
            "left_surface": last.left_surface,
            "reached_goal": last.reached_goal,
        }
        result = EpisodeResult(
            scene=self.scene.scene,
            episode=self.index,
            outcome=outcome_of(flags, truncated),
            steps=last.step,
            sim_time=float(last.time),
            reward=total,
            path_length=path_length(xy),
            start_target_distance=float(np.linalg.norm(self.scene.target_xy - xy[0])),
            turning_angle_deg=float(np.degrees(turning_angle(xy))),
            min_clearance=float(min_clear),
            collision_partner=last.collision,
            predictor_fallbacks=int(fallbacks),
        )
        ade, fde, samples = prediction_errors(
            np.stack([s.prediction for s in steps]), np.stack([s.mover_xy for s in steps])
        )
        return EpisodeScore(result=result, ade=ade, fde=fde, prediction_samples=samples)


class EpisodeLog:
    """An episode log written by ``EpisodeRecorder``, read whole on construction.

    A log whose data section is whole but whose summary section (the index after the data) is damaged or cut is
    read in full from its data section: ``summary_damage`` says where, and a warning is logged (other MCAP readers
    need the summary: ``recover`` writes a copy with a new one).

    Args:
        path: The ``.mcap`` file.
        allow_truncated: Read what a truncated log holds instead of raising ``TruncatedLogError``.

    Attributes:
        path: The file.
        truncated: The data section ends early, cut or damaged (only with ``allow_truncated``).
        summary_damage: Where and how the summary section is damaged ("" if it is whole).
        metadata: The run's ``deck_sim`` metadata record (scene, seed, predictor, policy, versions, ...).
        attachments: Stored files by name: (media type, bytes).
        library: The writer's library string from the MCAP header.

    Raises:
        LogError: the file is missing, empty, not MCAP, damaged or not a deck_sim log.
        TruncatedLogError: the file ends before its footer (and ``allow_truncated`` is false).
    """

    def __init__(self, path: str | os.PathLike[str], allow_truncated: bool = False) -> None:
        self.path = Path(path)
        raw = read_records(self.path, allow_truncated)
        self.truncated = not raw.complete
        self.summary_damage = raw.summary_damage
        if raw.summary_damage:
            _logger.warning(
                "%s: the summary section (the index after the data) is damaged at %s; the data section is whole and "
                "was read in full. `deck-sim log recover %s` writes a copy with a new summary",
                self.path,
                raw.summary_damage,
                self.path,
            )
        self.library = raw.header.library if raw.header else ""
        records = {m.name: dict(m.metadata) for m in raw.metadata}
        if schema.METADATA_NAME not in records:
            raise LogError(
                f"{self.path}: an MCAP file but not a deck_sim episode log (no '{schema.METADATA_NAME}' metadata "
                "record)"
            )
        self.metadata: dict[str, str] = records[schema.METADATA_NAME]
        self.attachments: dict[str, tuple[str, bytes]] = {a.name: (a.media_type, a.data) for a in raw.attachments}
        self._raw = raw
        self._decode()

    def _decode(self) -> None:
        raw = self._raw
        factory = DecoderFactory()
        decoders: dict[int, Any] = {}
        counts: dict[int, int] = defaultdict(int)
        for ch in raw.channels.values():
            sch = raw.schemas.get(ch.schema_id)
            if ch.message_encoding == "json":
                decoders[ch.id] = json.loads
            else:
                try:
                    decoders[ch.id] = factory.decoder_for(ch.message_encoding, sch)
                except DECODE_ERRORS as err:
                    raise LogError(f"{self.path}: cannot decode topic {ch.topic}: {err}") from None
        by_topic: dict[str, list[tuple[Message, Any]]] = defaultdict(list)
        for m in raw.messages:
            ch = raw.channels.get(m.channel_id)
            decode = decoders.get(m.channel_id)
            if ch is None or decode is None:
                raise LogError(f"{self.path}: message on unknown or undecodable channel {m.channel_id}")
            counts[m.channel_id] += 1
            if ch.topic in (schema.EVENTS, schema.SCENE) or schema.is_state_topic(ch.topic):
                try:
                    by_topic[ch.topic].append((m, decode(m.data)))
                except DECODE_ERRORS as err:
                    raise LogError(
                        f"{self.path}: a {ch.topic} message at {m.log_time} ns does not decode: {err}"
                    ) from None
            else:
                by_topic[ch.topic].append((m, None))  # decoded per episode, on demand
        self._decoders = decoders
        self.topics: dict[str, TopicInfo] = {}
        for ch in raw.channels.values():
            sch = raw.schemas.get(ch.schema_id)
            self.topics[ch.topic] = TopicInfo(
                topic=ch.topic,
                schema_name=sch.name if sch else "",
                schema_encoding=sch.encoding if sch else "",
                message_encoding=ch.message_encoding,
                count=counts[ch.id],
            )
        # episodes start at their episode_start event; every message belongs to the last start before it
        starts = sorted(
            (m.log_time, i) for i, (m, log) in enumerate(by_topic.get(schema.EVENTS, [])) if log.name == "episode_start"
        )
        start_times = [t for t, _ in starts]
        grouped: list[dict[str, list[tuple[Message, Any]]]] = [defaultdict(list) for _ in starts]
        for topic, items in by_topic.items():
            for m, msg in items:
                k = bisect.bisect_right(start_times, m.log_time) - 1
                if k < 0:
                    raise LogError(f"{self.path}: a {topic} message at {m.log_time} ns precedes every episode start")
                grouped[k][topic].append((m, msg))
        self._episodes: list[LoggedEpisode] = []
        for (t0, _), msgs in zip(starts, grouped, strict=True):
            scenes = msgs.get(schema.SCENE, [])
            states = [m for topic, items in msgs.items() if schema.is_state_topic(topic) for m in items]
            if not scenes or not states:
                continue  # the writer was killed before the episode's scene or first step reached the disk
            deck = next((e for e in scenes[0][1].entities if e.id == "deck"), None)
            frame = next((kv.value for kv in deck.metadata if kv.key == "scene_frame"), None) if deck else None
            if frame is None:
                raise LogError(f"{self.path}: the /scene message at {t0} ns lacks the deck entity's scene_frame")
            scene = schema.scene_from_json(frame)
            events = [
                LogEvent(m.log_time, scene.episode, log.name, _level_name(log.level), log.message)
                for m, log in msgs.get(schema.EVENTS, [])
            ]
            self._episodes.append(LoggedEpisode(scene.episode, t0, scene, events, msgs, self._decode_message))

    def _decode_message(self, m: Message) -> Any:
        try:
            return self._decoders[m.channel_id](m.data)
        except DECODE_ERRORS as err:
            topic = self._raw.channels[m.channel_id].topic
            raise LogError(f"{self.path}: a {topic} message at {m.log_time} ns does not decode: {err}") from None

    # -- public ------------------------------------------------------------------------------------------
    @property
    def episodes(self) -> list[LoggedEpisode]:
        """Every episode the log holds, in order (the last may be incomplete)."""
        return list(self._episodes)

    def episode(self, index: int) -> LoggedEpisode:
        """The episode with this index (its ``index``, the run's episode number)."""
        for ep in self._episodes:
            if ep.index == index:
                return ep
        raise LogError(f"{self.path}: no episode {index}; the log holds {[e.index for e in self._episodes]}")

    def steps(self, episode: int | None = None) -> Iterator[StepFrame]:
        """Every step of one episode, or of all episodes in order."""
        for ep in self._episodes if episode is None else [self.episode(episode)]:
            yield from ep.steps

    def events(self, episode: int | None = None) -> Iterator[LogEvent]:
        """Every event of one episode, or of all episodes in order."""
        for ep in self._episodes if episode is None else [self.episode(episode)]:
            yield from ep.events

    def rescore(self, episode: int, aircraft: str | None = None) -> EpisodeScore:
        """``LoggedEpisode.rescore`` of one episode (of one of its aircraft, where it has several)."""
        return self.episode(episode).rescore(aircraft)

    def rescore_team(self, episode: int) -> TeamEpisodeResult:
        """``LoggedEpisode.rescore_team`` of one episode of several aircraft."""
        return self.episode(episode).rescore_team()

    @property
    def duration(self) -> float:
        """Simulated seconds of all episodes together."""
        return float(sum(ep.duration for ep in self._episodes))


def _level_name(level: int) -> str:
    names = {0: "UNKNOWN", 1: "DEBUG", 2: "INFO", 3: "WARNING", 4: "ERROR", 5: "FATAL"}
    return names.get(int(level), str(level))


@dataclass(frozen=True)
class Recovery:
    """What ``recover`` kept.

    Attributes:
        path: The valid log written.
        was_truncated: The source's data section ended early (cut or damaged).
        messages: Messages copied.
        episodes_complete: Complete episodes in the copy.
        episodes_incomplete: Episodes whose end was lost (0 or 1).
        stopped_at: Where and why reading the source stopped ("" if its data section was whole).
        summary_damage: Where and how the source's summary section was damaged ("" if it was whole); the copy has
            a new one.
    """

    path: Path
    was_truncated: bool
    messages: int
    episodes_complete: int
    episodes_incomplete: int
    stopped_at: str
    summary_damage: str = ""


def recover(path: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> Recovery:
    """Copy every complete record of a (truncated or damaged) log's data section into a new, valid MCAP file,
    with a new summary section.

    Args:
        path: The damaged log.
        out: Where to write the copy (default: beside it, ``<name>.recovered.mcap``); must differ from ``path``.

    Raises:
        LogError: the source is missing, not MCAP, or holds no deck_sim metadata, or what it holds does not make
            an episode log; or ``out`` is ``path``.
    """
    src = Path(path)
    dst = Path(out) if out is not None else src.with_name(src.stem + ".recovered.mcap")
    if dst.resolve() == src.resolve():
        raise LogError(f"{src}: recover writes a new file; give an output path other than the source")
    raw = read_records(src, allow_truncated=True)
    if not any(m.name == schema.METADATA_NAME for m in raw.metadata):
        raise LogError(f"{src}: not a deck_sim episode log (no '{schema.METADATA_NAME}' metadata record)")
    with open(dst, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        library = raw.header.library if raw.header else ""
        writer.start(profile=raw.header.profile if raw.header else "", library=f"{library}; recovered by deck_sim")
        for m in raw.metadata:
            writer.add_metadata(m.name, dict(m.metadata))
        for a in raw.attachments:
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in sorted(raw.schemas.items())}
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in sorted(raw.channels.items())
        }
        copied = [m for m in raw.messages if m.channel_id in channel_ids]  # (a message needs its channel)
        for m in copied:
            writer.add_message(channel_ids[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
        writer.finish()
    log = EpisodeLog(dst)
    complete = sum(ep.complete for ep in log.episodes)
    return Recovery(
        path=dst,
        was_truncated=not raw.complete,
        messages=len(copied),
        episodes_complete=complete,
        episodes_incomplete=len(log.episodes) - complete,
        stopped_at=raw.stopped_at,
        summary_damage=raw.summary_damage,
    )
