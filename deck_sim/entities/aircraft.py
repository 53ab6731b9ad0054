"""The wheeled aircraft: steerable nose wheel, main gear braked by dampers, engine thrust."""

from __future__ import annotations

from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from deck_sim.entities._common import load_model, planar_footprint, planar_parts


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
        center, half, radius = planar_footprint(self._mjcf_root)
        self.footprint = (center, half, radius)
        self.parts = planar_parts(self._mjcf_root)  # (k, 5) rounded boxes, one per collision geom

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

    def physical_limits(self, physics: mjcf.Physics) -> dict[str, float]:
        """What a controller must know of this aircraft, read from the compiled model (SI units).

        Keys: ``mass`` (kg, whole vehicle), ``wheelbase`` (m, nose axle to main axle), ``max_steer`` (rad),
        ``max_thrust`` (N at command 1), ``brake_kv`` (N m s/rad of one main-wheel damper at command 1) and
        ``wheel_radius`` (m, main wheels); the keyword names of ``control.tracking.AircraftLimits``.
        """
        model = physics.model
        nose = physics.bind(self._mjcf_root.find("body", "nose_gear")).pos
        main = physics.bind(self._mjcf_root.find("body", "main_left")).pos
        return {
            "mass": float(model.body_subtreemass[physics.bind(self._root_body).element_id]),
            "wheelbase": float(nose[0] - main[0]),
            "max_steer": float(physics.bind(self._steer).ctrlrange[1]),
            "max_thrust": float(physics.bind(self._thrust).gear[0]),
            "brake_kv": float(-physics.bind(self._brakes[0]).gainprm[2]),  # damper: gain = -kv * velocity
            "wheel_radius": float(physics.bind(self._mjcf_root.find("geom", "main_left_wheel")).size[0]),
        }


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
