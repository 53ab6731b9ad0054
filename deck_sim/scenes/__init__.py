"""Scene specifications as data: ``deck1``, ``deck2``, ``square`` and the multi-aircraft ``deck1-multi`` and
``deck2-multi`` TOML files, validated on load.

Every constant of a scene lives in its TOML file: obstacle counts, where things spawn, the movers' speeds, the
episode limits and every reward constant (paper eq. 10-16). ``load_scene`` checks each field's type and bounds (each
field's docstring gives them; sites, slots, distances and speeds are checked against the arena and the vehicles,
``deck_sim.scenes.arena_facts``) and raises ``SceneSpecError`` naming the file, the field and the offending value,
before any model is built.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from deck_sim.scenes.validation import (  # noqa: F401  (the bounds are part of this package's API)
    MAX_ACCEL,
    MAX_AGENTS,
    MAX_HISTORY,
    MAX_HORIZON,
    MAX_MOVERS,
    MAX_PHYSICS_TIMESTEP,
    MAX_SCATTERED,
    MAX_TAXIING_AIRCRAFT,
    MAX_TIME_LIMIT,
    MAX_TURN_RATE,
    MIN_ACCEL,
    MIN_PHYSICS_TIMESTEP,
    SceneSpecError,
    validate,
)

SCENE_DIR = Path(__file__).parent


@dataclass(frozen=True)
class AgentSpec:
    """The agent: its vehicle, where it starts, where its target lies and how far one action reaches."""

    vehicle: Literal["aircraft", "pedestrian"]
    """Vehicle model: the wheeled ``aircraft`` (deck) or a holonomic ``pedestrian`` (square)."""
    start_sites: tuple[str, ...]
    """Names of arena sites the agent starts at (one drawn per episode); at least one, each a site of the arena."""
    target_sites: tuple[str, ...]
    """Names of arena sites that may be the target (one drawn per episode, within the distance bounds); at least
    one, each a site of the arena."""
    reach: float
    """Metres: an action of norm 1 asks for this displacement over one decision period. > 0 and at most the
    vehicle's top speed times ``episode.control_period`` (``arena_facts.vehicle_top_speeds``; the tracker caps the
    speed there, so a longer reach would not be what the action asks)."""
    goal_radius: float
    """Metres: the episode succeeds when the agent's reference point is this close to the target. > 0 and at most
    the arena's diagonal."""
    radius: float
    """Metres: radius of the disc that stands for the agent in clearance, reward and planning. > 0 and at most half
    the surface's shorter side (the disc fits on it)."""
    start_jitter: float = 0.0
    """Metres: uniform jitter of the start position in x and y. >= 0, and every start site jittered this far stays
    on the surface."""
    yaw_jitter: float = 0.0
    """Radians: uniform jitter of the start heading, in [0, pi]."""
    target_jitter: float = 0.0
    """Metres: uniform jitter of the target position in x and y. >= 0, and every target site jittered this far
    stays on the surface."""
    min_target_distance: float = 0.0
    """Metres: lower bound on the straight-line start-target distance; >= 0, and from every start site some target
    site lies within the two bounds (give or take the jitters)."""
    max_target_distance: float = 1e9
    """Metres: upper bound on the straight-line start-target distance; >= ``min_target_distance``."""


@dataclass(frozen=True)
class AgentsSpec:
    """How many aircraft learn and act at once (the multi-agent scenes); every one is an ``[agent]`` as that
    section describes it, each with its own start and target, drawn without repeats from ``agent.start_sites``
    and ``agent.target_sites``. The section is optional: a scene without it has one agent."""

    count: int = 1
    """Learning aircraft per episode: 1 to ``MAX_AGENTS``; above 1 the vehicle must be the ``aircraft``, and
    ``agent.start_sites`` and ``agent.target_sites`` must each name at least ``count`` sites (no two aircraft start
    or aim at the same one)."""


@dataclass(frozen=True)
class StaticSpec:
    """Static obstacles: parked aircraft or kiosks in named slots, plus standing groups placed at random."""

    slot_prefix: str
    """Arena sites whose names start with this are the slots that slotted obstacles fill. Not empty, and (with
    ``slotted`` above 0) naming no start, target or spot site (an obstacle would stand on it)."""
    slotted: int
    """How many slots are filled per episode (drawn without replacement): 0 up to the number of slots."""
    slotted_kind: Literal["parked_aircraft", "kiosk"]
    """What stands in a slot."""
    scattered: int = 0
    """How many standing groups are placed uniformly at random on free ground (rejection sampling): 0 to
    ``MAX_SCATTERED``, and 0 in a scene with aircraft (the agent's vehicle or ``movers.aircraft``): MuJoCo's
    capsule-cylinder collision can return more contacts than it reserves room for when an aircraft's fuselage
    (a capsule) lies across a group's cylinder, which aborts the simulation, and it does at once when the model is
    compiled with every body at the origin."""
    scatter_clearance: float = 3.0
    """Metres of free space kept between a scattered group and anything else, starts and targets included; 0 up to
    the arena's diagonal."""

    @property
    def count(self) -> int:
        """Number of static obstacles per episode."""
        return self.slotted + self.scattered


@dataclass(frozen=True)
class MoverSpec:
    """Dynamic obstacles (paper's assumptions 1-3): go to a special spot, dwell a random time, go on."""

    tractors: int = 0
    """Deck tractors (wheeled, differential drive); >= 0, all movers together at most ``MAX_MOVERS``."""
    aircraft: int = 0
    """Taxiing aircraft (the agent's own vehicle model, driven by a mover script); 0 to ``MAX_TAXIING_AIRCRAFT``."""
    pedestrians: int = 0
    """Walking pedestrians (holonomic); >= 0."""
    spots: tuple[str, ...] = ()
    """Names of the special spots the movers travel between: sites of the arena, no name twice, at least two when
    there are movers."""
    speed_range: tuple[float, float] = (2.0, 4.0)
    """m/s: each trip's cruise speed is drawn uniformly from this range; 0 <= min <= max, max > 0 and at most the
    top speed of the slowest kind of mover in the scene (``arena_facts.vehicle_top_speeds``; of the fastest vehicle
    in a scene without movers)."""
    dwell_range: tuple[float, float] = (3.0, 15.0)
    """Seconds: each dwell at a spot lasts a uniform draw from this range; 0 <= min <= max <= ``MAX_TIME_LIMIT``."""
    accel: float = 1.0
    """m/s^2: acceleration the movers' scripts ask for (their actuators cap it physically too); in
    [``MIN_ACCEL``, ``MAX_ACCEL``]."""
    decel: float = 1.0
    """m/s^2: braking they plan with when stopping at a spot; in [``MIN_ACCEL``, ``MAX_ACCEL``]."""
    turn_rate: float = 0.6
    """rad/s: largest turn rate the wheeled movers' scripts command; in (0, ``MAX_TURN_RATE``]."""
    clearance: float = 3.0
    """Metres: how far their planned routes stay from static obstacles (beyond their own radius); 0 up to the arena's
    diagonal."""
    yield_distance: float = 8.0
    """Metres: a mover brakes when another mover or the agent is this close ahead of it (0 disables); 0 up to the
    arena's diagonal."""
    yield_to_agent: bool = True
    """Whether movers also yield to the agent (deck crews stop for a taxiing aircraft)."""
    agent_yield_distance: float = 6.0
    """Metres: a mover brakes at once when the agent is this close ahead of it (an emergency stop; keep it
    short so that movers do not wait on an agent that waits on them); 0 up to the arena's diagonal."""
    agent_yield_braking: float = 0.0
    """m/s^2: with a value above 0, the emergency stop for the agent reaches ``agent_yield_distance`` plus the
    mover's stopping distance at this braking, v^2 / (2 * agent_yield_braking), with v its speed now (capped at the
    top of ``speed_range``), so a fast tractor starts braking earlier (the control period's delay, the agent's own
    motion and how hard the vehicle really brakes are not in it); 0 (default) keeps the fixed reach. In
    [0, ``MAX_ACCEL``]."""
    spawn_near_agent: int = 0
    """How many movers start on free ground within ``near_radius`` of the agent instead of at spots; >= 0, and
    with ``spawn_random`` at most the number of movers."""
    spawn_random: int = 0
    """How many movers start on free ground anywhere (paper's deck 2: 4 placed at random); >= 0."""
    near_radius: float = 20.0
    """Metres: radius around the agent's start for ``spawn_near_agent``; 0 up to the arena's diagonal."""

    @property
    def count(self) -> int:
        """Number of dynamic obstacles."""
        return self.tractors + self.aircraft + self.pedestrians


@dataclass(frozen=True)
class RewardSpec:
    """Constants of the APF-shaped reward, paper eq. 10-16 (see ``deck_sim.tasks.rewards``).

    Every weighted term, and their sum, must stay a finite number."""

    attraction_max: float
    """L, metres: cap of the target-attraction term r1 per step; >= ``attraction_min``."""
    attraction_min: float
    """l, metres: floor of |r1| per step (the sign follows the progress); > 0."""
    repulsion_max: float
    """H, metres: cap of the obstacle-repulsion term r2 per step; >= ``repulsion_min``."""
    repulsion_min: float
    """h, metres: floor of |r2| per step inside the influence radius; > 0."""
    influence_radius: float
    """Metres of clearance within which the nearest obstacle repels (no r2 beyond); > 0, at most the arena's
    diagonal."""
    collision: float = -50.0
    """r3: reward on collision (and on leaving the deck); <= 0 (a penalty)."""
    goal: float = 200.0
    """r4: reward on reaching the target; >= 0."""
    w_attraction: float = 1.0
    """lambda1: weight of r1; >= 0 (each weight's sign is its constant's)."""
    w_repulsion: float = 1.0
    """lambda2: weight of r2; >= 0."""
    w_collision: float = 1.0
    """lambda3: weight of r3; >= 0."""
    w_goal: float = 1.0
    """lambda4: weight of r4; >= 0."""
    progress_deadband: float = 0.01
    """Metres: |progress| below this counts as none (r1 = 0, r2 = 0), so that a standing agent is not paid +l
    or charged -l by numerical noise; the paper's d >= 0 branch is otherwise kept. >= 0 and below ``agent.reach``
    (a full step's progress)."""
    lookahead_steps: int = 0
    """Control steps that the repulsion term r2 looks ahead at the movers; 0 (the default): the paper's, every
    obstacle's clearance now. With k > 0 a mover's clearance in r2 is its footprint clearance now less how much
    nearer the two centres come within the next k steps (never more than now), the agent carried on at its current
    velocity and the mover along the forecast of ``lookahead_predictor``: the closest point of approach, between
    centres, so that r2 penalises steps that bring a predicted encounter closer. The reward is the scene's: the
    same whatever the agent observes. In [0, ``episode.horizon``]."""
    lookahead_predictor: Literal["constant_velocity", "stationary", "oracle", "mpc"] = "mpc"
    """The predictor whose forecast r2 reads when ``lookahead_steps`` > 0, built with ``episode.horizon`` steps
    whatever the agent observes; where the episode's own predictor is the same, its forecast is reused."""


@dataclass(frozen=True)
class EpisodeSpec:
    """Timing, history and prediction of the task."""

    time_limit: float
    """Seconds of simulated time before the episode is truncated; in (0, ``MAX_TIME_LIMIT``]."""
    control_period: float = 0.5
    """Seconds between decisions (the paper's step); in (0, ``time_limit``]."""
    physics_timestep: float = 0.02
    """Seconds per MuJoCo step; in [``MIN_PHYSICS_TIMESTEP``, ``MAX_PHYSICS_TIMESTEP``] (the range the models are
    stable at, see there) and must divide ``control_period``."""
    history: int = 10
    """Samples of each mover's past positions kept for the predictor; 2 to ``MAX_HISTORY``, and at least the MPC
    predictor's own ``history`` when ``predictor`` is ``mpc``."""
    horizon: int = 10
    """Predicted steps N of each mover (at the control period); 1 to ``MAX_HORIZON``."""
    predictor: Literal["none", "constant_velocity", "stationary", "oracle", "mpc"] = "constant_velocity"
    """Which predictor fills the observation's predicted part. ``mpc`` also bounds the scene by the MPC predictor's
    compiled capacity: at most its ``max_movers`` movers and ``max_spots`` spots
    (``control.mpc_settings.MPCPredictorSettings``)."""
    collision_checks: int = 5
    """Contact checks per control step (the fused physics substeps are split this many times); 1 up to the number
    of physics steps per control step."""

    obstacle_shape: bool = False
    """Also observe the shape of every obstacle: the nearest point of each static obstacle's and each mover's
    footprint (``static_nearest``, ``dynamic_nearest``, relative to the agent, in the same order as their centres)
    and each mover's heading (``dynamic_heading``, cos and sin). Off by default (the paper's observation)."""
    predicted_frame: Literal["agent", "mover"] = "agent"
    """Where the observation's ``predicted`` positions are measured from: ``agent`` (the paper's eq. 8: predicted
    position minus the agent's) or ``mover`` (predicted position minus that mover's position now: its predicted
    displacement, zero for a mover that is predicted to stand)."""
    predicted_approach: bool = False
    """Also observe, from the forecast, each mover's closest approach: ``predicted_approach`` (n, 2), in the order
    of ``dynamic_obstacles``, the time (seconds from now, a multiple of ``control_period`` up to the horizon) and
    the distance between centres (metres) at which the mover's forecast track comes nearest to the agent carried on
    at its current velocity (now included). A function of what MDDPG observes already (its forecast and its own
    velocity), in the form in which a collision course shows. Needs a predictor (``predictor`` not ``none``). Off by
    default (the paper's observation)."""
    mover_size: bool = False
    """Also observe each mover's size (``dynamic_size``, (n, 2), in the same order as ``dynamic_obstacles``): the
    half-length and half-width of its footprint, rounding radius included, metres (on deck 1: (9.15, 6.8) for the
    taxiing aircraft, (2.0, 1.0) for a tractor). Off by default (the paper's observation)."""
    static_size: bool = False
    """Also observe each static obstacle's footprint (``static_size``, (m, 2): its half-length and half-width,
    rounding radius included, metres; ``static_heading``, (m, 2): the cos and sin of its long axis; both in the
    order of ``static_obstacles``). With ``obstacle_shape`` and ``mover_size`` the observation then holds every
    obstacle's footprint, which a planner can plan from (``Navigate.observed_view``). Off by default (the paper's
    observation)."""
    frame: Literal["world", "agent"] = "world"
    """The axes of the observation's vectors and of the action: ``world`` (the deck's axes, the paper's) or
    ``agent`` (x along the agent's heading, y to its left; egocentric). In the agent frame every relative vector
    of the observation (``target``, obstacles, ``predicted``, the shape's nearest points and headings,
    ``target_near``, ``static_near``, ``dynamic_near``, ``predicted_near``, ``route``, ``velocity``) is turned by
    minus the agent's yaw, and an action (x, y) asks for a displacement of ``reach * x`` metres ahead and
    ``reach * y`` to the left.
    ``position``, ``heading`` (the yaw's cos and sin, so the world can still be recovered), ``dynamic_size``,
    ``static_size`` and ``edge_near`` stay as they are.
    The scripted and classical planners, which plan in the world, have their actions turned into this frame
    (``Navigate.action_from_world``)."""
    near_steps: int = 0
    """Also observe, at a scale the far field does not swamp, what lies within ``near_steps`` decision periods'
    reach (``near_steps * agent.reach`` metres): ``target_near`` (2), the target minus the agent with its length
    clipped to that range, and ``edge_near`` (4), the agent's distance to the surface's west, east, south and
    north edges, each clipped to it. An actor that reads ``target`` and ``position`` tens of metres wide after
    normalisation cannot resolve the last metres before a goal next to an edge. 0 (default, the paper's
    observation) leaves them out. >= 0, and the near field at most the arena's diagonal."""
    near_obstacles: bool = False
    """Also observe every obstacle within the near field (``near_steps``, which must then be > 0) at that field's
    scale: ``static_near`` (m, 2) and ``dynamic_near`` (n, 2), the nearest point of each static obstacle's and
    each mover's footprint minus the agent, its length clipped to ``near_steps * agent.reach`` metres, in the same
    nearest-first order as their centres. A set actor normalises an obstacle feature over all the obstacles of
    its set at once, so on the square the centres of 28 statics spread over 100 m leave the metre between the
    agent and a 1.2 m standing group a few hundredths wide; these rows keep it a metre. Off by default (the
    paper's observation)."""
    predicted_near: bool = False
    """Also observe the forecast at the near field's scale (``near_steps``, which must then be > 0; needs a
    predictor): ``predicted_near`` (n, N, 2), in the order of ``dynamic_obstacles``, the nearest point of each
    mover's footprint now moved by its predicted displacement at each of the N forecast steps, minus the agent's
    position now, its length clipped to ``near_steps * agent.reach`` metres (``tasks.observation.near_forecast``).
    ``predicted`` spans the whole surface, so after normalisation a mover's next few metres are a small difference
    between large inputs; these rows hold them at the scale of ``dynamic_near``. Off by default (the paper's
    observation)."""
    route_steps: int = 0
    """Also observe the way to the target around the static obstacles: ``route`` (``route_steps``, 2), the points
    ``k * agent.reach`` metres along the shortest path (``geometry.VisibilityGraph``, for a disc of the agent's
    radius plus ``ROUTE_MARGIN``, the scripted planner's static margin) for k = 1 .. ``route_steps``, relative to
    the agent (the target itself where the path is shorter). The path ignores the movers, so it is the same
    information with or without prediction: it is what a global planner hands a local one. 0 (default, the
    paper's observation) leaves it out. >= 0, and ``route_steps * agent.reach`` at most the arena's perimeter."""


ROUTE_MARGIN = 2.5
"""Metres of clearance beyond the agent's radius that the observed ``route`` keeps from static obstacles (the
scripted planner's ``margin``)."""

POLICY_EPISODE_FIELDS = ("predicted_frame", "frame", "control_period", "history")
"""``[episode]`` fields that change what an observation or an action means without changing any observation's key
or shape (a forecast's origin, the axes, the decision period an action's displacement spans, the past positions
the predictor reads): a trained actor must act with the values it was trained with, and nothing but its training
record can tell them (``policies.LearnedPolicy.scene_overrides`` carries them over)."""


@dataclass(frozen=True)
class SceneSpec:
    """One scene of the suite."""

    name: str
    """Short name, e.g. ``deck1``."""
    arena: Literal["deck", "square"]
    """Which arena model the scene is played on."""
    description: str
    agent: AgentSpec
    static: StaticSpec
    movers: MoverSpec
    reward: RewardSpec
    episode: EpisodeSpec
    paper_counts: tuple[int, int] = field(default=(0, 0))
    """(static, dynamic) obstacle counts of the paper's scene, checked against the spec."""
    agents: AgentsSpec = field(default_factory=AgentsSpec)
    """How many aircraft act at once (``[agents]``, optional)."""

    @property
    def multi_agent(self) -> bool:
        """Whether several aircraft act at once (``agents.count`` above 1): the scene loads as the multi-agent
        task (``deck_sim.tasks.multi.MultiNavigate``)."""
        return self.agents.count > 1


_SECTIONS = {
    "agent": AgentSpec,
    "static": StaticSpec,
    "movers": MoverSpec,
    "reward": RewardSpec,
    "episode": EpisodeSpec,
    "agents": AgentsSpec,
}
_OPTIONAL_SECTIONS = {"agents"}
"""Sections a scene file may leave out (their fields' defaults apply)."""
SECTIONS = tuple(_SECTIONS)
"""The sections of a scene file, in order (the first part of an override ``section__field``)."""


def _convert(value: Any, annotation: Any, where: str) -> Any:
    """Check ``value`` against a field annotation (from a string annotation resolved by typing)."""
    origin = typing.get_origin(annotation)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SceneSpecError(f"{where}: expected a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:
            raise SceneSpecError(
                f"{where}: expected a finite number, got an integer of {len(str(abs(value)))} digits, beyond a "
                "float's range"
            ) from None
        if not math.isfinite(number):
            raise SceneSpecError(f"{where}: expected a finite number, got {value!r}")
        return number
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneSpecError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise SceneSpecError(f"{where}: expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise SceneSpecError(f"{where}: expected a string, got {value!r}")
        return value
    if origin is Literal:
        allowed = typing.get_args(annotation)
        if value not in allowed:
            raise SceneSpecError(f"{where}: expected one of {list(allowed)}, got {value!r}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            raise SceneSpecError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise SceneSpecError(f"{where}: expected {len(args)} values, got {value!r}")
        return tuple(_convert(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin in (typing.Union, types.UnionType):  # pragma: no cover - no optional fields today
        raise SceneSpecError(f"{where}: unsupported annotation {annotation}")
    raise SceneSpecError(f"{where}: unsupported annotation {annotation}")  # pragma: no cover


def _build(cls: type, table: Any, where: str) -> Any:
    """Make dataclass ``cls`` from a TOML table, naming unknown, missing and ill-typed fields."""
    if not isinstance(table, dict):
        raise SceneSpecError(f"{where}: expected a table, got {table!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise SceneSpecError(f"{where}: unknown field(s) {unknown}; known fields are {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        if name in _SECTIONS and cls is SceneSpec:
            continue
        if name not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SceneSpecError(f"{where}: missing required field {name!r}")
            continue
        kwargs[name] = _convert(table[name], hints[name], f"{where}.{name}")
    return kwargs


def parse_scene(data: dict[str, Any], src: str = "<scene>") -> SceneSpec:
    """Build and validate a ``SceneSpec`` from a parsed TOML document."""
    top = _build(SceneSpec, data, src)
    sections = {}
    for key, cls in _SECTIONS.items():
        if key not in data and key in _OPTIONAL_SECTIONS:
            data = {**data, key: {}}
        if key not in data:
            raise SceneSpecError(f"{src}: missing section [{key}]")
        sections[key] = cls(**_build(cls, data[key], f"{src} [{key}]"))
    spec = SceneSpec(**top, **sections)
    validate(spec, src)
    return spec


def scene_names() -> list[str]:
    """Names of the scenes shipped with the package."""
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))


def _scene_path(name_or_path: str | Path, relative_to: Path | None = None) -> Path:
    """The file of a shipped scene's name (``deck1``), or a ``.toml`` path (relative to ``relative_to`` if given,
    else to the working directory)."""
    path = Path(name_or_path)
    if path.suffix == ".toml":
        return path if path.is_absolute() or relative_to is None else relative_to / path
    if str(name_or_path) not in scene_names():
        raise SceneSpecError(f"unknown scene {str(name_or_path)!r}; known scenes: {', '.join(scene_names())}")
    return SCENE_DIR / f"{name_or_path}.toml"


def _read_scene_file(path: Path, chain: tuple[Path, ...]) -> dict[str, Any]:
    """A scene file's TOML document with the scene it ``extends`` (a shipped name or a path relative to the file)
    merged under it: the base's sections, each field replaced where the file sets it."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SceneSpecError(f"scene file {path} does not exist") from err
    except IsADirectoryError as err:
        raise SceneSpecError(f"scene file {path} is a directory, not a TOML file") from err
    except OSError as err:
        raise SceneSpecError(f"scene file {path} cannot be read: {err.strerror or err}") from err
    except UnicodeDecodeError as err:
        raise SceneSpecError(f"{path.name}: not a TOML file (not UTF-8 text at byte {err.start})") from err
    except tomllib.TOMLDecodeError as err:
        raise SceneSpecError(f"{path.name}: not valid TOML: {err}") from err
    base_name = data.pop("extends", None)
    if base_name is None:
        return data
    if not isinstance(base_name, str) or not base_name:
        raise SceneSpecError(f"{path.name}: extends: expected a scene name or a .toml path, got {base_name!r}")
    base_path = _scene_path(base_name, relative_to=path.parent)
    if base_path.resolve() in {p.resolve() for p in (*chain, path)}:
        cycle = " -> ".join(p.name for p in (*chain, path, base_path))
        raise SceneSpecError(f"{path.name}: extends: the scenes extend each other in a cycle ({cycle})")
    merged = _read_scene_file(base_path, (*chain, path))
    counts = {f"{section}__{name}" for section, fields in data.items() if isinstance(fields, dict) for name in fields}
    if counts & _COUNT_FIELDS and "paper_counts" not in data:
        merged.pop("paper_counts", None)  # the base's counts changed: not the paper's scene unless the file says so
    for key, value in data.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged


def load_scene(name_or_path: str | Path, **overrides: Any) -> SceneSpec:
    """Load a shipped scene by name (``deck1``) or any scene file by path, then apply ``overrides``.

    A file may start from another scene: ``extends = "deck1"`` (a shipped name, or a ``.toml`` path relative to the
    file) takes every section of that scene and replaces the fields the file sets.

    Overrides name a section and field with a double underscore, e.g. ``episode__predictor="oracle"`` or
    ``movers__tractors=0``; they are validated like the file's own fields.

    Raises:
        SceneSpecError: unknown name, unreadable or malformed file, bad override.
    """
    path = _scene_path(name_or_path)
    data = _read_scene_file(path, ())
    for key, value in overrides.items():
        section, sep, name = key.partition("__")
        if not sep or section not in _SECTIONS:
            raise SceneSpecError(f"override {key!r}: expected <section>__<field> with section in {sorted(_SECTIONS)}")
        table = data.setdefault(section, {})
        if not isinstance(table, dict):
            raise SceneSpecError(f"{path.name} [{section}]: expected a table, got {table!r}")
        table[name] = value
    if set(overrides) & _COUNT_FIELDS:
        data.pop("paper_counts", None)  # counts overridden: no longer the paper's scene
    return parse_scene(data, path.name)


_COUNT_FIELDS = {
    "static__slotted",
    "static__scattered",
    "movers__tractors",
    "movers__aircraft",
    "movers__pedestrians",
}


def _toml_value(value: Any) -> str:
    """One field value as TOML (the types a scene spec holds: bool, int, float, str and tuples of them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)  # repr round-trips a float exactly
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise SceneSpecError(f"cannot write {value!r} of type {type(value).__name__} as TOML")


def dump_scene(spec: SceneSpec) -> str:
    """The scene as TOML text that ``parse_scene`` reads back into an equal spec (overrides included).

    This is what a run stores beside its results (for example in an episode log) to replay the scene exactly.
    """
    lines = [f"# scene {spec.name}, written by deck_sim.scenes.dump_scene"]
    for f in dataclasses.fields(SceneSpec):
        if f.name not in _SECTIONS:
            lines.append(f"{f.name} = {_toml_value(getattr(spec, f.name))}")
    for key in _SECTIONS:
        lines.append(f"\n[{key}]")
        section = getattr(spec, key)
        for f in dataclasses.fields(section):
            lines.append(f"{f.name} = {_toml_value(getattr(section, f.name))}")
    return "\n".join(lines) + "\n"
