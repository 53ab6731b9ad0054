"""What an episode log holds: topics, schema names, the JSON state record, events and the time base.

Shared by the writer (``deck_sim.recording.writer``) and the reader (``deck_sim.recording.reader``); numpy and the
standard library only.

Topics (Foxglove well-known schemas in protobuf, recognised by their exact names; ``/agent/state`` is JSON):

    /tf           foxglove.FrameTransforms  frame ``deck`` to ``agent`` and to every mover (frame = mover name),
                                             the bodies' full 3D poses, every step
    /scene        foxglove.SceneUpdate      once per episode: deck outline, static obstacles, target, and the
                                             agent's and movers' boxes locked to their frames; the ``deck``
                                             entity's metadata holds the exact scene (``scene_frame``, JSON)
    /prediction   foxglove.SceneUpdate      every step, one line strip per mover (entity ``prediction/<mover>``):
                                             point 0 is the mover now, points 1..N its predicted positions
    /agent/path   foxglove.SceneUpdate      every step, the agent's path so far (entity ``agent_path``)
    /agent/state  deck_sim.AgentState       every step, JSON: pose, speed, heading, action, reward terms, ...
    /events       foxglove.Log              episode start and end, the outcome (goal, collision, timeout,
                                             off_surface, diverged) and predictor fallbacks; ``name`` is the kind

A log of several aircraft (``deck1-multi`` ...) has, instead of the agent's frame and topics, one frame per
aircraft (frame = its name, ``aircraft_0`` ...) and per aircraft:

    /agent/<name>/path   foxglove.SceneUpdate   every step, that aircraft's path so far (entity ``<name>_path``)
    /agent/<name>/state  deck_sim.AgentState    every step, JSON: its state, with ``agent`` (its name) and ``done``;
                                                 ``x``, ``y`` are where its path stands (where it was done, once done)

``/prediction`` holds one line per mover and per aircraft (``prediction/<name>``), ``/scene`` a target per
aircraft (``target/<name>``), and ``/events`` an outcome event per aircraft (its message names it).

Log time is simulation time: episode k's messages are stamped ``base_k + t`` with t the simulated seconds since
its reset; ``base_0 = 0`` and ``base_k`` is one second after the whole second that follows episode k-1's last
step (``next_base``), so episodes never overlap and each starts on a whole second.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from deck_sim.geometry import Footprints
from deck_sim.types import AircraftStep, SceneFrame, StepFrame, TeamSceneFrame, TeamStepFrame

FORMAT = "deck_sim.episode_log/1"
"""Value of the ``format`` key of the ``deck_sim`` metadata record."""
METADATA_NAME = "deck_sim"
"""Name of the MCAP metadata record describing the run."""

TF, SCENE, PREDICTION, PATH, STATE, EVENTS = "/tf", "/scene", "/prediction", "/agent/path", "/agent/state", "/events"
TOPICS: dict[str, str] = {
    TF: "foxglove.FrameTransforms",
    SCENE: "foxglove.SceneUpdate",
    PREDICTION: "foxglove.SceneUpdate",
    PATH: "foxglove.SceneUpdate",
    STATE: "deck_sim.AgentState",
    EVENTS: "foxglove.Log",
}
"""Schema name of every topic."""

ROOT_FRAME = "deck"
"""The world frame of the log (also the square's)."""
AGENT_FRAME = "agent"

EVENT_KINDS = (
    "episode_start",
    "episode_end",
    "goal",
    "collision",
    "timeout",
    "off_surface",
    "diverged",
    "predictor_fallback",
)
"""Values of ``foxglove.Log.name`` on ``/events``."""

STATE_SCHEMA: dict[str, Any] = {
    "title": "deck_sim.AgentState",
    "description": "The agent's state at one control step of a deck_sim episode (SI units, radians).",
    "type": "object",
    "properties": {
        "episode": {"type": "integer", "description": "episode index in the run"},
        "step": {"type": "integer", "description": "control steps since the reset (0: the reset)"},
        "time": {"type": "number", "description": "simulated seconds since the reset"},
        "x": {"type": "number", "description": "agent position x, m (float64, exact)"},
        "y": {"type": "number", "description": "agent position y, m (float64, exact)"},
        "heading": {"type": "number", "description": "agent yaw, rad"},
        "speed": {"type": "number", "description": "agent forward speed, m/s"},
        "action_x": {
            "type": ["number", "null"],
            "description": "action x in [-1, 1], in the axes of the episode.frame metadata (null at the reset)",
        },
        "action_y": {"type": ["number", "null"], "description": "action y in [-1, 1] (null at the reset)"},
        "r1": {"type": "number", "description": "target attraction (eq. 10-12)"},
        "r2": {"type": "number", "description": "obstacle repulsion (eq. 13-14)"},
        "r3": {"type": "number", "description": "collision term (eq. 15)"},
        "r4": {"type": "number", "description": "goal term (eq. 15)"},
        "total": {"type": "number", "description": "weighted sum, the step's reward (eq. 16)"},
        "distance_to_goal": {"type": "number", "description": "m"},
        "min_clearance": {"type": ["number", "string"], "description": "m to the nearest obstacle"},
        "predictor_fallbacks": {"type": "integer", "description": "movers predicted by constant velocity"},
        "collision": {"type": ["string", "null"], "description": "obstacle touched at this step"},
        "reached_goal": {"type": "boolean"},
        "left_surface": {"type": "boolean"},
        "diverged": {"type": "boolean"},
        "last": {"type": "boolean", "description": "the episode ended at this step"},
        "discount": {"type": ["number", "null"], "description": "0 on termination, 1 otherwise"},
        "agent": {"type": "string", "description": "the aircraft's name (logs of several aircraft)"},
        "done": {"type": "boolean", "description": "the aircraft is done (logs of several aircraft)"},
    },
}
"""JSON Schema of ``/agent/state`` messages (schema encoding ``jsonschema``)."""

NS = 1_000_000_000


def agent_path_topic(name: str) -> str:
    """The path topic of aircraft ``name`` in a log of several aircraft."""
    return f"/agent/{name}/path"


def agent_state_topic(name: str) -> str:
    """The state topic of aircraft ``name`` in a log of several aircraft."""
    return f"/agent/{name}/state"


def is_state_topic(topic: str) -> bool:
    """Whether ``topic`` carries ``deck_sim.AgentState`` messages (``/agent/state`` or an aircraft's)."""
    return topic == STATE or (topic.startswith("/agent/") and topic.endswith("/state"))


def log_time(base_ns: int, t: float) -> int:
    """Log time in nanoseconds of simulated time ``t`` seconds into an episode whose time base is ``base_ns``."""
    return base_ns + int(round(t * NS))


def next_base(base_ns: int, end_ns: int) -> int:
    """Time base of the episode after one with base ``base_ns`` whose last message was at ``end_ns``."""
    return base_ns + ((end_ns - base_ns) // NS + 2) * NS


def number(x: float) -> float | str:
    """A float for JSON: itself when finite, else its name (``inf``, ``-inf``, ``nan``), which JSON cannot hold."""
    x = float(x)
    return x if math.isfinite(x) else repr(x)


def from_number(x: float | str | None) -> float:
    """Inverse of ``number``."""
    return float(x)  # type: ignore[arg-type]


def state_record(frame: StepFrame) -> dict[str, Any]:
    """The ``/agent/state`` message of a step (``STATE_SCHEMA``); floats are written exactly by ``json``."""
    return _record(frame, frame.agent_pose[:2], frame)


def aircraft_state_record(frame: TeamStepFrame, i: int) -> dict[str, Any]:
    """The ``/agent/<name>/state`` message of aircraft ``i`` at a step of several aircraft (``STATE_SCHEMA``): its
    name first, ``x``, ``y`` where its path stands, ``done`` last."""
    a = frame.aircraft[i]
    return {"agent": a.name, **_record(frame, a.track_xy, a), "done": bool(a.done)}


def _record(frame: StepFrame | TeamStepFrame, xy: np.ndarray, own: StepFrame | AircraftStep) -> dict[str, Any]:
    """The fields of a state message: the step's (``frame``) and an aircraft's own (``own``, at ``xy``)."""
    action, terms = own.action, own.reward_terms
    return {
        "episode": int(frame.episode),
        "step": int(frame.step),
        "time": float(frame.time),
        "x": float(xy[0]),
        "y": float(xy[1]),
        "heading": float(own.heading),
        "speed": float(own.speed),
        "action_x": None if action is None else float(action[0]),
        "action_y": None if action is None else float(action[1]),
        "r1": float(terms["r1"]),
        "r2": float(terms["r2"]),
        "r3": float(terms["r3"]),
        "r4": float(terms["r4"]),
        "total": float(terms["total"]),
        "distance_to_goal": number(own.distance_to_goal),
        "min_clearance": number(own.min_clearance),
        "predictor_fallbacks": int(frame.predictor_fallbacks),
        "collision": own.collision,
        "reached_goal": bool(own.reached_goal),
        "left_surface": bool(own.left_surface),
        "diverged": bool(frame.diverged),
        "last": bool(frame.last),
        "discount": None if own.discount is None else float(own.discount),
    }


def _fp(fp: Footprints) -> dict[str, list]:
    return {
        "centers": np.asarray(fp.centers, dtype=float).tolist(),
        "half": np.asarray(fp.half, dtype=float).tolist(),
        "yaw": np.asarray(fp.yaw, dtype=float).tolist(),
        "radius": np.asarray(fp.radius, dtype=float).tolist(),
    }


def _unfp(d: dict[str, list]) -> Footprints:
    return Footprints(
        np.array(d["centers"], dtype=np.float64).reshape(-1, 2),
        np.array(d["half"], dtype=np.float64).reshape(-1, 2),
        np.array(d["yaw"], dtype=np.float64).reshape(-1),
        np.array(d["radius"], dtype=np.float64).reshape(-1),
    )


def scene_to_json(scene: SceneFrame) -> str:
    """The scene frame as JSON (floats written exactly; a ``TeamSceneFrame`` with its aircraft and targets)."""
    team = {}
    if isinstance(scene, TeamSceneFrame):
        team = {"agent_names": list(scene.agent_names),
                "targets_xy": np.asarray(scene.targets_xy, dtype=float).tolist()}
    return json.dumps(
        {
            **team,
            "scene": scene.scene,
            "episode": int(scene.episode),
            "dt": float(scene.dt),
            "bounds": np.asarray(scene.bounds, dtype=float).tolist(),
            "target_xy": np.asarray(scene.target_xy, dtype=float).tolist(),
            "goal_radius": float(scene.goal_radius),
            "agent_radius": float(scene.agent_radius),
            "agent_footprint": _fp(scene.agent_footprint),
            "static_names": list(scene.static_names),
            "statics": _fp(scene.statics),
            "static_poses": np.asarray(scene.static_poses, dtype=float).tolist(),
            "mover_names": list(scene.mover_names),
            "movers": _fp(scene.movers),
        }
    )


def scene_from_json(text: str) -> SceneFrame:
    """Inverse of ``scene_to_json``."""
    d = json.loads(text)
    team = {}
    if "agent_names" in d:
        team = {"agent_names": tuple(d["agent_names"]),
                "targets_xy": np.array(d["targets_xy"], dtype=np.float64).reshape(-1, 2)}
    return (TeamSceneFrame if team else SceneFrame)(
        **team,
        scene=d["scene"],
        episode=int(d["episode"]),
        dt=float(d["dt"]),
        bounds=np.array(d["bounds"], dtype=np.float64).reshape(2, 2),
        target_xy=np.array(d["target_xy"], dtype=np.float64),
        goal_radius=float(d["goal_radius"]),
        agent_radius=float(d["agent_radius"]),
        agent_footprint=_unfp(d["agent_footprint"]),
        static_names=tuple(d["static_names"]),
        statics=_unfp(d["statics"]),
        static_poses=np.array(d["static_poses"], dtype=np.float64).reshape(-1, 3),
        mover_names=tuple(d["mover_names"]),
        movers=_unfp(d["movers"]),
    )
