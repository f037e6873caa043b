"""The robot steps and walks under the CPG and reflexes, on both engines."""

import dataclasses

import jax.numpy as jnp
import pytest

from mjxcpg.control import walk

HAND, STEPPING = 0, 1


@pytest.mark.parametrize("engine", ["walks_mujoco", "walks_mjx"])
def test_stepping_with_zero_feedback_does_not_fall(engine, request):
    gait = request.getfixturevalue(engine)[STEPPING]
    assert not gait.fell and gait.seconds == pytest.approx(20.0)
    assert gait.gait_period is not None


@pytest.mark.parametrize("engine", ["walks_mujoco", "walks_mjx"])
def test_hand_designed_feedback_walks_forward(engine, request):
    gait = request.getfixturevalue(engine)[HAND]
    assert not gait.fell
    assert 0.04 <= gait.mean_vx <= 0.12
    assert 0.26 <= gait.mean_pelvis_height <= 0.30


def test_stepping_in_place(mujoco_sim):
    params = dataclasses.replace(mujoco_sim.params, amp_x=0.0)
    run = walk.make_walk(mujoco_sim.engine, mujoco_sim.layout, params, 2500, lambda obs, k: 0.0 * k)
    gait = walk.summarise(run(mujoco_sim.engine.init(mujoco_sim.qpos0, 1), walk.initial_cpg(1),
                              jnp.zeros(1)), params.control_dt)[0]
    assert not gait.fell and abs(gait.mean_vx) < 0.01
