"""The robot steps and walks under the CPG and reflexes, on both engines."""

import dataclasses
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.control import walk
from mjxcpg.control.controller import hand_feedback

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
    gait = walk.summarise(run(mujoco_sim.engine.init(mujoco_sim.qpos0, 1), walk.initial_controller(1),
                              jnp.zeros(1)), params.control_dt, mujoco_sim.layout.weight)[0]
    assert not gait.fell and abs(gait.mean_vx) < 0.01


def test_hand_designed_start_is_the_hand_feedback_then_the_given_one(mujoco_sim):
    """Two robots, 1 s each: hand-designed for all of it (through ``hand_seconds``) equals the
    hand-designed feedback given outright, and a start of 0.5 s then a_5 = 0 parts from it
    only after 0.5 s."""
    def zero(obs, k):
        return 0.0 * k

    start = walk.walk_from_standing(mujoco_sim, zero, jnp.zeros(1), 1.0, hand_seconds=1.0)
    outright = walk.walk_from_standing(mujoco_sim, lambda obs, k: hand_feedback(mujoco_sim.params, obs) + 0.0 * k,
                                       jnp.zeros(1), 1.0)
    assert jnp.array_equal(start.a5, outright.a5) and jnp.array_equal(start.height, outright.height)
    half = walk.walk_from_standing(mujoco_sim, zero, jnp.zeros(1), 1.0, hand_seconds=0.5)
    n = round(0.5 / mujoco_sim.control_dt)
    assert jnp.array_equal(half.a5[:, :n], outright.a5[:, :n])
    assert jnp.all(half.a5[:, n:] == 0.0)


def test_the_start_window_measures_a_walk_by_hand():
    """Two robots, 0.01 s periods over 3 s: one walks +0.04 m/s and never falls, one walks
    backward at -0.02 m/s and falls at 1.0 s. Over 0.3-1.5 s the first's mean v_x is 0.04; the
    second's is read up to its fall (0.3-0.99 s), -0.02, and its fall is at 1.0 s."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    import start_window

    t = np.arange(300) * 0.01
    x = np.stack([0.04 * t, -0.02 * t])
    fallen = np.zeros((2, 300), bool)
    fallen[1, 100:] = True
    fell, when, early_vx = start_window.start_measures(fallen, x, 0.01, (0.3, 1.5))
    assert fell.tolist() == [False, True]
    assert np.isnan(when[0]) and when[1] == pytest.approx(1.0)
    assert early_vx == pytest.approx([0.04, -0.02], abs=1e-12)
