"""What a scene's values are checked against, read from the model files in ``deck_sim/assets``: each arena's sites
and walkable surface, and each vehicle's top speed.

Read with the standard library's XML parser (no MuJoCo, no dm_control), so that loading a scene stays cheap; the
values are the ones the compiled models hold (``tests/test_scene_bounds.py`` compares them).
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

ASSETS = Path(__file__).resolve().parent.parent / "assets"

ARENA_FILES = {"deck": ("scene_deck.xml", "deck"), "square": ("scene_square.xml", "square")}
"""Arena name -> (scene file in ``assets``, name of the body that holds its sites and its ``surface`` geom); the
files ``deck_sim.entities.arenas`` builds the arenas from."""


@dataclass(frozen=True)
class ArenaFacts:
    """An arena's named sites and walkable surface (planar, metres)."""

    name: str
    sites: dict[str, tuple[float, float]]
    """Site name -> (x, y), in the arena's frame (the world's)."""
    lo: tuple[float, float]
    """(xmin, ymin) of the walkable surface."""
    hi: tuple[float, float]
    """(xmax, ymax) of the walkable surface."""

    @property
    def diagonal(self) -> float:
        """Length of the surface's diagonal, metres: no distance on the surface is longer."""
        return math.hypot(self.hi[0] - self.lo[0], self.hi[1] - self.lo[1])

    @property
    def perimeter(self) -> float:
        """Perimeter of the surface, metres."""
        return 2.0 * ((self.hi[0] - self.lo[0]) + (self.hi[1] - self.lo[1]))

    def sites_with_prefix(self, prefix: str) -> list[str]:
        """Names of the sites that start with ``prefix``, sorted (as ``_SiteArena.sites_with_prefix``)."""
        return sorted(n for n in self.sites if n.startswith(prefix))

    def on_surface(self, x: float, y: float) -> bool:
        """Whether the point (x, y) lies on the walkable surface."""
        return self.lo[0] <= x <= self.hi[0] and self.lo[1] <= y <= self.hi[1]


def _floats(text: str | None, n: int) -> tuple[float, ...]:
    values = tuple(float(v) for v in (text or "").split())
    return values + (0.0,) * (n - len(values))


def _root_with_includes(path: Path) -> ET.Element:
    """The ``<mujoco>`` element of ``path`` with every ``<include file=...>`` replaced by the included file's
    children (one level, as the scene files use it)."""
    root = ET.parse(path).getroot()
    for parent in list(root.iter()):
        for i, child in enumerate(list(parent)):
            if child.tag == "include":
                parent.remove(child)
                for j, included in enumerate(_root_with_includes(path.parent / child.attrib["file"])):
                    parent.insert(i + j, included)
    return root


@functools.cache
def arena_facts(arena: str) -> ArenaFacts:
    """The sites and surface of the arena called ``arena`` (``deck`` or ``square``)."""
    filename, body_name = ARENA_FILES[arena]
    root = _root_with_includes(ASSETS / filename)
    body = next(b for b in root.iter("body") if b.get("name") == body_name)
    sites = {s.attrib["name"]: _floats(s.get("pos"), 3)[:2] for s in body.iter("site")}
    surface = next(g for g in body.iter("geom") if g.get("name") == "surface")
    (cx, cy, _), (hx, hy, _) = _floats(surface.get("pos"), 3), _floats(surface.get("size"), 3)
    return ArenaFacts(arena, sites, (cx - hx, cy - hy), (cx + hx, cy + hy))


def _default_attribute(root: ET.Element, tag: str, cls: str, attribute: str) -> str | None:
    """``attribute`` of the ``tag`` default of class ``cls`` (or of a class it nests in)."""
    for default in root.iter("default"):
        if default.get("class") != cls:
            continue
        for element in default.iter(tag):
            if element.get(attribute) is not None:
                return element.get(attribute)
    return None


def _ctrl_max(root: ET.Element, actuator: str) -> float:
    element = next(a for a in root.find("actuator") if a.get("name") == actuator)
    return max(abs(v) for v in _floats(element.get("ctrlrange"), 2))


@functools.cache
def vehicle_top_speeds() -> dict[str, float]:
    """Top speed of every vehicle, m/s: ``tractor`` (its wheel-speed servos' limit times its wheel radius),
    ``pedestrian`` (its walking-velocity servos' limit, in any direction) and ``aircraft`` (the taxi speed limit of
    the tracking controller, ``control.tracking.AircraftLimits.max_speed``: its thrust has no speed limit of its
    own)."""
    from deck_sim.control.tracking import AircraftLimits

    tractor = ET.parse(ASSETS / "tractor.xml").getroot()
    wheel = next(g for g in tractor.iter("geom") if g.get("name") == "left_wheel")
    size = wheel.get("size") or _default_attribute(tractor, "geom", wheel.get("class", ""), "size")
    pedestrian = ET.parse(ASSETS / "pedestrian.xml").getroot()
    return {
        "tractor": _ctrl_max(tractor, "left_wheel") * _floats(size, 1)[0],
        "aircraft": AircraftLimits.max_speed,
        "pedestrian": min(_ctrl_max(pedestrian, "x"), _ctrl_max(pedestrian, "y")),
    }
