"""Settings of the MPC predictor (``deck_sim.control.mpc_predictor``): the movers' models and every tuning value.

A ``MPCPredictorSettings`` is frozen and hashable: the predictor builds (and compiles) one CasADi Function per
distinct settings value, and the compiled library's cache key covers everything the settings put into the
generated C source.
"""

from __future__ import annotations

from dataclasses import dataclass, field

N_ESTIMATE = 6
"""Length of a mover's state estimate: position x, y (m), heading (rad), speed (m/s), acceleration (m/s^2),
turn rate (rad/s)."""
N_INFO = 8
"""Length of a mover's info vector: chosen spot (-1 none), its belief, stopped, at a spot, speed m/s,
heading rad, acceleration m/s^2, turn rate rad/s."""


@dataclass(frozen=True)
class MoverModel:
    """Limits and behaviour of one kind of mover, as the predictor assumes them."""

    max_speed: float
    """Largest speed, m/s."""
    max_accel: float
    """Acceleration used when the mover speeds up towards its cruise speed, m/s^2."""
    brake_decel: tuple[float, float]
    """Range (lo, hi) of the braking deceleration movers use to stop at a spot, m/s^2."""
    max_turn_rate: float
    """Largest turn rate, rad/s (wheeled movers; pedestrians are holonomic and ignore it)."""
    cruise_speed: tuple[float, float]
    """Range (lo, hi) of the cruise speeds movers pick at every departure, m/s."""
    heading_gain: float = 1.5
    """Turn rate commanded per radian of bearing error to the spot in the rollout, 1/s."""
    speed_time_constant: float = 0.5
    """Time constant of the rollout's speed tracking, s."""
    yield_distance: float = 0.0
    """A mover stops while another mover is less than this far ahead of it (centre to centre), m; 0: never."""
    yield_width: float = 0.0
    """... and less than this far to the side of its line of travel, m."""
    yield_time: float = 4.0
    """... for at most this long, then goes anyway, s."""


@dataclass(frozen=True)
class MPCPredictorSettings:
    """Everything the MPC predictor needs; frozen and hashable (one built Function per distinct value)."""

    horizon: int = 10
    """Number of predicted steps N, each ``dt`` seconds apart."""
    dt: float = 0.5
    """Seconds between samples, in the history and in the prediction (the task's decision period)."""
    history: int = 10
    """Samples of history used (the last ``history`` of the tracks); tracks must hold at least this many."""
    max_spots: int = 16
    """Capacity for special spots compiled into the Function; ``reset`` refuses more."""
    max_movers: int = 16
    """Capacity for movers that others may yield to, compiled into the Function; ``predict`` refuses more."""

    # Moving-horizon estimation.
    estimation_window: int = 5
    """Most recent samples fitted by the moving-horizon estimator (at most ``history``, at least 3)."""
    forgetting: float = 0.6
    """Weight of a sample j periods old in the fit is ``forgetting**j`` (0 < forgetting <= 1)."""
    gauss_newton_iterations: int = 2
    """Fixed number of damped Gauss-Newton iterations from each start."""
    damping: float = 1e-6
    """Levenberg damping added to the Gauss-Newton normal matrix, in the residuals' units (m^2)."""
    accel_weight: float = 0.01
    """Prior weight pulling the estimated acceleration to zero, (m / (m/s^2))^2."""
    turn_rate_weight: float = 0.1
    """Prior weight pulling the estimated turn rate to zero, (m / (rad/s))^2."""
    estimation_substeps: int = 1
    """RK4 substeps per period when the estimator integrates the model back over the window."""

    # Movers.
    wheeled: MoverModel = field(
        default_factory=lambda: MoverModel(
            max_speed=6.0,
            max_accel=1.0,
            brake_decel=(1.0, 1.5),
            max_turn_rate=0.6,
            cruise_speed=(2.0, 5.0),
            yield_distance=10.0,
            yield_width=3.0,
            yield_time=2.0,
        )
    )
    """Model of wheeled movers (deck tractors): unicycle."""
    pedestrian: MoverModel = field(
        default_factory=lambda: MoverModel(
            max_speed=2.0,
            max_accel=1.0,
            brake_decel=(0.8, 1.2),
            max_turn_rate=3.0,
            cruise_speed=(1.0, 1.6),
            heading_gain=3.0,
            speed_time_constant=0.4,
        )
    )
    """Model of pedestrians: holonomic point."""

    # Intent belief.
    belief_decay: float = 0.8
    """Each step the log-belief is multiplied by this before the new log-likelihood is added (0..1)."""
    heading_sigma: float = 0.25
    """Standard deviation of a mover's heading about the bearing to its spot, rad."""
    speed_noise: float = 0.1
    """Speed uncertainty widening the heading likelihood of slow movers: var += (speed_noise / v)^2, m/s."""
    lateral_sigma: float = 0.5
    """Standard deviation of a spot's lateral offset from the line of travel of a mover heading to it, m."""
    heading_floor: float = 0.15
    """Likelihood floor of the heading term (detours around obstacles point away from the spot)."""
    turn_lookahead: float = 1.0
    """Seconds of the current turn rate added to the heading before comparing it with a spot's bearing, s."""
    brake_sigma: float = 0.3
    """Standard deviation of the observed deceleration about the one needed to stop at a spot, m/s^2."""
    brake_sigma_rel: float = 0.25
    """Part of that deviation proportional to the needed deceleration (estimates lag as braking starts)."""
    brake_margin: float = 0.2
    """Tolerance added to the braking range when judging whether a mover should already be braking, m/s^2."""
    brake_floor: float = 0.02
    """Likelihood floor of a spot the mover should already be braking for but is not."""
    free_keeps_braking: bool = True
    """Under "none", a braking mover keeps braking at the rate seen to a stop (else it holds its speed)."""
    brake_threshold: float = 0.3
    """Deceleration above which a mover counts as braking, m/s^2."""
    none_loglik: float = -4.0
    """Log-likelihood per step of the "heading to no spot" hypothesis (on the spots' scale: 0 is perfect)."""
    at_spot_radius: float = 4.0
    """A mover stopped within this distance of a spot is at that spot, m."""
    stop_speed: float = 0.25
    """A mover whose newest displacement is below ``stop_speed * dt`` (plus noise) is standing still, m/s."""
    stop_samples: int = 1
    """How many newest displacements must be below that for a mover to count as standing (1 or 2)."""
    position_noise: float = 0.01
    """Standard deviation of the noise on observed positions, m (widens the standing-still test)."""

    # Cruise speed.
    cruise_accel_threshold: float = 0.2
    """Movers with |accel| below this and |turn rate| below ``cruise_turn_threshold`` cruise, m/s^2."""
    cruise_turn_threshold: float = 0.1
    """See ``cruise_accel_threshold``, rad/s."""
    cruise_memory: int = 8
    """Cruise speed is the running mean of the last ``cruise_memory`` cruising speed estimates."""

    # Rollout.
    steady_line_window: int = 4
    """While a mover holds its speed and heading, the rollout starts from a straight-line fit over this many
    samples rather than from the moving-horizon estimate (0: always the estimate)."""
    detour_heading_gain: float = 0.15
    """Rollout turn rate per radian of bearing error to the spot while the mover is not yet turning towards
    it (it may be on a straight detour leg around something the predictor cannot see), 1/s. While it turns
    towards the spot, brakes, is near it or is slower than ``steer_speed``, the model's ``heading_gain``
    applies."""
    steer_time: float = 5.0
    """Within ``speed * steer_time`` metres of the spot the rollout steers at it with the full gain, s."""
    steer_speed: float = 1.0
    """Below this speed (departing) the rollout steers at the spot with the full heading gain, m/s."""
    rollout_substeps: int = 1
    """Model integration substeps per predicted step."""
    stop_offset: float = 0.2
    """Movers stop this far short of the spot's centre, m."""

    # Compilation.
    compile: str = "auto"
    """"auto": generate C, compile it with ``compiler`` into the cache, load it; fall back to CasADi's virtual
    machine (logged) if that fails. "c": the same but raise on failure. "none": virtual machine only."""
    compiler: str = "gcc"
    """C compiler executable."""
    compiler_flags: tuple[str, ...] = ("-O1", "-fPIC", "-shared")
    """Flags for the compiler (-O2 runs faster but compiles longer)."""
    cache_dir: str | None = None
    """Directory for compiled artefacts; None: ``default_cache_dir()`` (``$DECK_SIM_CACHE/casadi``, else
    ``$XDG_CACHE_HOME/deck_sim/casadi``, else ``~/.cache/deck_sim/casadi``). Artefacts are keyed by a hash of
    the C source, compiler, flags, CasADi version and platform."""

    def __post_init__(self) -> None:
        problems = []
        if self.horizon < 1:
            problems.append(f"horizon must be >= 1, got {self.horizon}")
        if not self.dt > 0:
            problems.append(f"dt must be > 0 s, got {self.dt}")
        if not 3 <= self.estimation_window <= self.history:
            problems.append(
                f"estimation_window must be in [3, history={self.history}], got {self.estimation_window}"
            )
        if not 0 < self.forgetting <= 1:
            problems.append(f"forgetting must be in (0, 1], got {self.forgetting}")
        if not 0 <= self.belief_decay <= 1:
            problems.append(f"belief_decay must be in [0, 1], got {self.belief_decay}")
        if self.max_spots < 1:
            problems.append(f"max_spots must be >= 1, got {self.max_spots}")
        if self.stop_samples not in (1, 2):
            problems.append(f"stop_samples must be 1 or 2, got {self.stop_samples}")
        if self.gauss_newton_iterations < 1 or self.rollout_substeps < 1 or self.estimation_substeps < 1:
            problems.append("gauss_newton_iterations, rollout_substeps and estimation_substeps must be >= 1")
        if self.max_movers < 1:
            problems.append(f"max_movers must be >= 1, got {self.max_movers}")
        if self.compile not in ("auto", "c", "none"):
            problems.append(f"compile must be 'auto', 'c' or 'none', got {self.compile!r}")
        if problems:
            raise ValueError("invalid MPCPredictorSettings: " + "; ".join(problems))

    @property
    def memory_size(self) -> int:
        """Length of the per-mover memory vector carried between steps.

        Layout: the state estimate (``N_ESTIMATE``: position m in world coordinates, heading rad, speed m/s,
        acceleration m/s^2, turn rate rad/s), whether it is valid, the running mean cruise speed m/s, the
        number of cruising samples in it, whether the mover stood still, the log-belief of each of the
        ``max_spots`` spots, the log-belief of "none", and whether each spot is excluded (the one just left).
        """
        return N_ESTIMATE + 4 + 2 * self.max_spots + 1
