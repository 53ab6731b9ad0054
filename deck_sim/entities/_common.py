"""Helpers shared by the entities: asset paths and planar footprints read from MJCF collision geoms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from dm_control import mjcf

ASSETS = Path(__file__).resolve().parent.parent / "assets"


def load_model(filename: str, name: str) -> mjcf.RootElement:
    """Parse ``assets/<filename>`` and rename its model to ``name``; drop a free joint and keyframes.

    The asset files are complete MuJoCo models (menagerie style, viewable alone); composer attaches entities
    through its own frames, so the model's own free joint and keyframes are removed here.
    """
    root = mjcf.from_path(str(ASSETS / filename))
    root.model = name
    for joint in root.find_all("joint"):
        if joint.tag == "freejoint" or getattr(joint, "type", None) == "free":
            joint.remove()
    if root.keyframe is not None:
        for key in list(root.keyframe.all_children()):
            key.remove()
    return root


def _is_collision(geom: mjcf.Element) -> bool:
    return geom.dclass is not None and geom.dclass.dclass == "collision"


def planar_footprint(root: mjcf.RootElement) -> tuple[np.ndarray, np.ndarray, float]:
    """Planar footprint of a model's collision geoms in its own frame: (center (2,), half (2,), radius).

    A model whose only collision geom is a vertical cylinder, capsule or sphere gets a circle (zero half-extents,
    its radius); otherwise the axis-aligned box bounding every collision geom in the x-y plane. Collision geoms
    must not be rotated about z (checked).
    """
    geoms = [g for g in root.find_all("geom") if _is_collision(g)]
    if not geoms:
        raise ValueError(f"model {root.model!r} has no collision geoms (class 'collision')")
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for g in geoms:
        if g.euler is not None and abs(float(np.asarray(g.euler)[2])) > 1e-9:
            raise ValueError(f"collision geom {g.name!r} is rotated about z; footprints assume it is not")
        size = np.asarray(g.size, dtype=float)
        pos = np.zeros(3) if g.pos is None else np.asarray(g.pos, dtype=float)
        gtype = g.type or "sphere"
        if gtype == "box":
            ext = size[:2]
            glo, ghi = pos[:2] - ext, pos[:2] + ext
        elif gtype in ("sphere", "cylinder") or (gtype == "capsule" and g.fromto is None):
            glo, ghi = pos[:2] - size[0], pos[:2] + size[0]
        elif gtype == "capsule":
            ft = np.asarray(g.fromto, dtype=float)
            glo = np.minimum(ft[:2], ft[3:5]) - size[0]
            ghi = np.maximum(ft[:2], ft[3:5]) + size[0]
        else:
            raise ValueError(f"collision geom {g.name!r}: footprint of type {gtype!r} not supported")
        lo, hi = np.minimum(lo, glo), np.maximum(hi, ghi)
    center, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    if len(geoms) == 1 and (
        geoms[0].type in ("cylinder", "sphere")
        or (
            geoms[0].type == "capsule"
            and geoms[0].fromto is not None
            and np.allclose(np.asarray(geoms[0].fromto)[:2], np.asarray(geoms[0].fromto)[3:5])
        )
    ):
        return center, np.zeros(2), float(half[0])
    return center, half, 0.0


def planar_parts(root: mjcf.RootElement) -> np.ndarray:
    """(k, 5) every collision geom of a model as a planar rounded box in the model's frame: centre x, y,
    half-length, half-width, radius (metres). Finer than ``planar_footprint``'s one box: an aircraft is a cross of
    fuselage, wings and tail, not the rectangle around them."""
    rows = []
    for g in root.find_all("geom"):
        if not _is_collision(g):
            continue
        size = np.asarray(g.size, dtype=float)
        pos = np.zeros(3) if g.pos is None else np.asarray(g.pos, dtype=float)
        gtype = g.type or "sphere"
        if gtype == "box":
            rows.append([pos[0], pos[1], size[0], size[1], 0.0])
        elif gtype in ("sphere", "cylinder") or (gtype == "capsule" and g.fromto is None):
            rows.append([pos[0], pos[1], 0.0, 0.0, size[0]])
        elif gtype == "capsule":
            ft = np.asarray(g.fromto, dtype=float)
            mid, half = (ft[:2] + ft[3:5]) / 2.0, np.abs(ft[3:5] - ft[:2]) / 2.0
            rows.append([mid[0], mid[1], half[0], half[1], size[0]])
        else:
            raise ValueError(f"collision geom {g.name!r}: footprint of type {gtype!r} not supported")
    if not rows:
        raise ValueError(f"model {root.model!r} has no collision geoms (class 'collision')")
    return np.array(rows)
