"""Static obstacles: parked aircraft, kiosks and standing groups (joint-less, so never tested against each
other or the arena)."""

from __future__ import annotations

from typing import Literal

from dm_control import composer, mjcf

from deck_sim.entities._common import load_model, planar_footprint

PropKind = Literal["parked_aircraft", "kiosk", "crowd_group"]


class StaticProp(composer.Entity):
    """A static obstacle loaded from ``assets/<kind>.xml``; the task places it with ``set_pose`` each episode."""

    def _build(self, kind: PropKind, name: str | None = None) -> None:
        self.kind = kind
        self._mjcf_root = load_model(f"{kind}.xml", name or kind)
        self.footprint = planar_footprint(self._mjcf_root)

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root
