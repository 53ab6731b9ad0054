"""Bounds of every scene field, checked at load against the arena and the vehicles.

``validate`` runs every check of a built ``SceneSpec`` and raises ``SceneSpecError`` naming the file, the field and
the offending value. The bounds that are not facts of the arena (``deck_sim.scenes.arena_facts``) are the constants
below.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from deck_sim.scenes.arena_facts import ArenaFacts, arena_facts, vehicle_top_speeds

if TYPE_CHECKING:
    from deck_sim.scenes import EpisodeSpec, SceneSpec


class SceneSpecError(ValueError):
    """A scene name is unknown or a scene file is malformed; the message names the field and value."""


MIN_PHYSICS_TIMESTEP = 0.001
"""Seconds: the smallest ``episode.physics_timestep``. Smaller steps are as stable, but every control step then runs
more than ``control_period / 0.001`` MuJoCo steps; the bound keeps a typo (a timestep in milliseconds, 1e-300) from
hanging a run."""

MAX_PHYSICS_TIMESTEP = 1 / 32
"""Seconds: the largest ``episode.physics_timestep`` the models are stable and faithful at. At 1/32 s every model
check of ``tests/test_physics.py`` passes (the aircraft taxis straight, turns at its kinematic rate, brakes to a stop
and is turned round by the tracker; the tractor drives at its wheel speed), and the scripted policy's episodes on
every scene keep every vehicle within its top speed. At the next timesteps that divide the 0.5 s decision the models
fail: at 1/24 s the tractor's speed ripples beyond 3 % of its wheel speed, at 1/20 s the aircraft creeps on under
full brakes, at 1/8 s the tracker can no longer turn the aircraft round, and at 1/2 s the aircraft run away without
MuJoCo warning of it. ``tests/test_scene_bounds.py`` shows each:
``test_the_models_hold_up_to_the_largest_timestep_and_not_beyond`` and
``test_a_runaway_at_a_coarse_timestep_is_flagged_as_divergence``."""

MAX_TIME_LIMIT = 3600.0
"""Seconds: the longest ``episode.time_limit`` and ``movers.dwell_range``: an hour of simulated time, far more than
an episode on the deck or the square needs (``deck_sim.registration.episode_decisions`` counts an episode's
decisions step by step)."""

MAX_MOVERS = 64
"""The most movers a scene may have. Every body starts at the origin when the model is compiled, and MuJoCo's
memory for their contacts there grows with the square of their number; the bound keeps the compilation within it
for any mix of vehicles (``tests/test_scene_bounds.py`` builds the largest mixes) and a layout placeable."""

MAX_TAXIING_AIRCRAFT = 16
"""The most taxiing aircraft among the movers: an aircraft has several large collision geoms, and two dozen of them
overlapping at the origin exhaust MuJoCo's memory when the model is compiled (the mover total stays within
``MAX_MOVERS``)."""

MAX_AGENTS = 8
"""The most aircraft ``agents.count`` may put on the surface at once (the deck's start sites and targets hold eight
apart from each other; every aircraft's observation carries every other one among its dynamic obstacles)."""

MAX_SCATTERED = 64
"""The most standing groups ``static.scattered`` may place."""

MAX_HISTORY = 1000
"""The most past samples ``episode.history`` may keep per mover (the task shifts them every control step)."""

MAX_HORIZON = 100
"""The most predicted steps ``episode.horizon`` may ask for (the observation holds them for every mover and the
MPC predictor's graph grows with them)."""

MAX_ACCEL = 9.81
"""m/s^2: the largest ``movers.accel``, ``movers.decel`` and ``movers.agent_yield_braking``: one g, more than any
deck vehicle or walker brakes or speeds up with (their actuators cap it lower)."""

MIN_ACCEL = 0.05
"""m/s^2: the smallest ``movers.accel`` and ``movers.decel``. A mover gains ``accel`` m/s per second and, planning
to stop at its spot, drives no faster than sqrt(2 * decel * d) at d metres from it: much below this bound movers
crawl over the arena's distances or never get going."""

MAX_TURN_RATE = 2 * math.pi
"""rad/s: the largest ``movers.turn_rate``, a full turn per second (the actuators cap what the vehicles reach)."""


def _check(condition: bool, where: str, message: str) -> None:
    if not condition:
        raise SceneSpecError(f"{where}: {message}")


def _check_range(
    value: float, lo: float, hi: float, where: str, bounds: str = "", lo_open: bool = False, lo_why: str = ""
) -> None:
    """``value`` in [lo, hi] (or (lo, hi] with ``lo_open``); ``bounds`` gives the upper bound's unit and where it
    comes from, ``lo_why`` where the lower one does."""
    below = "must be > " if lo_open else "must be >= "
    _check(
        lo < value if lo_open else lo <= value,
        where,
        f"{below}{lo:g}{' ' + lo_why if lo_why else ''}, got {value!r}",
    )
    _check(value <= hi, where, f"must be <= {hi:g}{' ' + bounds if bounds else ''}, got {value!r}")


def _check_sites(names: tuple[str, ...], arena: ArenaFacts, where: str) -> None:
    """Every name a site of ``arena``."""
    for i, name in enumerate(names):
        _check(
            name in arena.sites,
            f"{where}[{i}]",
            f"the {arena.name} arena has no site {name!r}; its sites are {', '.join(sorted(arena.sites))}",
        )


def validate(spec: SceneSpec, src: str) -> None:
    """Every field's bounds, and the checks across fields and against the arena and the vehicles."""
    arena = arena_facts(spec.arena)
    top_speed = vehicle_top_speeds()
    _validate_timing(spec.episode, f"{src} [episode]")
    _validate_agent(spec, f"{src} [agent]", arena, top_speed)
    _validate_movers(spec, f"{src} [movers]", arena, top_speed)
    _validate_static(spec, f"{src} [static]", arena)
    _validate_reward(spec, f"{src} [reward]", arena)
    _validate_episode(spec, f"{src} [episode]", arena)
    _validate_agents(spec, f"{src} [agents]")
    s, m = spec.static, spec.movers
    if spec.paper_counts != (0, 0):
        _check(
            (s.count, m.count) == spec.paper_counts,
            f"{src} paper_counts",
            f"scene has {s.count} static and {m.count} dynamic obstacles, paper_counts says {spec.paper_counts}",
        )


def _validate_timing(e: EpisodeSpec, w: str) -> None:
    """The episode's clock: time limit, control period and physics timestep."""
    _check_range(e.time_limit, 0.0, MAX_TIME_LIMIT, f"{w}.time_limit", "s (MAX_TIME_LIMIT)", lo_open=True)
    _check_range(e.control_period, 0.0, e.time_limit, f"{w}.control_period", "s (episode.time_limit)", lo_open=True)
    _check_range(
        e.physics_timestep,
        MIN_PHYSICS_TIMESTEP,
        math.inf,
        f"{w}.physics_timestep",
        lo_why="s (MIN_PHYSICS_TIMESTEP: finer steps only multiply the physics steps per decision)",
    )
    ratio = e.control_period / e.physics_timestep
    _check(
        abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1,
        f"{w}.physics_timestep",
        f"{e.physics_timestep} does not divide control_period {e.control_period}",
    )
    _check_range(
        e.physics_timestep,
        0.0,
        MAX_PHYSICS_TIMESTEP,
        f"{w}.physics_timestep",
        "s, the largest timestep the models are stable at (deck_sim.scenes.MAX_PHYSICS_TIMESTEP)",
    )
    _check(
        1 <= e.collision_checks <= round(ratio),
        f"{w}.collision_checks",
        f"expected 1..{round(ratio)} (the physics steps per control step, episode.control_period / "
        f"episode.physics_timestep), got {e.collision_checks}",
    )


def _validate_agent(spec: SceneSpec, w: str, arena: ArenaFacts, top_speed: dict[str, float]) -> None:
    a, period = spec.agent, spec.episode.control_period
    for name in ("start_sites", "target_sites"):
        _check(len(getattr(a, name)) > 0, f"{w}.{name}", "must name at least one site")
        _check_sites(getattr(a, name), arena, f"{w}.{name}")
    speed = top_speed[a.vehicle]
    _check_range(
        a.reach,
        0.0,
        speed * period,
        f"{w}.reach",
        f"m (agent.vehicle {a.vehicle!r}: its top speed {speed:g} m/s over episode.control_period {period:g} s)",
        lo_open=True,
    )
    _check_range(a.goal_radius, 0.0, arena.diagonal, f"{w}.goal_radius", "m (the arena's diagonal)", lo_open=True)
    half = min(arena.hi[0] - arena.lo[0], arena.hi[1] - arena.lo[1]) / 2
    _check_range(a.radius, 0.0, half, f"{w}.radius", "m (half the surface's shorter side)", lo_open=True)
    for name, sites in (("start_jitter", "start_sites"), ("target_jitter", "target_sites")):
        j = getattr(a, name)
        _check(j >= 0, f"{w}.{name}", f"must be >= 0, got {j}")
        off = []
        for site in getattr(a, sites):
            x, y = arena.sites[site]
            if not (arena.on_surface(x - j, y - j) and arena.on_surface(x + j, y + j)):
                off.append(site)
        _check(not off, f"{w}.{name}", f"{j} m puts site(s) {off} of agent.{sites} off the {arena.name}'s surface")
    _check_range(a.yaw_jitter, 0.0, math.pi, f"{w}.yaw_jitter", "rad")
    _check(a.min_target_distance >= 0, f"{w}.min_target_distance", f"must be >= 0, got {a.min_target_distance}")
    _check(
        a.min_target_distance <= a.max_target_distance,
        f"{w}.min_target_distance",
        f"{a.min_target_distance} exceeds agent.max_target_distance {a.max_target_distance}",
    )
    slack = math.sqrt(2.0) * (a.start_jitter + a.target_jitter)  # how far the jitters move the distance
    for start in a.start_sites:
        sx, sy = arena.sites[start]
        dists = [math.hypot(arena.sites[t][0] - sx, arena.sites[t][1] - sy) for t in a.target_sites]
        if any(d + slack >= a.min_target_distance and d - slack <= a.max_target_distance for d in dists):
            continue
        name = "min_target_distance" if all(d + slack < a.min_target_distance for d in dists) else "max_target_distance"
        raise SceneSpecError(
            f"{w}.{name}: no site of agent.target_sites lies {a.min_target_distance:g}-{a.max_target_distance:g} m "
            f"from the start site {start!r} of agent.start_sites (with the jitters)"
        )


def _validate_agents(spec: SceneSpec, w: str) -> None:
    """The number of aircraft acting at once, against the vehicle, the sites and the MPC predictor's capacity."""
    k, a = spec.agents.count, spec.agent
    _check_range(k, 1, MAX_AGENTS, f"{w}.count", "(MAX_AGENTS)")
    if k == 1:
        return
    _check(a.vehicle == "aircraft", f"{w}.count", f"several agents must be aircraft, agent.vehicle is {a.vehicle!r}")
    _check(
        spec.arena == "deck",
        f"{w}.count",
        f"several aircraft need the deck (their apron lies beyond its stern), the arena is {spec.arena!r}",
    )
    for name in ("start_sites", "target_sites"):
        sites = getattr(a, name)
        _check(
            len(set(sites)) >= k,
            f"{w}.count",
            f"{k} aircraft need {k} distinct agent.{name} (one each), the scene names {len(set(sites))}",
        )
    _check(
        spec.reward.lookahead_steps == 0,
        f"{w}.count",  # (with agents.count; the message names the reward's field)
        "reward.lookahead_steps looks ahead from one aircraft; several agents need lookahead_steps = 0",
    )
    _check(
        spec.episode.predictor != "oracle",
        f"{w}.count",
        "the 'oracle' predictor simulates the movers ahead; the other aircraft's futures are their policies' choice, "
        "so several agents need episode.predictor 'none', 'constant_velocity', 'stationary' or 'mpc'",
    )
    if spec.episode.predictor == "mpc":
        from deck_sim.control.mpc_settings import MPCPredictorSettings  # a plain dataclass: no CasADi

        mpc = MPCPredictorSettings
        _check(
            spec.movers.count + k <= mpc.max_movers,
            f"{w}.count",
            f"'mpc' is compiled for at most {mpc.max_movers} predicted vehicles; {spec.movers.count} movers and {k} "
            f"aircraft (each predicted for the others) make {spec.movers.count + k}",
        )
        _check(
            len(spec.movers.spots) + k <= mpc.max_spots,
            f"{w}.count",
            f"'mpc' is compiled for at most {mpc.max_spots} spots; movers.spots names {len(spec.movers.spots)} and "
            f"the {k} aircraft's targets are spots too: {len(spec.movers.spots) + k}",
        )


def _validate_static(spec: SceneSpec, w: str, arena: ArenaFacts) -> None:
    s, a, m = spec.static, spec.agent, spec.movers
    _check(
        s.slot_prefix != "",
        f"{w}.slot_prefix",
        "must not be empty (every site of the arena would be a slot, starts, targets and spots included)",
    )
    slots = arena.sites_with_prefix(s.slot_prefix)
    for field_name in ("agent.start_sites", "agent.target_sites", "movers.spots") if s.slotted > 0 else ():
        section, name = field_name.split(".")
        taken = sorted(set(slots) & set(getattr(getattr(spec, section), name)))
        _check(
            not taken,
            f"{w}.slot_prefix",
            f"{s.slot_prefix!r} makes site(s) {taken} of {field_name} slots: an obstacle would stand on them",
        )
    _check(
        0 <= s.slotted <= len(slots),
        f"{w}.slotted",
        f"must be 0 to the {len(slots)} '{s.slot_prefix}*' slots (static.slot_prefix) of the {arena.name} arena, "
        f"got {s.slotted}",
    )
    _check_range(s.scattered, 0, MAX_SCATTERED, f"{w}.scattered", "(MAX_SCATTERED)")
    aircraft = [f"agent.vehicle = {a.vehicle!r}"] if a.vehicle == "aircraft" else []
    aircraft += [f"movers.aircraft = {m.aircraft}"] if m.aircraft > 0 else []
    _check(
        s.scattered == 0 or not aircraft,
        f"{w}.scattered",
        f"{s.scattered} standing groups cannot share a scene with aircraft ({', '.join(aircraft)}): MuJoCo's "
        "capsule-cylinder collision can return more contacts than it has room for and abort",
    )
    _check_range(s.scatter_clearance, 0.0, arena.diagonal, f"{w}.scatter_clearance", "m (the arena's diagonal)")


def _validate_movers(spec: SceneSpec, w: str, arena: ArenaFacts, top_speed: dict[str, float]) -> None:
    m = spec.movers
    for name in ("tractors", "aircraft", "pedestrians", "spawn_near_agent", "spawn_random"):
        _check(getattr(m, name) >= 0, f"{w}.{name}", f"must be >= 0, got {getattr(m, name)}")
    _check_range(m.aircraft, 0, MAX_TAXIING_AIRCRAFT, f"{w}.aircraft", "(MAX_TAXIING_AIRCRAFT)")
    counts = {"tractors": m.tractors, "aircraft": m.aircraft, "pedestrians": m.pedestrians}
    _check(
        m.count <= MAX_MOVERS,
        f"{w}.{max(counts, key=counts.__getitem__)}",
        f"{m.tractors} tractors + {m.aircraft} aircraft + {m.pedestrians} pedestrians make {m.count} movers, "
        f"more than the {MAX_MOVERS} a scene may have (MAX_MOVERS)",
    )
    _check_sites(m.spots, arena, f"{w}.spots")
    twice = sorted({n for n in m.spots if m.spots.count(n) > 1})
    _check(not twice, f"{w}.spots", f"name(s) {twice} given more than once")
    _check(m.count == 0 or len(m.spots) >= 2, f"{w}.spots", f"{m.count} movers need at least two spots")
    spawned = m.spawn_near_agent + m.spawn_random
    _check(
        spawned <= m.count,
        f"{w}.spawn_near_agent",
        f"spawn_near_agent {m.spawn_near_agent} + movers.spawn_random {m.spawn_random} exceed the {m.count} movers "
        "(movers.tractors + movers.aircraft + movers.pedestrians)",
    )
    lo, hi = m.speed_range
    _check(0 <= lo <= hi and hi > 0, f"{w}.speed_range", f"expected 0 <= min <= max, max > 0, got {[lo, hi]}")
    kinds = {"tractor": "tractors", "aircraft": "aircraft", "pedestrian": "pedestrians"}  # vehicle -> count field
    present = [k for k, count in kinds.items() if getattr(m, count) > 0]
    # the slowest kind of mover in the scene; without movers, the fastest vehicle (no mover goes faster)
    slowest = min(present, key=top_speed.__getitem__) if present else max(kinds, key=top_speed.__getitem__)
    _check(
        hi <= top_speed[slowest],
        f"{w}.speed_range",
        f"the top cruise speed {hi:g} m/s exceeds the {slowest}'s top speed {top_speed[slowest]:g} m/s "
        f"(movers.{kinds[slowest]} = {getattr(m, kinds[slowest])})",
    )
    lo, hi = m.dwell_range
    _check(
        0 <= lo <= hi <= MAX_TIME_LIMIT,
        f"{w}.dwell_range",
        f"expected 0 <= min <= max <= {MAX_TIME_LIMIT:g} s (MAX_TIME_LIMIT), got {[lo, hi]}",
    )
    for name in ("accel", "decel"):
        _check_range(getattr(m, name), MIN_ACCEL, MAX_ACCEL, f"{w}.{name}", "m/s^2 (MAX_ACCEL)", lo_why="(MIN_ACCEL)")
    _check_range(m.agent_yield_braking, 0.0, MAX_ACCEL, f"{w}.agent_yield_braking", "m/s^2 (MAX_ACCEL)")
    _check_range(m.turn_rate, 0.0, MAX_TURN_RATE, f"{w}.turn_rate", "rad/s (MAX_TURN_RATE)", lo_open=True)
    for name in ("clearance", "yield_distance", "agent_yield_distance", "near_radius"):
        _check_range(getattr(m, name), 0.0, arena.diagonal, f"{w}.{name}", "m (the arena's diagonal)")


def _validate_reward(spec: SceneSpec, w: str, arena: ArenaFacts) -> None:
    r = spec.reward
    _check(
        0 < r.attraction_min <= r.attraction_max,
        f"{w}.attraction_min",
        f"expected 0 < l <= L, got l={r.attraction_min}, L={r.attraction_max} (reward.attraction_max)",
    )
    _check(
        0 < r.repulsion_min <= r.repulsion_max,
        f"{w}.repulsion_min",
        f"expected 0 < h <= H, got h={r.repulsion_min}, H={r.repulsion_max} (reward.repulsion_max)",
    )
    _check_range(
        r.influence_radius, 0.0, arena.diagonal, f"{w}.influence_radius", "m (the arena's diagonal)", lo_open=True
    )
    _check(r.collision <= 0, f"{w}.collision", f"must be <= 0 (a penalty), got {r.collision}")
    _check(r.goal >= 0, f"{w}.goal", f"must be >= 0, got {r.goal}")
    terms = {
        "w_attraction": "attraction_max",
        "w_repulsion": "repulsion_max",
        "w_collision": "collision",
        "w_goal": "goal",
    }
    for weight, constant in terms.items():
        value = getattr(r, weight)
        _check(value >= 0, f"{w}.{weight}", f"must be >= 0 (the term's sign is its constant's), got {value}")
        _check(
            math.isfinite(value * getattr(r, constant)),
            f"{w}.{weight}",
            f"{weight} * reward.{constant} = {value} * {getattr(r, constant)} is not a finite number",
        )
    _check(
        math.isfinite(sum(abs(getattr(r, k) * getattr(r, c)) for k, c in terms.items())),
        f"{w}.w_attraction",
        "the weighted terms (w_attraction, w_repulsion, w_collision, w_goal times their constants) add up beyond "
        "the largest float",
    )
    _check(
        0 <= r.lookahead_steps <= spec.episode.horizon,
        f"{w}.lookahead_steps",
        f"expected 0 <= lookahead_steps <= episode.horizon {spec.episode.horizon}, got {r.lookahead_steps}",
    )
    _check(
        0 <= r.progress_deadband < spec.agent.reach,
        f"{w}.progress_deadband",
        f"expected 0 <= progress_deadband < agent.reach {spec.agent.reach} m, got {r.progress_deadband}",
    )


def _validate_episode(spec: SceneSpec, w: str, arena: ArenaFacts) -> None:
    e, a, m = spec.episode, spec.agent, spec.movers
    _check_range(e.history, 2, MAX_HISTORY, f"{w}.history", "(MAX_HISTORY)")
    _check_range(e.horizon, 1, MAX_HORIZON, f"{w}.horizon", "(MAX_HORIZON)")
    _check(e.near_steps >= 0, f"{w}.near_steps", f"must be >= 0, got {e.near_steps}")
    _check(
        e.near_steps <= arena.diagonal / a.reach,
        f"{w}.near_steps",
        f"near_steps * agent.reach = {e.near_steps} * {a.reach} m exceeds the arena's diagonal {arena.diagonal:.1f} m",
    )
    for name in ("predicted_approach", "predicted_near"):  # the options read from the forecast
        _check(
            not getattr(e, name) or e.predictor != "none",
            f"{w}.{name}",
            "is read from the forecast: it needs a predictor ([episode].predictor is 'none')",
        )
    _check(
        not e.predicted_near or e.near_steps > 0,
        f"{w}.predicted_near",
        "needs a near field: set [episode].near_steps > 0",
    )
    _check(
        not e.near_obstacles or e.near_steps > 0,
        f"{w}.near_obstacles",
        "needs a near field: set [episode].near_steps > 0",
    )
    _check(e.route_steps >= 0, f"{w}.route_steps", f"must be >= 0, got {e.route_steps}")
    _check(
        e.route_steps <= arena.perimeter / a.reach,
        f"{w}.route_steps",
        f"route_steps * agent.reach = {e.route_steps} * {a.reach} m exceeds the arena's perimeter "
        f"{arena.perimeter:.1f} m",
    )
    r = spec.reward
    uses, field = ("episode.predictor", f"{w}.predictor") if e.predictor == "mpc" else (None, "")
    if uses is None and r.lookahead_steps > 0 and r.lookahead_predictor == "mpc":
        uses, field = "reward.lookahead_predictor", w.replace("[episode]", "[reward]") + ".lookahead_predictor"
    if uses is not None:
        who = "" if uses == "episode.predictor" else f"{uses} "  # (the field name leads the message already)
        from deck_sim.control.mpc_settings import MPCPredictorSettings  # a plain dataclass: no CasADi

        mpc = MPCPredictorSettings
        _check(
            e.history >= mpc.history,
            f"{w}.history",
            f"{uses} 'mpc' reads the last {mpc.history} samples, got history {e.history}",
        )
        _check(
            m.count <= mpc.max_movers,
            field,
            f"{who}'mpc' is compiled for at most {mpc.max_movers} movers, the scene has {m.count} "
            "(movers.tractors + movers.aircraft + movers.pedestrians)",
        )
        _check(
            len(m.spots) <= mpc.max_spots,
            field,
            f"{who}'mpc' is compiled for at most {mpc.max_spots} spots, movers.spots names {len(m.spots)}",
        )
