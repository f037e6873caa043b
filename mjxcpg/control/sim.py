"""A robot, its controller constants and an engine, assembled once."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control import ik
from mjxcpg.control.controller import ControllerParams
from mjxcpg.physics import engines, hardware
from mjxcpg.physics.model import Layout, load_model
from mjxcpg.robots.description import RobotDescription
from mjxcpg.robots.qrio import QRIO

ROBOTS = ("nominal", "hardware")  # the simulated robot; see mjxcpg.physics.hardware


@dataclasses.dataclass
class Simulation:
    model: mujoco.MjModel
    layout: Layout
    params: ControllerParams
    engine: engines.Engine
    qpos0: np.ndarray

    @property
    def control_dt(self) -> float:
        return self.params.control_dt


def make_simulation(engine: str | None = None, slope_deg: float = 0.0,
                    params: ControllerParams | None = None,
                    physics_dt: float | None = None, robot: str = "nominal",
                    description: RobotDescription = QRIO) -> Simulation:
    """Load the model of ``description``, check the control period against the physics step,
    build the engine.

    ``robot="hardware"`` simulates the perturbed robot of ``mjxcpg.physics.hardware`` (its model,
    latency and sensor noise); the layout, hence the controller, stays the nominal one's.
    """
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot {robot!r}; choose one of {', '.join(ROBOTS)}")
    params = params or ControllerParams()
    model = load_model(slope_deg, timestep=physics_dt, robot=description)
    substeps = params.control_dt / model.opt.timestep
    if substeps < 1 or abs(substeps - round(substeps)) > 1e-6:
        raise ValueError(f"control period {params.control_dt} s is not a whole number of "
                         f"physics steps of {model.opt.timestep} s")
    layout = Layout.of(model, description)
    qpos0 = standing_qpos(model, layout, params.x0, params.z0)
    name = engine or engines.default_engine()
    if robot == "hardware":
        model = hardware.perturbed_model(model)
        physics_engine = hardware.HardwareEngine(
            engines.make_engine(name, model, round(substeps), description.pelvis), robot=description)
    else:
        physics_engine = engines.make_engine(name, model, round(substeps), description.pelvis)
    return Simulation(model=model, layout=layout, params=params, engine=physics_engine, qpos0=qpos0)


def standing_qpos(model: mujoco.MjModel, layout: Layout, x0: float, leg_length: float) -> np.ndarray:
    """A standing pose on flat ground with both ankles at (x0, leg_length) below the hips."""
    qpos = model.qpos0.copy()
    qpos[2] = layout.pelvis_height(leg_length) + 0.001
    angles = np.asarray(ik.leg_joint_angles(jnp.float32(x0), jnp.float32(leg_length), layout.geometry))
    for ctrl_ids in (layout.left_leg_ctrl, layout.right_leg_ctrl):
        for k, actuator in enumerate(ctrl_ids):
            joint = model.actuator_trnid[actuator, 0]
            qpos[model.jnt_qposadr[joint]] = angles[k]
    for actuator, target in enumerate(layout.ctrl_home):
        joint = model.actuator_trnid[actuator, 0]
        if actuator not in layout.left_leg_ctrl + layout.right_leg_ctrl:
            qpos[model.jnt_qposadr[joint]] = target
    return qpos
