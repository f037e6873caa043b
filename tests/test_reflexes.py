"""The controller's reflexes beyond the paper's: the heading reflex (a turn per step, through
the swing leg's hip yaw), the slope reflex (the pelvis pitch integrated into the ankles), the
slope posture (the pelvis turned toward upright on an incline) and the hand-designed start's
fade-out after the hand-over."""

import dataclasses
import math

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjxcpg.control import walk
from mjxcpg.control.controller import (ControllerParams, after_hand_start, hand_feedback, heading_reflex,
                                       joint_targets, posture_ankle_pitch, slope_reflex)
from mjxcpg.control.sim import make_simulation
from mjxcpg.physics.model import Observation

HIP_YAW, ANKLE_PITCH = 0, 4  # in leg_joint_angles' order


def observation(**fields) -> Observation:
    zeros = {name: jnp.float32(0.0) for name in Observation._fields}
    return Observation(**(zeros | {"gyro": jnp.zeros(3)} | fields))


@pytest.fixture(scope="module")
def sim():
    return make_simulation("native")


def leg_angles(sim, ctrl):
    layout = sim.layout
    return np.asarray(ctrl)[list(layout.left_leg_ctrl)], np.asarray(ctrl)[list(layout.right_leg_ctrl)]


@pytest.mark.parametrize("stepping, left_share, right_share", [(0.5, 0.5, 0.0), (2.0, 1.0, 0.0),
                                                               (-0.3, 0.0, 0.3), (0.0, 0.0, 0.0)])
def test_a_turn_yaws_the_lifted_leg_by_its_lift(sim, stepping, left_share, right_share):
    """q1 - q2 > 0 lifts the left leg (eq 4); the turn goes to its hip yaw in proportion to
    the lift, up to 1, and leaves the stance leg and every other joint as with no turn."""
    q = jnp.array([max(stepping, 0.0), max(-stepping, 0.0), 0.0, 0.0, 0.3, 0.1])
    turned = leg_angles(sim, joint_targets(sim.params, sim.layout, q, turn=0.2))
    straight = leg_angles(sim, joint_targets(sim.params, sim.layout, q))
    for leg, share in zip((0, 1), (left_share, right_share)):
        assert turned[leg][HIP_YAW] == pytest.approx(0.2 * share, abs=1e-7)
        others = [k for k in range(6) if k != HIP_YAW]
        np.testing.assert_array_equal(turned[leg][others], straight[leg][others])


def test_heading_reflex_turns_against_the_heading_within_its_limit():
    params = ControllerParams(h_heading=0.6, max_turn=0.3)
    assert float(heading_reflex(params, observation(heading=jnp.float32(0.2)))) == pytest.approx(-0.12)
    assert float(heading_reflex(params, observation(heading=jnp.float32(-1.0)))) == pytest.approx(0.3)
    assert float(heading_reflex(ControllerParams(), observation(heading=jnp.float32(0.5)))) == 0.0


def test_heading_reflex_steers_to_the_commanded_heading():
    """By hand: commanded 0.5 rad, at 0.3 the error is -0.2 and the turn +0.12 (to the left);
    at the command, none; far past it, the limit."""
    params = ControllerParams(h_heading=0.6, max_turn=0.3, heading_command=0.5)
    assert float(heading_reflex(params, observation(heading=jnp.float32(0.3)))) == pytest.approx(0.12)
    assert float(heading_reflex(params, observation(heading=jnp.float32(0.5)))) == 0.0
    assert float(heading_reflex(params, observation(heading=jnp.float32(-0.5)))) == pytest.approx(0.3)


def test_slope_reflex_integrates_the_pitch_up_to_its_limit():
    """d(offset)/dt = pitch / T: a constant pitch of 0.05 rad with T = 2 s moves the offset
    0.025 rad per second, so 0.1 rad after 4 s, and it stops at the 0.2 rad limit."""
    params = ControllerParams(slope_reflex_s=2.0, max_ankle_pitch=0.2)
    offset, obs = jnp.float32(0.0), observation(pitch=jnp.float32(0.05))
    for _ in range(round(4.0 / params.control_dt)):
        offset = slope_reflex(params, offset, obs)
    assert float(offset) == pytest.approx(0.1, rel=1e-4)
    for _ in range(round(8.0 / params.control_dt)):
        offset = slope_reflex(params, offset, obs)
    assert float(offset) == pytest.approx(0.2)
    assert float(slope_reflex(ControllerParams(), jnp.float32(0.0), obs)) == 0.0  # off by default


def test_heading_reflex_walks_a_turned_robot_back_to_its_course(sim):
    """The hand-designed gait started 20 degrees off +x: with the heading reflex it heads
    back, without it it keeps its start heading.  The gait holds its own heading within
    about 3 degrees over 100 s without the reflex (docs/learning.md), so "back" is within
    5 degrees after 20 s and "kept" is still beyond 15."""
    start = math.radians(20.0)
    qpos0 = sim.qpos0.copy()
    qpos0[3:7] = [math.cos(start / 2), 0.0, 0.0, math.sin(start / 2)]
    final = {}
    for gain in (0.0, 0.6):
        run_sim = dataclasses.replace(sim, spec=dataclasses.replace(
            sim.spec, params=dataclasses.replace(sim.params, h_heading=gain)), qpos0=qpos0)
        trace = walk.walk_from_standing(run_sim, lambda obs, k: hand_feedback(run_sim.params, obs),
                                        jnp.zeros(1), 20.0, record_qpos=True)
        assert not bool(trace.fallen[0, -1])
        w, x, y, z = np.asarray(trace.qpos[0, -1, 3:7])
        final[gain] = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    assert abs(final[0.6]) < 5.0 and final[0.0] > 15.0, final


@pytest.mark.parametrize("posture", [0.0, 0.5, 1.0])
def test_slope_posture_turns_the_pelvis_and_keeps_the_soles_flat(posture):
    """On a 6-degree incline the standing pose's pelvis is pitched by -(1 - posture) x 6
    degrees (tilted with the floor at 0, level at 1), each sole's corner spheres all lie 1 mm
    above the floor (the sole flat on it), and the controller holds the ankles pitched by
    -posture x 6 degrees."""
    slope = math.radians(6.0)
    params = ControllerParams(slope_posture=posture)
    sim = make_simulation("mujoco", slope_deg=6.0, params=params)
    data = mujoco.MjData(sim.model)
    data.qpos[:] = sim.qpos0
    mujoco.mj_kinematics(sim.model, data)
    w, _, y, _ = sim.qpos0[3:7]
    assert 2 * math.atan2(-y, w) == pytest.approx(slope * (1 - posture), abs=1e-9)  # pitched back uphill
    spheres = [g for g in np.flatnonzero(sim.model.geom_contype != 0) if sim.model.geom_bodyid[g] != 0]
    heights = [(data.geom_xpos[g][2] - data.geom_xpos[g][0] * math.tan(slope)) * math.cos(slope)
               - sim.model.geom_size[g][0] for g in spheres]
    np.testing.assert_allclose(heights, 0.001, atol=2e-5)  # float32 joint angles from the IK
    assert posture_ankle_pitch(params, sim.layout) == pytest.approx(-posture * slope)


@pytest.mark.parametrize("steps, policy_a5, expected", [
    (12, 0.3, 2.0 * 0.4),                             # before the hand-over: K d(theta_roll)/dt alone
    (62, 0.3, 0.3 + (1 - 0.496 / 2) * 2.0 * 0.4),     # t = 62 x 8 ms: K d(theta_roll)/dt weighed 1 - t / 2 s
    (238, 0.3, 0.3 + (1 - 1.904 / 2) * 2.0 * 0.4),
    (250, 0.3, 0.3), (625, -0.2, -0.2)])              # from 2 s on, the policy's a_5 alone
def test_the_hand_designed_start_fades_out_after_the_hand_over(steps, policy_a5, expected):
    """K = 2 s, roll rate 0.4 rad/s, hand-over after 25 periods of 8 ms, fade over 2 s."""
    params = ControllerParams(hand_gain=2.0, hand_fade_seconds=2.0, control_dt=0.008)
    obs = observation(gyro=jnp.array([0.4, 0.1, 0.0]))
    a5 = after_hand_start(params, obs, jnp.float32(policy_a5), jnp.int32(steps), jnp.int32(25))
    assert float(a5) == pytest.approx(expected, abs=1e-6)  # float32 of numbers of order 1
    off = dataclasses.replace(params, hand_fade_seconds=0.0)
    assert float(after_hand_start(off, obs, jnp.float32(policy_a5), jnp.int32(steps), 0)) == pytest.approx(policy_a5)


@pytest.mark.parametrize("steps, expected", [(12, (2.0 * 0.4, 0.0)),            # hand start: no stepping feedback
                                              (62, (0.3 + (1 - 0.496 / 2) * 2.0 * 0.4, -0.15)),
                                              (250, (0.3, -0.15))])
def test_a_two_output_policy_acts_after_the_hand_start_with_its_stepping_feedback(steps, expected):
    """The pair (a_5, stepping) from a two-output policy: the hand-designed start gives a_5 and
    no stepping feedback, the fade acts on a_5 alone."""
    params = ControllerParams(hand_gain=2.0, hand_fade_seconds=2.0, control_dt=0.008)
    obs = observation(gyro=jnp.array([0.4, 0.1, 0.0]))
    action = after_hand_start(params, obs, jnp.array([0.3, -0.15]), jnp.int32(steps), jnp.int32(25))
    np.testing.assert_allclose(action, expected, atol=1e-6)


def test_the_stepping_feedback_enters_the_cpg_as_eq_9s_a1_does(sim):
    """control_step with (a_5, s) drives the CPG with eq (8)'s vector at a_1 + s, built here by
    hand from eq (9): a_1 = h_ER (f_r - f_l) / mg + h_VSR vsr_sign theta_roll."""
    from mjxcpg.control import cpg
    from mjxcpg.control.controller import control_step, init_state
    params, layout = sim.params, sim.layout
    obs = observation(force_right=jnp.float32(40.0), force_left=jnp.float32(20.0), roll=jnp.float32(0.05),
                      gyro=jnp.array([0.3, -0.1, 0.0]))
    a1 = params.h_er * 20.0 / layout.weight + params.h_vsr * params.vsr_sign * 0.05
    a5, s = 0.7, -0.25
    state = init_state()
    stepped, ctrl = control_step(params, layout, state, obs, jnp.array([a5, s]))
    vector = jnp.array([a1 + s, -(a1 + s), a1 + s, -(a1 + s), a5, -a5], jnp.float32)
    expected = cpg.integrate(params.cpg, state.cpg, vector, params.control_dt, params.cpg_substeps)
    np.testing.assert_allclose(stepped.cpg.z, expected.z, rtol=1e-5, atol=1e-7)
    plain, _ = control_step(params, layout, state, obs, jnp.float32(a5))
    assert not np.allclose(plain.cpg.z, stepped.cpg.z)
