"""Which actuators do the positive work of a gait, and does it add up to the engines' figure?

The hand-designed feedback (or a_5 = 0 with ``--gain 0``) walks ``--seconds`` from standing on
MuJoCo C; every physics step, each actuator's max(0, force x velocity) is read from
``mjData.actuator_force`` and ``actuator_velocity`` (not from the sensors the engines use) and
summed after the 2 s of settling.  Prints the cost of transport both ways and, per actuator,
largest first, its work and the share of physics steps it spent at its force limit (before
any fall).

    NPROC=1 .venv/bin/python bench/actuator_work.py [--gain K] [--seconds 20] [--slope DEG]
        [--set h_heading=0.6 ...]
"""

import argparse
import dataclasses

import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control import walk
from mjxcpg.control.controller import roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.physics import engines


class PerActuatorMujoco(engines.MujocoEngine):
    """The scalar engine, keeping each control period's positive work per actuator."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.per_period: list[np.ndarray] = []
        self.saturated: list[np.ndarray] = []   # per control period, physics steps at the force limit
        self._limit = 0.999 * np.abs(self.model.actuator_forcerange).max(axis=1)

    def _simulate(self, physics, ctrl, pelvis_force=None):
        model, data = self.model, self._data
        assert len(physics) == 1 and pelvis_force is None, "one robot, no push"
        mujoco.mj_setState(model, data, physics[0], engines._FULLPHYSICS)
        data.qacc_warmstart[:] = 0
        data.ctrl[:] = ctrl[0]
        work, saturated = np.zeros(model.nu), np.zeros(model.nu)
        sensors = np.empty((self.substeps, model.nsensordata))
        for t in range(self.substeps):
            mujoco.mj_step(model, data)
            work += np.maximum(data.actuator_force * data.actuator_velocity, 0.0) * model.opt.timestep
            saturated += np.abs(data.actuator_force) >= self._limit
            sensors[t] = data.sensordata
        self.per_period.append(work)
        self.saturated.append(saturated)
        stepped = np.empty_like(physics)
        mujoco.mj_getState(model, data, stepped[0], engines._FULLPHYSICS)
        # What the engines report: the work from the power sensors, as MujocoEngine sums it.
        return stepped, data.sensordata[None].copy(), np.array([self._period_work(sensors)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gain", type=float, default=None, help="a_5 = K d theta_roll/dt (default: the hand-designed K)")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--slope", type=float, default=0.0, help="floor slope (degrees, uphill > 0)")
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="controller constants instead of the defaults (ControllerParams fields)")
    args = parser.parse_args()
    xla.one_cpu_thread()
    sim = make_simulation("mujoco", slope_deg=args.slope)
    changes = {name: float(value) for name, value in (item.split("=", 1) for item in args.set)}
    sim = sim.rebuild(params=dataclasses.replace(sim.params, **changes))
    engine = PerActuatorMujoco(sim.model, sim.engine.substeps)
    sim = dataclasses.replace(sim, engine=engine)
    gain = sim.params.hand_gain if args.gain is None else args.gain
    trace = walk.walk_from_standing(sim, roll_rate_feedback, jnp.array([gain]), args.seconds)
    gait = walk.summarise(trace, sim.control_dt, sim.layout.weight)[0]
    start = round(walk.SETTLE_SECONDS / sim.control_dt)
    # Period t moves the robot from trace position t to t + 1 (summarise's window); a walk
    # that falls is counted up to its fall.
    end = round(gait.seconds / sim.control_dt)
    if end - 1 <= start:
        print(f"K = {gain:g}, slope {args.slope:+g} deg: fell at {gait.seconds:.1f} s, before the "
              f"{walk.SETTLE_SECONDS:g} s of settling ended")
        return
    per_actuator = np.sum(engine.per_period[start:end - 1], axis=0)
    at_limit = np.sum(engine.saturated[start:end - 1], axis=0) / (max(end - 1 - start, 1) * sim.engine.substeps)
    x = np.asarray(trace.forward_position[0])
    distance = float(x[end - 1] - x[start])
    print(f"K = {gain:g}, slope {args.slope:+g} deg: {f'fell at {gait.seconds:.1f} s, ' if gait.fell else ''}"
          f"mean v_x {gait.mean_vx:.4f} m/s, m g {sim.layout.weight:.1f} N")
    cot = f"{per_actuator.sum() / (sim.layout.weight * distance):.4f}" if distance > 0 else "-"
    print(f"CoT: from the power sensors, as the engines {gait.cost_of_transport or float('nan'):.4f}; from "
          f"mjData {cot}; positive work {per_actuator.sum():.1f} J over {(end - 1 - start) * sim.control_dt:.1f} s")
    print(f"  {'actuator':18s} {'work':>9s} {'share':>7s} {'at limit':>9s}")
    for i in np.argsort(-per_actuator):
        print(f"  {sim.model.actuator(i).name:18s} {per_actuator[i]:7.2f} J {per_actuator[i] / per_actuator.sum():7.1%} "
              f"{at_limit[i]:9.1%}")


if __name__ == "__main__":
    main()
