"""The robot description: QRIO's names against its MJCF, its gait constants as published, and
the scaling rule that carries them to a robot of another size."""

import dataclasses
import math

import mujoco
import pytest

from mjxcpg.control.controller import ControllerParams
from mjxcpg.control.cpg import CPGParams
from mjxcpg.learning.learner import TrialParams
from mjxcpg.physics.model import Layout, load_model
from mjxcpg.robots.description import GaitConstants, scaled_gait
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


def test_qrio_names_and_leg_length_match_its_mjcf():
    model = load_model()
    kinds = {"joints": mujoco.mjtObj.mjOBJ_JOINT, "hip": mujoco.mjtObj.mjOBJ_BODY,
             "shin": mujoco.mjtObj.mjOBJ_BODY, "ankle": mujoco.mjtObj.mjOBJ_BODY,
             "sole": mujoco.mjtObj.mjOBJ_GEOM, "force": mujoco.mjtObj.mjOBJ_SENSOR}
    for leg in QRIO.legs:
        for field, kind in kinds.items():
            for name in (getattr(leg, field) if field == "joints" else [getattr(leg, field)]):
                assert mujoco.mj_name2id(model, kind, name) >= 0, name
        for joint in leg.joints:
            assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, joint) >= 0, joint
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, QRIO.floor) >= 0
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, QRIO.pelvis) >= 0
    for sensor in (QRIO.gyro, QRIO.orientation):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, sensor) >= 0
    layout = Layout.of(model)
    assert layout.geometry.thigh + layout.geometry.shin == pytest.approx(QRIO.leg_length)
    assert -model.opt.gravity[2] == pytest.approx(QRIO.gravity)
    for name, target in QRIO.home_pose:
        assert layout.ctrl_home[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)] == target
