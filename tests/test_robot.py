"""The robot descriptions: names against each MJCF, QRIO's gait constants as published, the
scaling rule that carries them to a robot of another size (checked against the physics of an
exactly scaled QRIO), and the second platform's hand-designed gait."""

import dataclasses
import importlib.resources
import math

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjxcpg import robots
from mjxcpg.control import walk
from mjxcpg.control.controller import ControllerParams, roll_rate_feedback
from mjxcpg.control.cpg import CPGParams
from mjxcpg.control.sim import make_simulation
from mjxcpg.learning.learner import TrialParams
from mjxcpg.physics.model import Layout, load_model
from mjxcpg.robots import PLATFORMS
from mjxcpg.robots.child import CHILD
from mjxcpg.robots.description import GaitConstants, RobotDescription, scaled_gait, scaled_mjcf
from mjxcpg.robots.qrio import QRIO

# The constants as the controller and the reward used them before they had a robot to come from.
PUBLISHED = {"tau": 0.105, "tau_adapt": 0.132, "amp_x": 0.015, "amp_z": 0.005, "z0": 0.215, "h_ref": 0.272}


def test_qrio_gait_is_the_published_constants_bit_for_bit():
    gait = QRIO.gait
    for name, value in PUBLISHED.items():
        assert getattr(gait, name) == value, name
    controller, cpg = ControllerParams(), CPGParams()
    assert (cpg.tau, cpg.tau_adapt) == (0.105, 0.132)
    assert (controller.amp_x, controller.amp_z, controller.z0) == (0.015, 0.005, 0.215)
    assert TrialParams().h_ref == 0.272
    assert ControllerParams.of(QRIO) == controller
    # This project's K and fall height, as they were before they had a robot to come from.
    assert gait.hand_gain == controller.hand_gain == 1.0 and gait.fall_height == 0.20


def test_scaling_rule_lengths_with_the_leg_times_with_sqrt_of_length_over_g():
    reference = QRIO.gait
    big = scaled_gait(4 * QRIO.leg_length)          # 4 x the leg: lengths x 4, times x 2
    for name in ("amp_x", "amp_z", "z0", "h_ref"):
        assert getattr(big, name) == pytest.approx(4 * getattr(reference, name))
    for name in ("tau", "tau_adapt"):
        assert getattr(big, name) == pytest.approx(2 * getattr(reference, name))
    moon = scaled_gait(QRIO.leg_length, gravity=9.81 / 4)  # a quarter of g: times x 2, lengths kept
    assert moon.tau == pytest.approx(2 * reference.tau) and moon.z0 == pytest.approx(reference.z0)
    # Froude similarity: tau / sqrt(L / g) is the same for every robot
    child = scaled_gait(0.5)
    assert child.tau / math.sqrt(0.5 / 9.81) == pytest.approx(reference.tau / math.sqrt(QRIO.leg_length / 9.81))
    assert isinstance(child, GaitConstants)


def test_controller_of_another_robot_takes_its_gait():
    tall = dataclasses.replace(QRIO, leg_length=2 * QRIO.leg_length)
    params = ControllerParams.of(tall)
    assert params.z0 == pytest.approx(2 * 0.215) and params.cpg.tau == pytest.approx(math.sqrt(2) * 0.105)
    assert params.h_er == ControllerParams().h_er  # reflex gains are dimensionless: kept
    assert params.hand_gain == pytest.approx(math.sqrt(2))  # K is a time: a_5 per roll rate


@pytest.mark.parametrize("robot", PLATFORMS.values(), ids=PLATFORMS)
def test_names_and_leg_length_match_its_mjcf(robot):
    model = load_model(robot=robot)
    kinds = {"joints": mujoco.mjtObj.mjOBJ_JOINT, "hip": mujoco.mjtObj.mjOBJ_BODY,
             "shin": mujoco.mjtObj.mjOBJ_BODY, "ankle": mujoco.mjtObj.mjOBJ_BODY,
             "sole": mujoco.mjtObj.mjOBJ_GEOM, "force": mujoco.mjtObj.mjOBJ_SENSOR}
    for leg in robot.legs:
        for field, kind in kinds.items():
            for name in (getattr(leg, field) if field == "joints" else [getattr(leg, field)]):
                assert mujoco.mj_name2id(model, kind, name) >= 0, name
        for joint in leg.joints:
            assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, joint) >= 0, joint
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, robot.floor) >= 0
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, robot.pelvis) >= 0
    for sensor in (robot.gyro, robot.orientation):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, sensor) >= 0
    layout = Layout.of(model, robot)
    assert layout.geometry.thigh + layout.geometry.shin == pytest.approx(robot.leg_length)
    assert -model.opt.gravity[2] == pytest.approx(robot.gravity)
    for name, target in robot.home_pose:
        assert layout.ctrl_home[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)] == target


def test_unknown_platform_is_a_one_line_error():
    with pytest.raises(ValueError, match="unknown platform 'atlas'; choose one of qrio, child"):
        robots.platform("atlas")


def standing_top_and_mass(robot: RobotDescription) -> tuple[float, float]:
    sim = make_simulation("mujoco", platform=robot.name)
    data = mujoco.MjData(sim.model)
    data.qpos[:] = sim.qpos0
    mujoco.mj_forward(sim.model, data)
    tops = data.geom_xpos[:, 2] + np.where(sim.model.geom_type == mujoco.mjtGeom.mjGEOM_SPHERE,
                                           sim.model.geom_size[:, 0], 0.0)
    return float(tops[1:].max()), float(sim.model.body_subtreemass[1])  # geom 0 is the floor


def test_child_is_another_size_and_proportions():
    """A child-sized humanoid (1.0-1.3 m standing) whose proportions are not QRIO's scaled."""
    child_height, child_mass = standing_top_and_mass(CHILD)
    qrio_height, qrio_mass = standing_top_and_mass(QRIO)
    assert 1.0 <= child_height <= 1.3 and 0.5 <= qrio_height <= 0.65
    child, qrio = Layout.of(load_model(robot=CHILD), CHILD), Layout.of(load_model(), QRIO)
    assert child.geometry.thigh != child.geometry.shin and qrio.geometry.thigh == qrio.geometry.shin
    scale = CHILD.leg_length / QRIO.leg_length
    assert not math.isclose(child_height / qrio_height, scale, rel_tol=0.03)
    assert not math.isclose(child_mass / qrio_mass, scale ** 3, rel_tol=0.1)


def test_dynamic_similarity_an_exactly_scaled_qrio_walks_sqrt2_slower_in_time(tmp_path, monkeypatch):
    """QRIO scaled by 2 in every length and 8 in every mass, with the gait constants
    ``scaled_gait`` gives it, against QRIO: equal Froude number predicts every time x sqrt(2)
    (the gait cycle) and every speed x sqrt(2) (lengths x 2 over times x sqrt(2)).

    What the scaling leaves out bounds the agreement: the physics step (4 ms), the control
    period (8 ms) and the contacts' solver time constant (20 ms) stay QRIO's, where similarity
    would stretch them by sqrt(2); they are 0.4-2% of the 1.3 s cycle, so 5% is allowed."""
    path = tmp_path / "qrio_x2.xml"
    with importlib.resources.as_file(QRIO.mjcf_resource()) as source:
        path.write_text(scaled_mjcf(source, 2.0, 8.0))
    big = dataclasses.replace(QRIO, name="qrio_x2", package=None, mjcf=str(path), leg_length=0.48)
    monkeypatch.setitem(PLATFORMS, big.name, big)
    gaits = {}
    for robot in (QRIO, big):
        sim = make_simulation("native", platform=robot.name)
        trace = walk.walk_from_standing(sim, roll_rate_feedback, jnp.array([sim.params.hand_gain]), 20.0)
        gaits[robot.name] = walk.summarise(trace, sim.control_dt, sim.layout.weight)[0]
    small, large = gaits["qrio"], gaits["qrio_x2"]
    assert not small.fell and not large.fell
    assert large.gait_period / small.gait_period == pytest.approx(math.sqrt(2), rel=0.05)
    assert large.mean_vx / small.mean_vx == pytest.approx(math.sqrt(2), rel=0.05)


def child_hand_gait(engine: str) -> walk.GaitSummary:
    sim = make_simulation(engine, platform="child")
    trace = walk.walk_from_standing(sim, roll_rate_feedback, jnp.array([sim.params.hand_gain]), 20.0)
    return walk.summarise(trace, sim.control_dt, sim.layout.weight)[0]


def test_child_walks_the_hand_designed_gait_20_s_on_mujoco_c():
    gait = child_hand_gait("native")
    assert not gait.fell and gait.seconds == 20.0 and gait.mean_vx > 0.05


@pytest.mark.slow
def test_child_hand_gait_on_mjx_within_3_percent_of_mujoco_c():
    """The engines' cross-check on the second robot, at the tolerance QRIO's hand-designed gait meets."""
    c, mjx = child_hand_gait("native"), child_hand_gait("mjx")
    assert not mjx.fell and mjx.seconds == 20.0
    assert mjx.mean_vx == pytest.approx(c.mean_vx, rel=0.03)


def test_a_simulation_records_how_it_was_built_and_rebuilds_with_one_field_changed():
    sim = make_simulation("mujoco", platform="child")
    assert (sim.spec.engine, sim.spec.platform, sim.spec.slope_deg, sim.spec.robot) == ("mujoco", "child", 0.0, "nominal")
    assert sim.spec.physics_dt == 0.004  # child.xml's <option timestep>
    assert sim.params == ControllerParams.of(CHILD)
    tilted = sim.rebuild(slope_deg=5.0)
    assert tilted.spec == dataclasses.replace(sim.spec, slope_deg=5.0) and tilted.params is sim.params
    assert tilted.layout.slope_tan == pytest.approx(math.tan(math.radians(5.0)), rel=1e-6)
    assert tilted.engine.name == "mujoco" and sim.rebuild(engine="native").engine.name == "native"


def test_hardware_stand_in_exists_for_qrio_only():
    with pytest.raises(ValueError, match="^the hardware robot is a perturbed qrio .*; child has none$"):
        make_simulation("mujoco", platform="child", robot="hardware")
