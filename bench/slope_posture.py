"""Does the start posture on an incline set how steep a slope the gait walks?

The robot normally starts tilted with the floor, its body perpendicular to it and its soles
flat (``sim.standing_qpos``), and its inverse kinematics keeps the soles parallel to the
pelvis, so it walks leaning back uphill and forward downhill.  Here it starts with its
pelvis turned toward upright by ``--fraction`` of the slope, both ankles pitched the other
way by as much so that the soles stay flat on the floor, and the controller holds that ankle
offset for the whole walk (``ControllerState.ankle_pitch``, the slope reflex's offset, with
the reflex itself off).  Fraction 0 is the usual start; 1 stands the pelvis level.  The
hand-designed feedback walks 20 s on each slope from standing; one line per slope.

    NPROC=1 .venv/bin/python bench/slope_posture.py --fraction 0.5 --slopes 4 5 6 7 8 9 -4 -5 -6 \\
        [--set h_heading=0.6 ...]
"""

import argparse
import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control import walk
from mjxcpg.control.controller import init_state, roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.robots.description import LEG_JOINTS


def turned_posture(sim, slope_deg: float, fraction: float) -> np.ndarray:
    """``sim``'s standing pose with the pelvis turned toward upright by ``fraction`` of the
    slope, the ankles pitched back by as much, and the lowest sole corner 1 mm above the floor."""
    model, layout = sim.model, sim.layout
    qpos = np.array(sim.qpos0)
    slope = math.radians(slope_deg)
    tilt = slope * (1 - fraction)  # what is left of the pelvis' tilt with the floor
    qpos[3:7] = [math.cos(tilt / 2), 0.0, -math.sin(tilt / 2), 0.0]
    ankle = LEG_JOINTS.index("ankle_pitch")
    for leg in (layout.left_leg_ctrl, layout.right_leg_ctrl):
        qpos[model.jnt_qposadr[model.actuator_trnid[leg[ankle], 0]]] -= slope * fraction
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    feet = [g for g in np.flatnonzero(model.geom_contype != 0) if model.geom_bodyid[g] != 0]
    # distance of each sphere's bottom from the floor plane z = x tan(slope), along its normal
    clearance = min((data.geom_xpos[g][2] - data.geom_xpos[g][0] * math.tan(slope)) * math.cos(slope)
                    - model.geom_size[g][0] for g in feet)
    qpos[2] -= (clearance - 0.001) / math.cos(slope)
    return qpos


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fraction", type=float, default=0.5, help="of the slope the pelvis is turned toward upright")
    parser.add_argument("--slopes", type=float, nargs="+", default=[4, 5, 6, 7, 8, -4, -5, -6])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="controller constants instead of the defaults (ControllerParams fields)")
    args = parser.parse_args()
    xla.one_cpu_thread()
    changes = {name: float(value) for name, value in (item.split("=", 1) for item in args.set)}
    for slope in args.slopes:
        sim = make_simulation("mujoco", slope_deg=slope)
        sim = sim.rebuild(params=dataclasses.replace(sim.params, **changes))
        run = walk.make_walk(sim.engine, sim.layout, sim.params, round(args.seconds / sim.control_dt),
                             roll_rate_feedback)
        controller = init_state()._replace(ankle_pitch=jnp.float32(-math.radians(slope) * args.fraction))
        controller = jax.tree.map(lambda x: x[None], controller)
        trace = run(sim.engine.init(turned_posture(sim, slope, args.fraction), 1), controller,
                    jnp.array([sim.params.hand_gain]))
        gait = walk.summarise(trace, sim.control_dt, sim.layout.weight)[0]
        state = f"fell at {gait.seconds:.1f} s" if gait.fell else f"walks {args.seconds:g} s at {gait.mean_vx:.3f} m/s"
        print(f"fraction {args.fraction:g}, slope {slope:+g} deg: {state}", flush=True)


if __name__ == "__main__":
    main()
