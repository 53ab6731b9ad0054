"""Plain data shared by every layer of deck_sim (numpy and the numpy-only ``deck_sim.geometry``).

Units are SI throughout: metres, seconds, radians. The world frame has x along the deck from stern to bow,
y to port and z up; planar quantities are (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from deck_sim.geometry import Footprints


class ObstacleKind(IntEnum):
    """How a dynamic obstacle moves; predictors pick a kinematic model from this."""

    WHEELED = 0
    """Non-holonomic vehicle (deck tractor, taxiing aircraft): unicycle with bounded acceleration and turn rate."""
    PEDESTRIAN = 1
    """Holonomic walker with bounded acceleration."""


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: position in metres and heading (yaw about z, from +x towards +y) in radians."""

    x: float
    y: float
    yaw: float

    @property
    def xy(self) -> np.ndarray:
        """Position as a (2,) float64 array."""
        return np.array([self.x, self.y], dtype=np.float64)


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
