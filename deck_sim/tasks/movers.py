"""Mover actuation: the movers placed at the start of an episode, their behaviour (speed and turn rate) turned into
actuator controls every control step, and the safety net that puts a mover pushed off the surface back on its next
spot."""

from __future__ import annotations

import logging

import mujoco
import numpy as np
from dm_control import mjcf

from deck_sim.behaviour import MoverBehaviour
from deck_sim.control.tracking import AircraftLimits, speed_and_yaw_rate
from deck_sim.entities import Aircraft, Pedestrian, Tractor
from deck_sim.geometry import Footprints, VisibilityGraph
from deck_sim.scenes import SceneSpec
from deck_sim.tasks.layout import Layout, yaw_quat
from deck_sim.tasks.physics_step import as_slice

log = logging.getLogger(__name__)


class MoverDriver:
    """Writes every mover's controls from its behaviour's command, once per control step.

    Tractors get their two wheel speeds (differential drive), taxiing aircraft steer, thrust and brakes
    (``control.tracking.speed_and_yaw_rate``), pedestrians their walking velocity.

    Args:
        physics: the compiled physics.
        spec: the scene.
        movers: the movers' entities.
        behaviour: the movers' behaviour.
        spot_xy: (k, 2) the movers' spots, metres.
        radii: (n,) every mover's disc radius for its routes, metres.
        n_agents: how many agents lead the state's rows (``FusedStepper.read_state``); the movers yield to every
            one of them.
    """

    def __init__(
        self,
        physics: mjcf.Physics,
        spec: SceneSpec,
        movers: list[Tractor | Aircraft | Pedestrian],
        behaviour: MoverBehaviour,
        spot_xy: np.ndarray,
        radii: np.ndarray,
        n_agents: int = 1,
    ) -> None:
        self._m, self._d = physics.model.ptr, physics.data.ptr
        self._k = n_agents
        self._movers = movers
        self._behaviour = behaviour
        self._spot_xy = spot_xy
        self._radii = radii
        self._clearance = spec.movers.clearance
        self._period = spec.episode.control_period
        self._dwell = spec.movers.dwell_range[0]
        self._scene = spec.name
        groups: dict[str, list[int]] = {"tractor": [], "aircraft": [], "pedestrian": []}
        ctrl: dict[str, list[np.ndarray]] = {"tractor": [], "aircraft": [], "pedestrian": []}
        for i, mover in enumerate(movers):
            kind = (
                "pedestrian"
                if isinstance(mover, Pedestrian)
                else "aircraft"
                if isinstance(mover, Aircraft)
                else "tractor"
            )
            groups[kind].append(i)
            ctrl[kind].append(np.array(physics.bind(list(mover.actuators)).element_id))
        mover_ctrl = {k: (np.array(v, dtype=int) if v else np.zeros((0, 2), dtype=int)) for k, v in ctrl.items()}
        # every mover's controls are written in one assignment: tractors, aircraft, pedestrians
        self._rows = groups
        self._ctrl_flat = as_slice(np.concatenate([mover_ctrl[k].ravel() for k in groups]).astype(int))
        self._ctrl = self._d.ctrl  # (a view: MuJoCo's array, written in place)
        # controller constants come from the compiled model, not from copies of the XML's numbers
        taxiing = [mv for mv in movers if isinstance(mv, Aircraft)]
        if taxiing:
            self._limits = AircraftLimits(**taxiing[0].physical_limits(physics), max_speed=spec.movers.speed_range[1])
        tractors = [mv for mv in movers if isinstance(mv, Tractor)]
        if tractors:
            self._tractor_track, self._tractor_wheel_radius = tractors[0].drive_geometry(physics)

    def start_episode(
        self, physics: mjcf.Physics, layout: Layout, statics: Footprints, bounds: np.ndarray, rng: np.random.Generator
    ) -> None:
        """Plan every mover's first trip round the episode's static obstacles ``statics`` within ``bounds`` and
        place it at rest at its start in ``layout``, heading for its first aim (pedestrians keep the world's
        axes)."""
        # route graphs, one per distinct mover clearance
        graphs: dict[float, VisibilityGraph] = {}
        mover_graphs = []
        for r in self._radii:
            key = round(float(r) + self._clearance, 3)
            if key not in graphs:
                graphs[key] = VisibilityGraph(statics, key, bounds)
            mover_graphs.append(graphs[key])
        self._behaviour.reset(mover_graphs, layout.mover_xy, layout.mover_spot, rng)
        aim = self._behaviour.aim - layout.mover_xy
        mover_yaw = np.arctan2(aim[:, 1], aim[:, 0])
        for i, mover in enumerate(self._movers):
            if isinstance(mover, Pedestrian):
                mover.set_pose(physics, np.array([*layout.mover_xy[i], 0.0]))
                physics.bind(list(mover.joints)).qpos = 0.0
                physics.bind(list(mover.joints)).qvel = 0.0
            else:
                # the attachment frame on the surface (a model's root body carries its own height above it)
                mover.set_pose(physics, np.array([*layout.mover_xy[i], 0.0]), yaw_quat(mover_yaw[i]))
                mover.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))

    def command(self, t: float, st: dict[str, np.ndarray]) -> None:
        """Ask the behaviour for every mover's command at time ``t`` (s) in the state ``st`` (the agents' rows
        first, as ``FusedStepper.read_state`` gives it) and write the movers' controls."""
        if not self._movers:
            return
        k = self._k
        speed, yaw_rate, velocity = self._behaviour.command_lists(
            t,
            self._period,
            st["xy"][k:],
            st["yaw"][k:],
            st["forward_speed"][k:],
            st["xy"][0] if k == 1 else st["xy"][:k],
            float(st["yaw"][0]) if k == 1 else st["yaw"][:k],
        )
        rows = self._rows
        ctrl: list[float] = []  # in the order of ``_ctrl_flat``
        if rows["tractor"]:
            half_track, radius = self._tractor_track / 2, self._tractor_wheel_radius
            for i in rows["tractor"]:
                v, w = speed[i], yaw_rate[i]
                ctrl += ((v - w * half_track) / radius, (v + w * half_track) / radius)
        if rows["aircraft"]:
            speeds = st["forward_speed"].tolist()
            for i in rows["aircraft"]:
                ac = speed_and_yaw_rate(speed[i], yaw_rate[i], speeds[k + i], self._limits)
                ctrl += (ac.steer, ac.thrust, ac.brake, ac.brake)
        if rows["pedestrian"]:
            for i in rows["pedestrian"]:
                ctrl += velocity[i]
        self._ctrl[self._ctrl_flat] = ctrl

    def rescue(self, physics: mjcf.Physics, lost: list[int], st: dict[str, np.ndarray]) -> int:
        """Put the movers ``lost`` (indices) that left the surface (pushed off in a crash) back at rest on their
        next spot, to dwell there and leave as usual; returns how many.

        A safety net, not behaviour: it is logged, and the task counts it in ``last_info["movers_rescued"]``.
        """
        for i in lost:
            mover = self._movers[i]
            xy = self._spot_xy[self._behaviour.spot[i]]
            log.warning(
                "%s: mover %s left the surface at %s; placed back at its next spot %s",
                self._scene,
                mover.mjcf_model.model,
                st["xy"][self._k + i].round(1),
                xy.round(1),
            )
            if isinstance(mover, Pedestrian):
                physics.bind(list(mover.joints)).qpos = (
                    xy - physics.bind(mjcf.get_attachment_frame(mover.mjcf_model)).pos[:2]
                )
                physics.bind(list(mover.joints)).qvel = 0.0
            else:
                mover.set_pose(physics, np.array([*xy, 0.0]), yaw_quat(0.0))
                mover.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
            self._behaviour.mode[i] = 1  # dwell, then leave as usual
            self._behaviour.dwell_until[i] = physics.data.time + self._dwell
        mujoco.mj_forward(self._m, self._d)
        return len(lost)
