"""Plain data shared by every layer of deck_sim (numpy and the numpy-only ``deck_sim.geometry``).

Units are SI throughout: metres, seconds, radians. The world frame has x along the deck from stern to bow,
y to port and z up; planar quantities are (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np

from deck_sim.geometry import Footprints

if TYPE_CHECKING:
    from deck_sim.control.tracking import AircraftLimits


class ObstacleKind(IntEnum):
    """How a dynamic obstacle moves; predictors pick a kinematic model from this."""

    WHEELED = 0
    """Non-holonomic vehicle (deck tractor, taxiing aircraft): unicycle with bounded acceleration and turn rate."""
    PEDESTRIAN = 1
    """Holonomic walker with bounded acceleration."""


@dataclass(frozen=True)
class ObstacleTracks:
    """What a predictor may see of the dynamic obstacles at one control step.

    Attributes:
        dt: Seconds between consecutive samples (the task's decision period).
        positions: (n, H, 2) observed planar positions in metres, oldest first; ``positions[:, -1]`` is now.
            At the start of an episode the task pads the history with the first observed position.
        kinds: (n,) ``ObstacleKind`` values.
        future: (n, N, 2) true future positions at ``dt`` spacing, filled by the task only for predictors
            whose ``needs_future`` is true (the oracle); ``None`` otherwise.
    """

    dt: float
    positions: np.ndarray
    kinds: np.ndarray
    future: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of obstacles."""
        return int(self.positions.shape[0])

    @property
    def current(self) -> np.ndarray:
        """(n, 2) positions now."""
        return self.positions[:, -1, :]


@dataclass(frozen=True)
class Prediction:
    """A predictor's answer: every obstacle's next N positions.

    Attributes:
        positions: (n, N, 2) predicted positions in metres at ``dt, 2 dt, ..., N dt`` from now. N may be 0 (the
            ``none`` predictor).
        fallback: (n,) bool, true where the predictor fell back to constant velocity for that obstacle.
    """

    positions: np.ndarray
    fallback: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def horizon(self) -> int:
        """Number of predicted steps N."""
        return int(self.positions.shape[1])

    @property
    def n_fallbacks(self) -> int:
        """How many obstacles fell back to constant velocity in this call."""
        return int(np.count_nonzero(self.fallback))


@dataclass(frozen=True)
class PlannerView:
    """Everything a full-knowledge planner may see at one step (what the scripted policy plans from).

    Positions in metres (world frame), angles in radians, speeds in m/s.
    """

    agent_xy: np.ndarray
    agent_yaw: float
    agent_speed: float
    agent_radius: float
    """Radius of the disc standing for the agent."""
    target_xy: np.ndarray
    goal_radius: float
    statics: Footprints
    """Static obstacles, the arena's own (the island) included."""
    movers: Footprints
    """Movers now."""
    mover_future: np.ndarray
    """(n, N, 2) the task's prediction of the movers (the true future when the task runs the oracle)."""
    bounds: np.ndarray
    """((xmin, ymin), (xmax, ymax)) of the surface."""
    reach: float
    """Metres per unit action."""
    period: float
    """Seconds per decision."""
    agent_circles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(k, 3) circles (x forward, y left, radius; metres, in the agent's own frame) at the ends of the agent's
    body that stick out of its disc: an aircraft's nose and tail (``geometry.end_circles``). Empty for a walker."""
    agent_limits: AircraftLimits | None = None
    """How the agent turns and speeds up when it is a wheeled aircraft (the tracker's limits); None for a walker,
    which moves as it is asked."""


@dataclass(frozen=True)
class SceneFrame:
    """What stays fixed during one episode, as an episode log records it (``deck_sim.recording``).

    Positions in metres (world frame), angles in radians. Obstacle footprints follow ``Footprints``: rounded
    rectangles of half-extents ``half`` grown by ``radius``.

    Attributes:
        scene: Scene name (``SceneSpec.name``).
        episode: Index of the episode in its run.
        dt: Seconds between control steps.
        bounds: ((xmin, ymin), (xmax, ymax)) of the surface; leaving it ends an episode.
        target_xy: (2,) the target.
        goal_radius: The episode succeeds within this distance of the target.
        agent_radius: Radius of the disc that stands for the agent in clearances and rewards.
        agent_footprint: The agent's own footprint in its body frame: (1,) row of centre offset, half, radius.
        static_names: Name of every static obstacle, the arena's own (the island) last.
        statics: Footprints of the static obstacles, in ``static_names`` order.
        static_poses: (m, 3) x, y, yaw of every static obstacle's body (for props: the pose that places them).
        mover_names: Name of every mover (its frame in the log).
        movers: Footprints of the movers in their body frames (centres are offsets from the body, yaw 0).
    """

    scene: str
    episode: int
    dt: float
    bounds: np.ndarray
    target_xy: np.ndarray
    goal_radius: float
    agent_radius: float
    agent_footprint: Footprints
    static_names: tuple[str, ...]
    statics: Footprints
    static_poses: np.ndarray
    mover_names: tuple[str, ...]
    movers: Footprints


@dataclass(frozen=True)
class StepFrame:
    """The state of one control step, as an episode log records it (``deck_sim.recording``).

    Step 0 is the state right after the reset (no action, no reward). Positions in metres (float64, exactly as
    the task computed them), angles in radians, speeds in m/s, times in seconds since the episode's start.

    Attributes:
        episode: Index of the episode in its run.
        step: Control steps since the reset.
        time: Simulated time, s.
        action: (2,) the action that led to this step, in [-1, 1]^2; ``None`` at step 0.
        agent_pose: (7,) the agent's body: x, y, z, then the orientation quaternion w, x, y, z.
        heading: The agent's yaw.
        speed: The agent's forward speed.
        mover_poses: (n, 7) every mover's body pose, same layout as ``agent_pose``.
        prediction: (n, N, 2) the predictor's positions of every mover at dt, 2 dt, ... N dt from now.
        reward_terms: r1, r2, r3, r4 and their weighted sum ``total`` (paper eq. 10-16) of this step.
        distance_to_goal: Distance from the agent to the target.
        min_clearance: Clearance from the agent's disc to the nearest obstacle.
        predictor_fallbacks: Movers whose prediction fell back to constant velocity at this step.
        collision: Name of the obstacle the agent touched at this step, if any.
        reached_goal: The agent reached the target.
        left_surface: The agent left the surface.
        diverged: The physics diverged.
        last: The episode ended at this step.
        discount: The environment's discount (0 on termination, 1 otherwise; ``None`` at step 0).
    """

    episode: int
    step: int
    time: float
    action: np.ndarray | None
    agent_pose: np.ndarray
    heading: float
    speed: float
    mover_poses: np.ndarray
    prediction: np.ndarray
    reward_terms: dict[str, float]
    distance_to_goal: float
    min_clearance: float
    predictor_fallbacks: int
    collision: str | None
    reached_goal: bool
    left_surface: bool
    diverged: bool
    last: bool
    discount: float | None

    @property
    def agent_xy(self) -> np.ndarray:
        """(2,) the agent's position."""
        return self.agent_pose[:2]

    @property
    def mover_xy(self) -> np.ndarray:
        """(n, 2) the movers' positions."""
        return self.mover_poses[:, :2]


@dataclass(frozen=True)
class TeamSceneFrame(SceneFrame):
    """What stays fixed during one episode of several aircraft (``deck_sim.tasks.multi``), as a log records it.

    The fields of ``SceneFrame`` (``target_xy`` is the first aircraft's target; every aircraft has
    ``agent_footprint``, ``agent_radius`` and ``goal_radius``), and:

    Attributes:
        agent_names: The aircraft's names, ``aircraft_0`` ... (their frames and topics in the log).
        targets_xy: (k, 2) every aircraft's target, in ``agent_names`` order.
    """

    agent_names: tuple[str, ...] = ()
    targets_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


@dataclass(frozen=True)
class AircraftStep:
    """One aircraft's part of a ``TeamStepFrame`` (units as ``StepFrame``'s).

    Attributes:
        name: The aircraft's name.
        action: (2,) its action that led to this step; ``None`` at step 0 and once it is done.
        pose: (7,) its body: x, y, z, then the orientation quaternion w, x, y, z.
        heading: Its yaw.
        speed: Its forward speed.
        track_xy: (2,) where its path stands: its position while it taxis, where it was done (``done_position``)
            from the step it was done on (its body then waits on the apron beyond the stern).
        reward_terms: r1 ... r4 and ``total`` of this step (zeros once it is done).
        distance_to_goal: Distance from it to its target (at the step it was done, from then on).
        min_clearance: Clearance from its disc to the nearest obstacle (likewise).
        collision: What it touched, if it collided.
        reached_goal: It reached its target.
        left_surface: It left the surface.
        done: It is done (at this step or before).
        discount: 0 once it is done, 1 otherwise (``None`` at step 0).
    """

    name: str
    action: np.ndarray | None
    pose: np.ndarray
    heading: float
    speed: float
    track_xy: np.ndarray
    reward_terms: dict[str, float]
    distance_to_goal: float
    min_clearance: float
    collision: str | None
    reached_goal: bool
    left_surface: bool
    done: bool
    discount: float | None


@dataclass(frozen=True)
class TeamStepFrame:
    """The state of one control step of several aircraft, as an episode log records it.

    Attributes:
        episode: Index of the episode in its run.
        step: Control steps since the reset.
        time: Simulated time, s.
        aircraft: Every aircraft's part, in ``TeamSceneFrame.agent_names`` order.
        mover_poses: (n, 7) every mover's body pose.
        prediction: (n + k, N, 2) the predictor's positions of every mover, then of every aircraft.
        predictor_fallbacks: Rows whose prediction fell back to constant velocity at this step.
        diverged: The physics diverged.
        last: The episode ended at this step.
    """

    episode: int
    step: int
    time: float
    aircraft: tuple[AircraftStep, ...]
    mover_poses: np.ndarray
    prediction: np.ndarray
    predictor_fallbacks: int
    diverged: bool
    last: bool

    @property
    def mover_xy(self) -> np.ndarray:
        """(n, 2) the movers' positions."""
        return self.mover_poses[:, :2]
