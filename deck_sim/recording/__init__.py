"""Episode logs as MCAP for Foxglove: ``EpisodeRecorder`` writes them, ``EpisodeLog`` reads and re-scores them,
``recover`` repairs a log whose writer was killed.

The recorder writes plain frames (``deck_sim.types.SceneFrame``, ``StepFrame``) and imports neither MuJoCo nor the
task: ``deck_sim.rollout`` turns a running task into frames (``TaskFrames``) and records with
``run_episode(..., recorder=...)``. The topics, schemas and time base are described in ``deck_sim.recording.schema``.
"""

from deck_sim.recording.reader import (
    EpisodeLog,
    EpisodeScore,
    LogEvent,
    LoggedEpisode,
    Recovery,
    TopicInfo,
    recover,
)
from deck_sim.recording.records import LogError, TruncatedLogError
from deck_sim.recording.schema import TOPICS
from deck_sim.recording.writer import DEFAULT_CHUNK_SIZE, Attachment, EpisodeRecorder, RecordingError

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "TOPICS",
    "Attachment",
    "EpisodeLog",
    "EpisodeRecorder",
    "EpisodeScore",
    "LogError",
    "LogEvent",
    "LoggedEpisode",
    "RecordingError",
    "Recovery",
    "TopicInfo",
    "TruncatedLogError",
    "recover",
]
