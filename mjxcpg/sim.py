"""A robot, its controller constants and an engine, assembled once."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from mjxcpg import engines
from mjxcpg.controller import ControllerParams
from mjxcpg.robot import Layout, load_model, standing_qpos


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
                    physics_dt: float | None = None) -> Simulation:
    """Load the model, check the control period against the physics step, build the engine."""
    params = params or ControllerParams()
    model = load_model(slope_deg, timestep=physics_dt)
    substeps = params.control_dt / model.opt.timestep
    if substeps < 1 or abs(substeps - round(substeps)) > 1e-6:
        raise ValueError(f"control period {params.control_dt} s is not a whole number of "
                         f"physics steps of {model.opt.timestep} s")
    layout = Layout.of(model)
    return Simulation(
        model=model, layout=layout, params=params,
        engine=engines.make_engine(engine or engines.default_engine(), model, round(substeps)),
        qpos0=standing_qpos(model, layout, params.x0, params.z0),
    )
