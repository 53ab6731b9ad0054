"""Arenas: the carrier flight deck and the crowd square, with their named sites."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from dm_control import composer, mjcf

from deck_sim.entities._common import ASSETS
from deck_sim.geometry import Footprints


@dataclass(frozen=True)
class Site2D:
    """A named planar site of an arena: position (m) and yaw (rad)."""

    name: str
    x: float
    y: float
    yaw: float

    @property
    def xy(self) -> np.ndarray:
        """Position as a (2,) array."""
        return np.array([self.x, self.y])


def _site_yaw(site: mjcf.Element) -> float:
    if site.euler is not None:
        return float(np.asarray(site.euler)[2])
    if site.quat is not None:
        w, x, y, z = np.asarray(site.quat, dtype=float)
        return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    return 0.0


class _SiteArena(composer.Arena):
    """An arena loaded from a ``scene_*.xml`` whose sites name spots, slots and starts."""

    _scene_file: str
    _body_name: str

    def _build(self, name: str | None = None) -> None:
        self._mjcf_root = mjcf.from_path(str(ASSETS / self._scene_file))
        if name:
            self._mjcf_root.model = name
        body = self._mjcf_root.find("body", self._body_name)
        self.sites: dict[str, Site2D] = {}
        for s in body.find_all("site"):
            pos = np.asarray(s.pos, dtype=float)
            self.sites[s.name] = Site2D(s.name, float(pos[0]), float(pos[1]), _site_yaw(s))
        surface = self._mjcf_root.find("geom", "surface")
        c, h = np.asarray(surface.pos, dtype=float)[:2], np.asarray(surface.size, dtype=float)[:2]
        self.bounds = np.stack([c - h, c + h])
        """((xmin, ymin), (xmax, ymax)) of the walkable surface, metres; leaving it ends an episode."""
        # the lit scene file sets the global visual; make the free camera frame the whole arena
        self._mjcf_root.statistic.center = [float(c[0]), float(c[1]), 0.0]
        self._mjcf_root.statistic.extent = float(2 * h.max())

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root

    def site(self, name: str) -> Site2D:
        """The site called ``name``; raises ``KeyError`` listing similar names if it does not exist."""
        try:
            return self.sites[name]
        except KeyError:
            prefix = name.split("_")[0]
            near = sorted(n for n in self.sites if n.startswith(prefix))
            raise KeyError(f"arena {self._mjcf_root.model!r} has no site {name!r}; sites like it: {near}") from None

    def sites_with_prefix(self, prefix: str) -> list[Site2D]:
        """Sites whose names start with ``prefix``, sorted by name."""
        return [self.sites[n] for n in sorted(self.sites) if n.startswith(prefix)]

    def fixed_obstacles(self) -> Footprints:
        """Footprints of obstacles that are part of the arena itself (the island); boxes only."""
        return Footprints.empty()

    def on_surface(self, xy: np.ndarray) -> np.ndarray:
        """Whether planar points (..., 2) lie on the walkable surface (NaN is off it)."""
        xy = np.asarray(xy)
        if xy.ndim == 2 and xy.shape[0] <= 64:
            # the task's per-step call (the agent and every mover): plain float comparisons cost less than
            # numpy's calls on a few points, with the same result
            (x0, y0), (x1, y1) = self.bounds.tolist()
            return np.array([x0 <= x <= x1 and y0 <= y <= y1 for x, y in xy.tolist()], dtype=bool)
        return np.all((xy >= self.bounds[0]) & (xy <= self.bounds[1]), axis=-1)


class DeckArena(_SiteArena):
    """The flight deck at sea (assets/scene_deck.xml, including deck.xml)."""

    _scene_file = "scene_deck.xml"
    _body_name = "deck"

    def fixed_obstacles(self) -> Footprints:
        """The island, as a box footprint."""
        island = self._mjcf_root.find("geom", "island")
        pos, size = np.asarray(island.pos, dtype=float), np.asarray(island.size, dtype=float)
        return Footprints(pos[None, :2], size[None, :2], np.zeros(1), np.zeros(1))

    @property
    def fixed_obstacle_geoms(self) -> list[mjcf.Element]:
        """Collision geoms of the arena's own obstacles, in the order of ``fixed_obstacles``."""
        return [self._mjcf_root.find("geom", "island")]


class SquareArena(_SiteArena):
    """The crowd square (assets/scene_square.xml, including square.xml)."""

    _scene_file = "scene_square.xml"
    _body_name = "square"

    @property
    def fixed_obstacle_geoms(self) -> list[mjcf.Element]:
        """The square has no obstacles of its own."""
        return []


def make_arena(kind: str) -> _SiteArena:
    """The arena called ``kind`` (``deck`` or ``square``)."""
    if kind == "deck":
        return DeckArena()
    if kind == "square":
        return SquareArena()
    raise ValueError(f"unknown arena {kind!r}; expected 'deck' or 'square'")
