"""A robot, its controller constants and an engine, assembled once, with the record of how."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg import robots
from mjxcpg.control import ik
from mjxcpg.control.controller import ControllerParams
from mjxcpg.physics import engines, hardware
from mjxcpg.physics.model import Layout, load_model
from mjxcpg.robots.description import LEG_JOINTS

ROBOTS = ("nominal", *hardware.MISMATCHES)  # the simulated robot; see mjxcpg.physics.hardware
HARDWARE_PLATFORM = "qrio"         # the platform whose hardware mismatch mjxcpg.physics.hardware models


@dataclasses.dataclass(frozen=True)
class SimulationSpec:
    """How a simulation is built, every choice resolved (``Simulation.spec``)."""

    engine: str                   # one of engines.ENGINES
    platform: str                 # one of mjxcpg.robots.PLATFORMS
    slope_deg: float              # floor slope, uphill along +x positive
    physics_dt: float | None      # physics time step (s); None before ``build_simulation``: the model's
    robot: str                    # one of ROBOTS: the nominal robot or its hardware stand-in
    params: ControllerParams      # the controller's constants: their one home in a simulation


@dataclasses.dataclass(frozen=True)
class Simulation:
    spec: SimulationSpec
    model: mujoco.MjModel
    layout: Layout
    engine: engines.Engine
    qpos0: np.ndarray

    @property
    def params(self) -> ControllerParams:
        return self.spec.params

    @property
    def control_dt(self) -> float:
        return self.spec.params.control_dt

    def rebuild(self, **changes) -> Simulation:
        """The simulation built as this one with the fields of ``SimulationSpec`` in ``changes``
        changed (for example ``rebuild(slope_deg=5.0)``)."""
        return build_simulation(dataclasses.replace(self.spec, **changes))


def make_simulation(engine: str | None = None, slope_deg: float = 0.0,
                    params: ControllerParams | None = None,
                    physics_dt: float | None = None, robot: str = "nominal",
                    platform: str = robots.DEFAULT_PLATFORM) -> Simulation:
    """The simulation of ``platform`` on ``engine`` (default: ``engines.default_engine()``),
    with the platform's default controller unless ``params`` are given and the model's time
    step unless ``physics_dt`` is.

    ``robot="hardware"`` simulates the perturbed robot of ``mjxcpg.physics.hardware`` (its model,
    latency and sensor noise), ``robot="harsh"`` its harsher variant; the layout, hence the
    controller, stays the nominal one's.
    """
    return build_simulation(SimulationSpec(
        engine=engine or engines.default_engine(), platform=platform, slope_deg=float(slope_deg),
        physics_dt=physics_dt, robot=robot, params=params or ControllerParams.of(robots.platform(platform))))


def build_simulation(spec: SimulationSpec) -> Simulation:
    """Load the platform's model, check the control period against the physics step, build
    the engine."""
    description = robots.platform(spec.platform)
    model = load_model(spec.slope_deg, timestep=spec.physics_dt, robot=description)
    spec = dataclasses.replace(spec, physics_dt=float(model.opt.timestep))  # the record says the step taken
    substeps = spec.params.control_dt / model.opt.timestep
    if substeps < 1 or abs(substeps - round(substeps)) > 1e-6:
        raise ValueError(f"control period {spec.params.control_dt} s is not a whole number of "
                         f"physics steps of {model.opt.timestep} s")
    layout = Layout.of(model, description)
    qpos0 = standing_qpos(model, layout, spec.params.x0, spec.params.z0, spec.params.slope_posture)
    if spec.robot in hardware.MISMATCHES:
        if spec.platform != HARDWARE_PLATFORM:
            raise ValueError(f"the {spec.robot} robot is a perturbed {HARDWARE_PLATFORM} (docs/hardware.md); "
                             f"{spec.platform} has none")
        mismatch = hardware.MISMATCHES[spec.robot]
        model = hardware.perturbed_model(model, mismatch)
        physics_engine = hardware.HardwareEngine(
            engines.make_engine(spec.engine, model, round(substeps), description.pelvis), mismatch, description)
    elif spec.robot == "nominal":
        physics_engine = engines.make_engine(spec.engine, model, round(substeps), description.pelvis)
    else:
        raise ValueError(f"unknown robot {spec.robot!r}; choose one of {', '.join(ROBOTS)}")
    return Simulation(spec=spec, model=model, layout=layout, engine=physics_engine, qpos0=qpos0)


def standing_qpos(model: mujoco.MjModel, layout: Layout, x0: float, leg_length: float,
                  posture: float = 0.0) -> np.ndarray:
    """A standing pose with both ankles at (x0, leg_length) below the hips, the soles flat on
    the floor 1 mm above it.

    On an inclined floor the whole robot is tilted with it, as a robot that holds its soles
    parallel to its pelvis stands when set down on an incline: level, its soles would meet
    the floor on an edge, one end in it and the other above it.  With ``posture`` p
    (``ControllerParams.slope_posture``) the pelvis is turned toward upright by p x slope
    and both ankles pitched back by as much (``controller.posture_ankle_pitch``), the soles
    still flat, the lowest sole corner 1 mm above the floor.
    """
    qpos = model.qpos0.copy()
    qpos[2] = layout.pelvis_height(leg_length) + 0.001
    slope = math.atan(layout.slope_tan)
    if slope != 0.0:
        # Rotated about the floor's origin as the floor is: uphill (+x) the robot leans back.
        qpos[0], qpos[2] = -qpos[2] * math.sin(slope), qpos[2] * math.cos(slope)
        tilt = slope * (1 - posture)
        qpos[3:7] = [math.cos(tilt / 2), 0.0, -math.sin(tilt / 2), 0.0]
    turned = posture != 0.0 and slope != 0.0
    angles = np.array(ik.leg_joint_angles(jnp.float32(x0), jnp.float32(leg_length), layout.geometry))
    if turned:
        angles[LEG_JOINTS.index("ankle_pitch")] -= posture * slope
    for ctrl_ids in (layout.left_leg_ctrl, layout.right_leg_ctrl):
        for k, actuator in enumerate(ctrl_ids):
            joint = model.actuator_trnid[actuator, 0]
            qpos[model.jnt_qposadr[joint]] = angles[k]
    for actuator, target in enumerate(layout.ctrl_home):
        joint = model.actuator_trnid[actuator, 0]
        if actuator not in layout.left_leg_ctrl + layout.right_leg_ctrl:
            qpos[model.jnt_qposadr[joint]] = target
    if turned:
        qpos[2] -= (_floor_clearance(model, qpos, slope) - 0.001) / math.cos(slope)
    return qpos


def _floor_clearance(model: mujoco.MjModel, qpos: np.ndarray, slope: float) -> float:
    """The smallest distance, normal to the floor plane through the origin, from the floor to
    the robot's colliding geoms (the soles' corner spheres)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    colliding = [g for g in np.flatnonzero(model.geom_contype != 0) if model.geom_bodyid[g] != 0]
    return min((data.geom_xpos[g][2] - data.geom_xpos[g][0] * math.tan(slope)) * math.cos(slope)
               - model.geom_size[g][0] for g in colliding)
