"""Which of the child-sized humanoid's proportions its hand-designed gait tolerates.

The child (``mjxcpg/robots/child``) against variants that change one proportion each, and
against QRIO scaled exactly (every length x2, every mass x8: dynamically similar,
``description.scaled_mjcf``).  Each walks 20 s from standing on the native engine with the
roll-rate feedback a_5 = gain x K d theta_roll/dt, K the child's hand-designed gain (QRIO's
1 s carried over by ``scaled_gait``: sqrt(2) s); a cell is the mean speed (m/s), or the time
of the fall.

    NPROC=1 .venv/bin/python bench/platform_proportions.py
"""

import dataclasses
import importlib.resources
import tempfile
from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import mujoco

from mjxcpg import robots
from mjxcpg.control import walk
from mjxcpg.control.controller import roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.robots.child import CHILD
from mjxcpg.robots.description import scaled_mjcf
from mjxcpg.robots.qrio import QRIO

GAINS = (0.0, 0.5, 0.7071, 1.0, 1.4142)   # times K


def feet_wide(width: float) -> Callable[[mujoco.MjSpec], None]:
    def change(spec: mujoco.MjSpec) -> None:
        for geom in spec.geoms:
            if "_sole_toe_" in geom.name or "_sole_heel_" in geom.name:
                geom.pos = [geom.pos[0], width / 2 if geom.name.endswith("left") else -width / 2, geom.pos[2]]
            elif geom.name.endswith("_sole"):
                geom.size = [geom.size[0], width / 2, geom.size[2]]
        for site in spec.sites:
            if site.name.endswith("_sole"):
                site.size = [site.size[0], width / 2 + 0.01, site.size[2]]
    return change


def hips_apart(width: float) -> Callable[[mujoco.MjSpec], None]:
    def change(spec: mujoco.MjSpec) -> None:
        for side, sign in (("l", 1), ("r", -1)):
            hip = spec.body(f"{side}_hip")
            hip.pos = [hip.pos[0], sign * width / 2, hip.pos[2]]
    return change


def equal_thigh_and_shin(spec: mujoco.MjSpec) -> None:
    half = CHILD.leg_length / 2
    for side in "lr":
        spec.body(f"{side}_shin").pos = [0, 0, -half]
        spec.body(f"{side}_ankle").pos = [0, 0, -half]
        for name in ("thigh", "shin"):
            for geom in spec.body(f"{side}_{name}").geoms:
                geom.fromto = [0, 0, 0, 0, 0, -half]


VARIANTS: dict[str, Callable[[mujoco.MjSpec], None] | None] = {
    "child as shipped": None,
    "feet 0.14 m wide (0.16)": feet_wide(0.14),
    "feet 0.12 m wide": feet_wide(0.12),
    "hips 0.18 m apart (0.20)": hips_apart(0.18),
    "thigh = shin = 0.24 m (0.26, 0.22)": equal_thigh_and_shin,
}


def walk_platform(robot) -> list[walk.GaitSummary]:
    robots.PLATFORMS[robot.name] = robot
    sim = make_simulation("native", platform=robot.name)
    gains = jnp.array(GAINS) * sim.params.hand_gain
    return walk.summarise(walk.walk_from_standing(sim, roll_rate_feedback, gains, 20.0), sim.control_dt,
                          sim.layout.weight)


def main() -> None:
    rows = {}
    with tempfile.TemporaryDirectory() as folder, importlib.resources.as_file(CHILD.mjcf_resource()) as child_xml, \
            importlib.resources.as_file(QRIO.mjcf_resource()) as qrio_xml:
        for k, (name, change) in enumerate(VARIANTS.items()):
            path = Path(folder) / f"variant{k}.xml"
            spec = mujoco.MjSpec.from_file(str(child_xml))
            if change is not None:
                change(spec)
            path.write_text(spec.to_xml())
            rows[name] = walk_platform(dataclasses.replace(CHILD, name=f"variant{k}", package=None, mjcf=str(path)))
        path = Path(folder) / "qrio_x2.xml"
        path.write_text(scaled_mjcf(qrio_xml, 2.0, 8.0))
        rows["QRIO x2 in length, x8 in mass"] = walk_platform(dataclasses.replace(
            QRIO, name="qrio_x2", package=None, mjcf=str(path), leg_length=2 * QRIO.leg_length))
    print("| model | " + " | ".join(f"{g:.2f} K" for g in GAINS) + " |")
    print("|---|" + "---|" * len(GAINS))
    for name, gaits in rows.items():
        cells = [f"fell at {g.seconds:.1f} s" if g.fell else f"{g.mean_vx:.3f}" for g in gaits]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
