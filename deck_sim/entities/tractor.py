"""The deck tractor: differential drive on two wheels and a frictionless caster."""

from __future__ import annotations

from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from deck_sim.entities._common import load_model, planar_footprint


class Tractor(composer.Entity):
    """A deck tractor mover (assets/tractor.xml); actuators are wheel-speed servos (rad/s)."""

    def _build(self, name: str = "tractor") -> None:
        self._mjcf_root = load_model("tractor.xml", name)
        self._root_body = self._mjcf_root.find("body", "tractor")
        self._wheels = (
            self._mjcf_root.find("actuator", "left_wheel"),
            self._mjcf_root.find("actuator", "right_wheel"),
        )
        self.footprint = planar_footprint(self._mjcf_root)

    def _build_observables(self) -> TractorObservables:
        return TractorObservables(self)

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root

    @property
    def root_body(self) -> mjcf.Element:
        """The chassis body (carries the free joint once attached)."""
        return self._root_body

    @property
    def actuators(self) -> tuple[mjcf.Element, ...]:
        """Left and right wheel-speed servos."""
        return self._wheels

    def drive_geometry(self, physics: mjcf.Physics) -> tuple[float, float]:
        """(track, wheel radius) in metres, read from the compiled model: wheel speeds for a forward speed v
        and turn rate w are (v -+ w track / 2) / radius."""
        left = physics.bind(self._mjcf_root.find("body", "left_wheel")).pos
        right = physics.bind(self._mjcf_root.find("body", "right_wheel")).pos
        radius = physics.bind(self._mjcf_root.find("geom", "left_wheel")).size[0]
        return float(left[1] - right[1]), float(radius)


class TractorObservables(composer.Observables):
    """Position and body-frame velocity of the tractor."""

    @composer.observable
    def position(self) -> observable.MJCFFeature:
        """World position of the imu site, metres."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "position"))

    @composer.observable
    def velocity(self) -> observable.MJCFFeature:
        """Velocity in the chassis frame, m/s."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "velocity"))
