"""The wheeled aircraft: steerable nose wheel, main gear braked by dampers, engine thrust."""

from __future__ import annotations

from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from deck_sim.entities._common import load_model, planar_footprint

WHEELBASE = 5.4
"""Metres between the nose-wheel axle and the main-gear axle (aircraft.xml)."""


class Aircraft(composer.Entity):
    """A fighter-class aircraft that taxis on real wheel contacts (assets/aircraft.xml).

    Actuators: ``nose_steer`` (position servo, rad), ``thrust`` (0..1 of 30 kN), ``brake_left`` and
    ``brake_right`` (0..1 of the wheel dampers). Used as the agent on the deck and as a taxiing mover.
    """

    def _build(self, name: str = "aircraft") -> None:
        self._mjcf_root = load_model("aircraft.xml", name)
        self._root_body = self._mjcf_root.find("body", "aircraft")
        self._steer = self._mjcf_root.find("actuator", "nose_steer")
        self._thrust = self._mjcf_root.find("actuator", "thrust")
        self._brakes = [self._mjcf_root.find("actuator", n) for n in ("brake_left", "brake_right")]
        self._collision_geoms = [
            g
            for g in self._mjcf_root.find_all("geom")
            if g.dclass is not None and g.dclass.dclass == "collision"
        ]
        center, half, radius = planar_footprint(self._mjcf_root)
        self.footprint = (center, half, radius)

    def _build_observables(self) -> AircraftObservables:
        return AircraftObservables(self)

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root

    @property
    def root_body(self) -> mjcf.Element:
        """The airframe body (carries the free joint once attached)."""
        return self._root_body

    @property
    def actuators(self) -> tuple[mjcf.Element, ...]:
        """Steer, thrust, left brake, right brake (the order of ``command``'s columns)."""
        return (self._steer, self._thrust, *self._brakes)

    @property
    def collision_geoms(self) -> list[mjcf.Element]:
        """Geoms whose contacts with obstacles count as collisions."""
        return self._collision_geoms

    @property
    def max_steer(self) -> float:
        """Largest nose-wheel angle in radians."""
        return float(self._steer.ctrlrange[1])


class AircraftObservables(composer.Observables):
    """Sensors of the aircraft's imu site (disabled unless a task enables them)."""

    @composer.observable
    def position(self) -> observable.MJCFFeature:
        """World position of the imu site, metres."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "position"))

    @composer.observable
    def heading(self) -> observable.MJCFFeature:
        """Unit x axis of the airframe in the world frame."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "heading"))

    @composer.observable
    def velocity(self) -> observable.MJCFFeature:
        """Velocity in the airframe, m/s."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "velocity"))

    @composer.observable
    def gyro(self) -> observable.MJCFFeature:
        """Angular velocity in the airframe, rad/s."""
        return observable.MJCFFeature("sensordata", self._entity.mjcf_model.find("sensor", "gyro"))
