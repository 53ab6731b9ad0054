"""Episode layouts: where the agent, the target, the static obstacles and the movers start (planar, metres).

``sample_layout`` draws one by rejection sampling from the scene's sites and slots; every draw comes from the
generator it is given, so the same generator state gives the same layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from deck_sim.geometry import Footprints
from deck_sim.scenes import SceneSpec

if TYPE_CHECKING:
    from deck_sim.entities.arenas import Site2D, _SiteArena

_GROUP_RADIUS = 1.2
"""Radius of a scattered standing group's disc, metres."""


class LayoutError(ValueError):
    """The episode's layout could not be sampled (rejection sampling ran out of attempts): the scene's values ask for
    more than its arena holds. A ``ValueError``, as bad input is (``deck-sim`` reports it in one line)."""


@dataclass
class Layout:
    """Where everything starts in one episode (planar, metres and radians): every agent's start and target (one
    row per agent; a single-agent scene has one), the static obstacles and the movers."""

    agents_xy: np.ndarray  # (k, 2)
    agents_yaw: np.ndarray  # (k,)
    targets_xy: np.ndarray  # (k, 2)
    static_xy: np.ndarray  # (m, 2)
    static_yaw: np.ndarray  # (m,)
    mover_xy: np.ndarray  # (n, 2)
    mover_spot: np.ndarray  # (n,) spot index or -1
    target_sites: list[str] = field(default_factory=list)
    static_sites: list[str] = field(default_factory=list)

    @property
    def agent_xy(self) -> np.ndarray:
        """(2,) the (first) agent's start."""
        return self.agents_xy[0]

    @property
    def agent_yaw(self) -> float:
        """The (first) agent's start heading."""
        return float(self.agents_yaw[0])

    @property
    def target_xy(self) -> np.ndarray:
        """(2,) the (first) agent's target."""
        return self.targets_xy[0]

    @property
    def target_site(self) -> str:
        """The site of the (first) agent's target."""
        return self.target_sites[0]


def yaw_quat(yaw: float) -> np.ndarray:
    """The quaternion (w, x, y, z) of a rotation by ``yaw`` radians about the vertical."""
    return np.array([np.cos(yaw / 2.0), 0.0, 0.0, np.sin(yaw / 2.0)])


def static_footprints(
    layout: Layout, props: list[tuple[np.ndarray, np.ndarray, float]], fixed: Footprints
) -> Footprints:
    """The footprints of the episode's static obstacles in the world: every prop's own footprint (centre offset
    (2,), half-extents (2,), rounding radius; metres, in the prop's frame) posed as ``layout`` places it, then the
    arena's ``fixed`` ones."""
    return Footprints.concatenate(
        [
            Footprints(
                layout.static_xy + _rotate(np.array([p[0] for p in props]).reshape(-1, 2), layout.static_yaw),
                np.array([p[1] for p in props]).reshape(-1, 2),
                layout.static_yaw,
                np.array([p[2] for p in props]),
            ),
            fixed,
        ]
    )


def _rotate(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Vectors (k, 2) each turned by its own ``yaw`` (k,) radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)


def sample_layout(
    spec: SceneSpec,
    arena: _SiteArena,
    slotted_footprint: tuple[np.ndarray, np.ndarray, float] | None,
    spot_xy: np.ndarray,
    mover_spawn_radius: np.ndarray,
    mover_names: list[str],
    rng: np.random.Generator,
) -> Layout:
    """Draw a non-overlapping layout for one episode.

    Args:
        spec: the scene.
        arena: the scene's arena (its sites, bounds and fixed obstacles).
        slotted_footprint: the slotted static obstacles' footprint (centre offset (2,), half-extents (2,),
            rounding radius; metres), or None when the scene has none.
        spot_xy: (k, 2) the movers' spots, metres.
        mover_spawn_radius: (n,) radius of the disc round each mover's footprint whatever its heading, metres.
        mover_names: the n movers' names, for errors.
        rng: the episode's generator.

    Raises:
        LayoutError: naming what could not be placed and why.
    """
    lo, hi = arena.bounds
    fixed = arena.fixed_obstacles()
    if spec.agents.count == 1:
        agent_xy, agent_yaw, target_xy, target_site = _start_and_target(spec, arena, rng)
        starts, yaws, targets, target_sites = agent_xy[None], np.array([agent_yaw]), target_xy[None], [target_site]
    else:
        starts, yaws, targets, target_sites = _starts_and_targets(spec, arena, rng)

    chosen = _slotted_sites(spec, arena, slotted_footprint, starts, targets, rng)
    static_xy = [s.xy for s in chosen]
    static_yaw = [s.yaw for s in chosen]
    kind_fp = slotted_footprint
    statics_fp = Footprints.concatenate(
        [
            fixed,
            Footprints(
                np.array(static_xy).reshape(-1, 2),
                np.repeat(kind_fp[1][None], len(chosen), 0) if kind_fp else np.zeros((0, 2)),
                np.array(static_yaw),
                np.full(len(chosen), kind_fp[2] if kind_fp else 0.0),
            ),
        ]
    )

    keep_clear = []
    for start, target in zip(starts, targets, strict=True):
        keep_clear += [(start, spec.agent.radius + 1.0), (target, spec.agent.goal_radius + 1.0)]
    keep_clear += [(s, 1.5) for s in spot_xy]
    scattered = _scattered_groups(spec, lo, hi, statics_fp, keep_clear, rng)
    static_xy += scattered
    static_yaw += [0.0] * len(scattered)
    all_fp = Footprints.concatenate(
        [
            statics_fp,
            Footprints(
                np.array(scattered).reshape(-1, 2),
                np.zeros((len(scattered), 2)),
                np.zeros(len(scattered)),
                np.full(len(scattered), _GROUP_RADIUS),
            ),
        ]
    )

    mover_xy, mover_spot = _place_movers(
        spec, lo, hi, all_fp, starts, targets, spot_xy, mover_spawn_radius, mover_names, rng
    )
    return Layout(
        agents_xy=starts,
        agents_yaw=yaws,
        targets_xy=targets,
        static_xy=np.array(static_xy).reshape(-1, 2),
        static_yaw=np.array(static_yaw),
        mover_xy=mover_xy,
        mover_spot=mover_spot,
        target_sites=target_sites,
        static_sites=[s.name for s in chosen],
    )


def _start_and_target(
    spec: SceneSpec, arena: _SiteArena, rng: np.random.Generator
) -> tuple[np.ndarray, float, np.ndarray, str]:
    """The agent's start (position, yaw) near a start site and a target near a target site at a distance in the
    scene's range; returns them with the target site's name."""
    a = spec.agent
    start = arena.site(a.start_sites[rng.integers(len(a.start_sites))])
    agent_xy = start.xy + rng.uniform(-a.start_jitter, a.start_jitter, 2)
    agent_yaw = float(start.yaw + rng.uniform(-a.yaw_jitter, a.yaw_jitter))
    targets = [arena.site(s) for s in a.target_sites]
    for _ in range(100):
        site = targets[rng.integers(len(targets))]
        target_xy = site.xy + rng.uniform(-a.target_jitter, a.target_jitter, 2)
        if a.min_target_distance <= np.linalg.norm(target_xy - agent_xy) <= a.max_target_distance:
            return agent_xy, agent_yaw, target_xy, site.name
    raise LayoutError(
        f"{spec.name}: no target among {list(a.target_sites)} lies "
        f"{a.min_target_distance}-{a.max_target_distance} m from the start {start.name}"
    )


_AGENT_SPACING = 2.0
"""Metres between the discs of two aircraft at their starts in a multi-agent scene (their targets are at least two
discs' radii apart)."""


def _starts_and_targets(
    spec: SceneSpec, arena: _SiteArena, rng: np.random.Generator, attempts: int = 500
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Every aircraft's start (positions (k, 2), yaws (k,)) near its own start site and its target (k, 2) near its
    own target site, each target within the scene's distance range of its aircraft's start; no two discs of the
    agent's radius closer than ``_AGENT_SPACING`` at the starts, nor two targets closer than two radii. Returns
    them with the target sites' names.

    Raises:
        LayoutError: no such draw in ``attempts`` tries.
    """
    a, k = spec.agent, spec.agents.count
    starts_all = [arena.site(s) for s in a.start_sites]
    targets_all = [arena.site(s) for s in a.target_sites]
    for _ in range(attempts):
        chosen = [starts_all[i] for i in rng.choice(len(starts_all), k, replace=False)]
        xy = np.array([s.xy for s in chosen]) + rng.uniform(-a.start_jitter, a.start_jitter, (k, 2))
        yaw = np.array([s.yaw for s in chosen]) + rng.uniform(-a.yaw_jitter, a.yaw_jitter, k)
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.eye(k) * 1e9
        if gaps.min() <= 2 * a.radius + _AGENT_SPACING:
            continue
        free = list(rng.permutation(len(targets_all)))
        targets, names = np.zeros((k, 2)), []
        for i in range(k):
            for j in list(free):
                site = targets_all[j]
                t = site.xy + rng.uniform(-a.target_jitter, a.target_jitter, 2)
                d = float(np.linalg.norm(t - xy[i]))
                spaced = all(np.linalg.norm(t - q) > 2 * a.radius for q in targets[:i])
                if a.min_target_distance <= d <= a.max_target_distance and spaced:
                    targets[i] = t
                    names.append(site.name)
                    free.remove(j)
                    break
            else:
                break
        if len(names) == k:
            return xy, yaw, targets, names
    raise LayoutError(
        f"{spec.name}: could not give {k} aircraft distinct starts among {list(a.start_sites)} (discs of "
        f"{a.radius} m apart) and targets among {list(a.target_sites)} "
        f"{a.min_target_distance}-{a.max_target_distance} m away in {attempts} tries"
    )


def _slotted_sites(
    spec: SceneSpec,
    arena: _SiteArena,
    kind_fp: tuple[np.ndarray, np.ndarray, float] | None,
    starts: np.ndarray,
    targets: np.ndarray,
    rng: np.random.Generator,
) -> list[Site2D]:
    """The slots of the slotted static obstacles, drawn among those clear of every start (k, 2) and target
    (k, 2), in the order of the arena's slots."""
    a = spec.agent
    slots = arena.sites_with_prefix(spec.static.slot_prefix)
    free = []
    for s in slots if kind_fp is not None else []:
        fp = Footprints(np.array([[s.x, s.y]]), kind_fp[1][None], np.array([s.yaw]), np.array([kind_fp[2]]))
        clear = True
        for agent_xy, target_xy in zip(starts, targets, strict=True):
            d_start = fp.distance(agent_xy)[0, 0]
            d_target = fp.distance(target_xy)[0, 0]
            clear = clear and d_start > a.radius + 2.0 and d_target > a.radius + a.goal_radius
        if clear:
            free.append(s)
    if len(free) < spec.static.slotted:
        raise LayoutError(
            f"{spec.name}: only {len(free)} of {len(slots)} '{spec.static.slot_prefix}*' slots are "
            f"clear of the start and target, {spec.static.slotted} static obstacles need one each"
        )
    return [free[i] for i in sorted(rng.choice(len(free), spec.static.slotted, replace=False))]


def _scattered_groups(
    spec: SceneSpec,
    lo: np.ndarray,
    hi: np.ndarray,
    statics_fp: Footprints,
    keep_clear: list[tuple[np.ndarray, float]],
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """Centres of the scattered standing groups (the square's): uniform on free ground, clear of the fixed and
    slotted obstacles, of the ``keep_clear`` discs (centre, radius) and of each other by the scene's clearance."""
    scattered: list[np.ndarray] = []
    for i in range(spec.static.scattered):
        for _ in range(2000):
            p = rng.uniform(lo + _GROUP_RADIUS + 1.0, hi - _GROUP_RADIUS - 1.0)
            c = spec.static.scatter_clearance + _GROUP_RADIUS
            if (
                statics_fp.distance(p).min(initial=np.inf) > c
                and all(np.linalg.norm(p - q) > r + c for q, r in keep_clear)
                and all(np.linalg.norm(p - q) > 2 * _GROUP_RADIUS + c for q in scattered)
            ):
                scattered.append(p)
                break
        else:
            raise LayoutError(
                f"{spec.name}: could not place standing group {i + 1} of {spec.static.scattered} "
                f"with {spec.static.scatter_clearance} m clearance after 2000 tries"
            )
    return scattered


def _place_movers(
    spec: SceneSpec,
    lo: np.ndarray,
    hi: np.ndarray,
    all_fp: Footprints,
    agents_xy: np.ndarray,
    targets_xy: np.ndarray,
    spot_xy: np.ndarray,
    spawn_radius: np.ndarray,
    names: list[str],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The movers' start positions (n, 2) and spot indices (n,; -1 off a spot): at distinct spots, near the
    (first) agent (``movers.spawn_near_agent`` of them) or anywhere free (``movers.spawn_random``, and any mover
    left without a usable spot), clear of every agent's start and target (``agents_xy``, ``targets_xy``: (k, 2))."""
    a, mv = spec.agent, spec.movers
    n = len(names)
    mover_xy = np.zeros((n, 2))
    mover_spot = np.full(n, -1)
    order = rng.permutation(n)
    near = set(order[: mv.spawn_near_agent].tolist())
    anywhere = set(order[mv.spawn_near_agent : mv.spawn_near_agent + mv.spawn_random].tolist())
    spot_order = list(rng.permutation(len(spot_xy)))
    placed: list[tuple[np.ndarray, float]] = [(xy, a.radius) for xy in agents_xy]
    agent_xy = agents_xy[0]
    for i in range(n):
        r = spawn_radius[i]  # circumscribed: safe whatever the initial heading

        def free(p: np.ndarray, r: float = r) -> bool:
            return bool(
                np.all(p > lo + r)
                and np.all(p < hi - r)
                and all_fp.distance(p).min(initial=np.inf) > r + 0.5
                and all(np.linalg.norm(p - t) > a.goal_radius + r + 2.0 for t in targets_xy)
                and all(np.linalg.norm(p - q) > r + rq + 2.0 for q, rq in placed)
            )

        ok = False
        if i not in near and i not in anywhere:
            while spot_order:
                s = spot_order.pop()
                if free(spot_xy[s]):
                    mover_xy[i], mover_spot[i], ok = spot_xy[s], s, True
                    break
            if not ok:  # no usable spot left (too many movers, or too tight for this one): free ground
                anywhere.add(i)
        for _ in range(2000 if not ok else 0):
            if i in near:
                ang = rng.uniform(-np.pi, np.pi)
                rad = rng.uniform(a.radius + r + 3.0, max(mv.near_radius, a.radius + r + 4.0))
                p = agent_xy + rad * np.array([np.cos(ang), np.sin(ang)])
            else:
                p = rng.uniform(lo + r + 1.0, hi - r - 1.0)
            if free(p):
                mover_xy[i], ok = p, True
                break
        if not ok:
            raise LayoutError(f"{spec.name}: could not place mover {names[i]} on free ground after 2000 tries")
        placed.append((mover_xy[i], r))
    return mover_xy, mover_spot
