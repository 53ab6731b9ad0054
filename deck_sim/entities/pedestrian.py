"""A walking pedestrian: holonomic on slide joints, with velocity servos."""

from __future__ import annotations

from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from deck_sim.entities._common import load_model, planar_footprint, planar_parts


class Pedestrian(composer.Entity):
    """A pedestrian (assets/pedestrian.xml): the square's agent and its walking movers.

    Its slide joints are in the attachment frame, so ``set_pose`` moves the frame and the joints hold the
    displacement from it; actuators are world-frame velocity servos (m/s).
    """

    def _build(self, name: str = "pedestrian", rgba: tuple[float, float, float, float] | None = None) -> None:
        self._mjcf_root = load_model("pedestrian.xml", name)
        self._root_body = self._mjcf_root.find("body", "pedestrian")
        self._joints = (self._mjcf_root.find("joint", "x"), self._mjcf_root.find("joint", "y"))
        self._servos = (self._mjcf_root.find("actuator", "x"), self._mjcf_root.find("actuator", "y"))
        if rgba is not None:
            self._mjcf_root.find("geom", "body_visual").rgba = rgba
        self.footprint = planar_footprint(self._mjcf_root)
        self.parts = planar_parts(self._mjcf_root)  # (k, 5) rounded boxes, one per collision geom

    def _build_observables(self) -> PedestrianObservables:
        return PedestrianObservables(self)

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root

    @property
    def root_body(self) -> mjcf.Element:
        """The body that carries the slide joints."""
        return self._root_body

    @property
    def joints(self) -> tuple[mjcf.Element, ...]:
        """Slide x and slide y."""
        return self._joints

    @property
    def actuators(self) -> tuple[mjcf.Element, ...]:
        """Velocity servos along world x and y."""
        return self._servos


class PedestrianObservables(composer.Observables):
    """Position and velocity of the pedestrian."""

    @composer.observable
    def position(self) -> observable.MJCFFeature:
        """World position of the imu site, metres."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "position"))

    @composer.observable
    def velocity(self) -> observable.MJCFFeature:
        """Velocity, m/s (the body does not rotate, so body frame = world frame)."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "velocity"))
