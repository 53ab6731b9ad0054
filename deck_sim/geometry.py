"""Planar geometry on the deck (numpy only): obstacle footprints, clearances and shortest paths.

Every obstacle footprint is a rounded, oriented rectangle: a box of half-extents ``half`` rotated by ``yaw``
about ``center``, grown by ``radius`` in every direction. A circle is a box with zero half-extents; a plain box
has zero radius. Distances are metres, angles radians.

Shortest paths use a visibility graph: each footprint, grown by the mover's own radius, is enclosed by an octagon
whose vertices (pushed out by a small margin) are the graph's nodes; A* expands nodes lazily, testing each edge
against every octagon with Cyrus-Beck clipping. The result is the shortest polyline that keeps the clearance
(up to the octagon's over-approximation of the rounded box).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

_OCT_ANGLES = np.arange(8) * (np.pi / 4.0)
_OCT_NORMALS = np.stack([np.cos(_OCT_ANGLES), np.sin(_OCT_ANGLES)], axis=1)  # (8, 2) in the box frame


class NoPathError(RuntimeError):
    """No collision-free path exists between two points among the given obstacles."""


def rotation(yaw: np.ndarray) -> np.ndarray:
    """(k, 2, 2) rotation matrices for yaws (k,) in radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def world_to_agent(vectors: np.ndarray, yaw: float) -> np.ndarray:
    """Vectors (..., 2) given in the world's axes, in the axes of an agent heading ``yaw`` radians (x ahead, y to
    its left): each is turned by minus the yaw (row vectors times ``rotation(yaw)``); lengths are kept."""
    return np.asarray(vectors, dtype=np.float64) @ rotation(np.float64(yaw))


def clip_length(vectors: np.ndarray, max_length: float) -> np.ndarray:
    """Vectors (..., 2) with each one's length clipped to ``max_length`` metres (> 0), its direction kept; a new
    array."""
    v = np.asarray(vectors, dtype=float)
    length = np.hypot(v[..., 0], v[..., 1])
    scale = np.where(length > max_length, max_length / np.maximum(length, 1e-300), 1.0)
    return v * scale[..., None]


def end_circles(parts: np.ndarray, radius: float) -> np.ndarray:
    """(k, 3) circles (x, y, radius; metres, in the body's own frame) at the ends of a body's parts that stick
    out of the disc of ``radius`` round its origin.

    ``parts`` (m, 5) are rounded boxes (centre x, y, half-length, half-width, rounding radius), as
    ``entities.planar_parts`` gives them. Each part's two ends along its longer axis that lie outside the disc
    become circles as wide as the part there (its shorter half-extent plus its rounding). For an aircraft whose
    disc is half its wing span these are the nose and the tail: what a disc leaves out of a long fuselage. A
    cover of the ends, not of every corner (a box's corners beside an end inside the disc may stick out by less
    than its half-width)."""
    rows = []
    for cx, cy, hx, hy, r in np.asarray(parts, dtype=float).reshape(-1, 5):
        along = np.array([hx, 0.0]) if hx >= hy else np.array([0.0, hy])
        for end in (np.array([cx, cy]) + along, np.array([cx, cy]) - along):
            if np.hypot(*end) > radius:
                rows.append([end[0], end[1], min(hx, hy) + r])
    return np.array(rows, dtype=float).reshape(-1, 3)


def agent_to_world(vectors: np.ndarray, yaw: float) -> np.ndarray:
    """The inverse of ``world_to_agent``: vectors (..., 2) in the agent's axes, in the world's."""
    return np.asarray(vectors, dtype=np.float64) @ rotation(np.float64(yaw)).T


@dataclass(frozen=True)
class Footprints:
    """k rounded oriented rectangles in the plane.

    Attributes:
        centers: (k, 2) metres.
        half: (k, 2) half-extents along the footprint's own x and y axes, metres.
        yaw: (k,) orientation of the footprint's x axis, radians.
        radius: (k,) rounding radius, metres.
    """

    centers: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    radius: np.ndarray

    @staticmethod
    def empty() -> Footprints:
        """No obstacles."""
        return Footprints(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    @staticmethod
    def concatenate(parts: list[Footprints]) -> Footprints:
        """All footprints of ``parts`` in order."""
        parts = [p for p in parts if len(p)] or [Footprints.empty()]
        return Footprints(
            np.concatenate([p.centers for p in parts]),
            np.concatenate([p.half for p in parts]),
            np.concatenate([p.yaw for p in parts]),
            np.concatenate([p.radius for p in parts]),
        )

    def __len__(self) -> int:
        return int(self.centers.shape[0])

    def inflate(self, margin: float) -> Footprints:
        """The same footprints grown by ``margin`` metres."""
        return Footprints(self.centers, self.half, self.yaw, self.radius + margin)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (p, k) from each point (p, 2) to each footprint's boundary; negative inside."""
        points = np.atleast_2d(points)
        rel = points[:, None, :] - self.centers[None, :, :]
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        lx = rel[..., 0] * c + rel[..., 1] * s
        ly = -rel[..., 0] * s + rel[..., 1] * c
        qx = np.abs(lx) - self.half[:, 0]
        qy = np.abs(ly) - self.half[:, 1]
        outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
        inside = np.minimum(np.maximum(qx, qy), 0.0)
        return outside + inside - self.radius

    def nearest_points(self, point: np.ndarray) -> np.ndarray:
        """(k, 2) the point of each footprint's boundary nearest to ``point`` (2,); ``point`` itself if inside."""
        rel = np.asarray(point, dtype=np.float64)[None, :] - self.centers
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        lx = rel[:, 0] * c + rel[:, 1] * s
        ly = -rel[:, 0] * s + rel[:, 1] * c
        qx, qy = np.clip(lx, -self.half[:, 0], self.half[:, 0]), np.clip(ly, -self.half[:, 1], self.half[:, 1])
        dx, dy = lx - qx, ly - qy
        gap = np.hypot(dx, dy)
        outside = gap > self.radius
        scale = np.where(outside, self.radius / np.where(gap > 0, gap, 1.0), 0.0)
        nx = np.where(outside, qx + dx * scale, lx)
        ny = np.where(outside, qy + dy * scale, ly)
        return self.centers + np.stack([nx * c - ny * s, nx * s + ny * c], axis=1)

    def octagons(self, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Half-planes of the octagon enclosing each footprint grown by ``margin``.

        Returns:
            normals (k, 8, 2) unit outward normals in the world frame and offsets (k, 8): a point x is inside
            octagon j iff ``normals[j] @ x < offsets[j]`` for all 8 rows.
        """
        rot = rotation(self.yaw)  # (k, 2, 2)
        normals = np.einsum("kij,nj->kni", rot, _OCT_NORMALS)
        support = (
            np.abs(_OCT_NORMALS[None, :, 0]) * self.half[:, None, 0]
            + np.abs(_OCT_NORMALS[None, :, 1]) * self.half[:, None, 1]
            + (self.radius[:, None] + margin)
        )
        offsets = np.einsum("kni,ki->kn", normals, self.centers) + support
        return normals, offsets

    def octagon_vertices(self, margin: float = 0.0) -> np.ndarray:
        """(k, 8, 2) vertices of the enclosing octagons grown by ``margin``, in world coordinates."""
        normals, offsets = self.octagons(margin)
        n1, n2 = normals, np.roll(normals, -1, axis=1)
        c1, c2 = offsets, np.roll(offsets, -1, axis=1)
        det = n1[..., 0] * n2[..., 1] - n1[..., 1] * n2[..., 0]
        x = (c1 * n2[..., 1] - c2 * n1[..., 1]) / det
        y = (n1[..., 0] * c2 - n2[..., 0] * c1) / det
        return np.stack([x, y], axis=-1)


def segments_blocked(
    a: np.ndarray,
    b: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    eps: float = 1e-6,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Whether each segment a[i] -> b[i] (s, 2) passes through the interior of any octagon: (s,) bool.

    ``bounds`` (centres (k, 2), radii (k,)) of discs enclosing the octagons skip the exact test for the pairs of
    a segment and an octagon whose disc the segment does not reach; the result is the same, only cheaper when
    most obstacles are far from most segments (a visibility graph's case).
    """
    if normals.shape[0] == 0 or a.shape[0] == 0:
        return np.zeros(a.shape[0], dtype=bool)
    d = b - a
    if bounds is None:
        return _clip_blocked(a, d, normals[None], offsets[None], eps).any(axis=1)
    centers, radii = bounds
    rel = centers[None, :, :] - a[:, None, :]  # (s, k, 2)
    length2 = np.maximum(np.einsum("si,si->s", d, d), 1e-18)
    t = np.clip(np.einsum("ski,si->sk", rel, d) / length2[:, None], 0.0, 1.0)
    gap = rel - t[..., None] * d[:, None, :]
    near = np.einsum("ski,ski->sk", gap, gap) < (radii[None, :] + 1e-3) ** 2
    seg, obs = np.nonzero(near)
    out = np.zeros(a.shape[0], dtype=bool)
    if seg.size:
        hit = _clip_blocked(a[seg], d[seg], normals[obs][:, None], offsets[obs][:, None], eps)[:, 0]
        out[seg[hit]] = True
    return out


def _clip_blocked(a: np.ndarray, d: np.ndarray, normals: np.ndarray, offsets: np.ndarray, eps: float) -> np.ndarray:
    """(s, k) whether segment s from a[s] along d[s] enters octagon k: normals (s or 1, k, 8, 2), offsets (., k, 8).

    Cyrus-Beck clipping of the segment against the octagon's eight half-planes.
    """
    num = offsets - np.einsum("skni,si->skn", normals, a)  # (s, k, 8)
    den = np.einsum("skni,si->skn", normals, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    enter = np.where(den < 0, t, -np.inf).max(axis=2)
    leave = np.where(den > 0, t, np.inf).min(axis=2)
    parallel_out = ((den == 0) & (num <= eps)).any(axis=2)
    enter = np.maximum(enter, 0.0)
    leave = np.minimum(leave, 1.0)
    return (enter < leave - eps) & ~parallel_out


def points_inside(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Whether each point (p, 2) lies inside any octagon: (p,) bool."""
    if normals.shape[0] == 0:
        return np.zeros(points.shape[0], dtype=bool)
    proj = np.einsum("kni,pi->pkn", normals, points)
    return (proj < offsets[None]).all(axis=2).any(axis=1)


@dataclass
class VisibilityGraph:
    """Shortest collision-free paths among fixed footprints for a disc of radius ``clearance``.

    Build once per set of static obstacles (an episode); ``shortest_path`` then costs a lazy A* over the
    octagon vertices. ``bounds`` ((xmin, ymin), (xmax, ymax)) drops nodes off the deck or plaza.
    """

    footprints: Footprints
    clearance: float
    bounds: np.ndarray
    node_margin: float = 0.05

    def __post_init__(self) -> None:
        grown = self.footprints.inflate(self.clearance)
        self._normals, self._offsets = grown.octagons()
        if len(grown):
            vertices = grown.octagon_vertices()
            self._discs = (grown.centers, np.linalg.norm(vertices - grown.centers[:, None], axis=2).max(axis=1))
            nodes = grown.octagon_vertices(self.node_margin).reshape(-1, 2)
        else:
            self._discs = (np.zeros((0, 2)), np.zeros(0))
            nodes = np.zeros((0, 2))
        lo, hi = np.asarray(self.bounds[0]), np.asarray(self.bounds[1])
        keep = np.all((nodes >= lo + self.clearance) & (nodes <= hi - self.clearance), axis=1)
        nodes = nodes[keep]
        nodes = nodes[~points_inside(nodes, self._normals, self._offsets)]
        self.nodes = nodes
        self._visible: dict[int, np.ndarray] = {}
        self._goals: dict[bytes, list[np.ndarray | None]] = {}
        """goal -> [obstacles containing it, nodes that see it, node distances to it] (the last two once a path
        needs the graph): goals repeat (the movers' spots, the agent's target), so each is worked out once."""

    def blocked(self, a: np.ndarray, b: np.ndarray, ignore: np.ndarray | None = None) -> np.ndarray:
        """Whether segments a[i] -> b[i] cross a grown obstacle (except those masked by ``ignore`` (k,))."""
        normals, offsets, (centers, radii) = self._normals, self._offsets, self._discs
        if ignore is not None and ignore.any():
            keep = ~ignore
            normals, offsets, centers, radii = normals[keep], offsets[keep], centers[keep], radii[keep]
        return segments_blocked(np.atleast_2d(a), np.atleast_2d(b), normals, offsets, bounds=(centers, radii))

    def _leaving(self, point: np.ndarray, inside: np.ndarray) -> np.ndarray:
        """(nodes,) whether the segment from ``point`` to each node heads away from every obstacle containing it.

        A start inside a grown obstacle may only leave it (not cross it); a goal inside one is entered the same
        way, from the side it lies on.
        """
        if not inside.any() or len(self.nodes) == 0:
            return np.ones(len(self.nodes), dtype=bool)
        away = point[None, :] - self.footprints.centers[inside]  # (c, 2)
        return np.all((self.nodes - point) @ away.T > 0.0, axis=1)

    def _containing(self, point: np.ndarray) -> np.ndarray:
        """(k,) mask of the grown obstacles that contain ``point``."""
        if self._normals.shape[0] == 0:
            return np.zeros(0, dtype=bool)
        return (np.einsum("kni,i->kn", self._normals, point) < self._offsets).all(axis=1)

    def _neighbours(self, i: int) -> np.ndarray:
        """Indices of graph nodes visible from node i (cached)."""
        cached = self._visible.get(i)
        if cached is None:
            others = np.arange(len(self.nodes))
            others = others[others != i]
            a = np.repeat(self.nodes[i : i + 1], len(others), axis=0)
            cached = others[~self.blocked(a, self.nodes[others])]
            self._visible[i] = cached
        return cached

    def _goal(self, goal: np.ndarray, nodes: bool = False) -> list[np.ndarray | None]:
        """[obstacles containing ``goal``, nodes from which the last segment to it is allowed, node distances to
        it] (the last two only with ``nodes``, else possibly None), cached per goal (at most 256 goals: then the
        oldest is forgotten). Read only."""
        key = goal.tobytes()
        cached = self._goals.get(key)
        if cached is None:
            if len(self._goals) >= 256:
                del self._goals[next(iter(self._goals))]
            cached = self._goals[key] = [self._containing(goal), None, None]
        if nodes and cached[1] is None:
            in_goal, n = cached[0], len(self.nodes)
            cached[1] = ~self.blocked(np.repeat(goal[None], n, 0), self.nodes, in_goal) & self._leaving(goal, in_goal)
            cached[2] = np.linalg.norm(self.nodes - goal, axis=1)
        return cached

    def shortest_path(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Shortest polyline (m, 2) from ``start`` to ``goal`` including both ends.

        A start or goal inside a grown obstacle is allowed (the first or last segment may leave or enter it);
        only the segments between are kept clear.

        Raises:
            NoPathError: if the goal cannot be reached.
        """
        start = np.asarray(start, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        # the first and last segments may leave the obstacles that contain their end point
        in_start, in_goal = self._containing(start), self._goal(goal)[0]
        direct_ok = not self.blocked(start, goal, in_start | in_goal)[0]
        if direct_ok and (in_start.any() or in_goal.any()):
            # a direct segment between points inside obstacles must also leave and enter them properly
            d = goal - start
            direct_ok = bool(
                np.all((start - self.footprints.centers[in_start]) @ d > 0.0)
                and np.all((goal - self.footprints.centers[in_goal]) @ -d > 0.0)
            )
        if direct_ok:
            return np.stack([start, goal])
        n = len(self.nodes)
        ok_start = ~self.blocked(np.repeat(start[None], n, 0), self.nodes, in_start) & self._leaving(start, in_start)
        _, ok_goal, dist_goal = self._goal(goal, nodes=True)
        from_start = np.flatnonzero(ok_start) if n else []
        to_goal = set(np.flatnonzero(ok_goal).tolist()) if n else set()
        if len(from_start) == 0 or not to_goal:
            raise NoPathError(f"no visible graph node from {start.round(2)} or to {goal.round(2)}")
        g = np.full(n, np.inf)
        parent = np.full(n, -1)
        heap: list[tuple[float, int]] = []
        for j in from_start:
            g[j] = float(np.linalg.norm(self.nodes[j] - start))
            heapq.heappush(heap, (g[j] + dist_goal[j], int(j)))
        best_goal, best_last = np.inf, -1
        closed = np.zeros(n, dtype=bool)
        while heap:
            f, i = heapq.heappop(heap)
            if f >= best_goal:
                break
            if closed[i]:
                continue
            closed[i] = True
            if i in to_goal and g[i] + dist_goal[i] < best_goal:
                best_goal, best_last = g[i] + dist_goal[i], i
            nb = self._neighbours(i)
            cand = g[i] + np.linalg.norm(self.nodes[nb] - self.nodes[i], axis=1)
            better = cand < g[nb]
            for j, gj in zip(nb[better], cand[better], strict=True):
                g[j] = gj
                parent[j] = i
                heapq.heappush(heap, (gj + dist_goal[j], int(j)))
        if best_last < 0:
            raise NoPathError(f"goal {goal.round(2)} is not reachable from {start.round(2)}")
        chain = [best_last]
        while parent[chain[-1]] >= 0:
            chain.append(int(parent[chain[-1]]))
        return np.vstack([start[None], self.nodes[chain[::-1]], goal[None]])


def points_along(path: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """The points (k, 2) at arc lengths ``distances`` (k,) metres along a polyline (m, 2) from its start; a
    distance beyond the polyline's end gives its end, a negative one its start."""
    seg = np.diff(path, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.asarray(distances, dtype=np.float64)
    return np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=-1)


def polyline_length(path: np.ndarray) -> float:
    """Length in metres of a polyline (m, 2)."""
    if len(path) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
