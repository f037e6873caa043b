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


def test_the_start_phase_measures_oscillators_and_gain_by_hand():
    """Over 4 s of 8 ms periods, a whole number of 0.8 s cycles: the stepping oscillator
    q1 - q2 = sin(w t) and the propulsive one q5 - q6 = sin(w t + 60 deg) (each pair as
    max(0, +-z) of one z), so the propulsive leads by 60 degrees, and by 60 - 180 = -120 with
    the sign of its z reversed. Roll 0.1 sin(w t) and a_5 = 0.7 d(roll)/dt: the gain is 0.7,
    within the central difference's leading relative error (w dt)^2 / 6 = 0.07% (times 1.5
    for its higher orders)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    import start_phase

    dt, w = 0.008, 2 * np.pi / 0.8
    t = np.arange(500) * dt
    step, swing = np.sin(w * t), np.sin(w * t + np.radians(60))
    z = np.zeros((500, 2, 6))
    z[:, :, 0], z[:, :, 1] = step[:, None], -step[:, None]
    z[:, 0, 4], z[:, 0, 5] = swing, -swing
    z[:, 1, 4], z[:, 1, 5] = -swing, swing
    lead = start_phase.relative_phase_deg(z, 100, 400)
    assert lead[0] == pytest.approx(60.0, abs=0.1) and lead[1] == pytest.approx(-120.0, abs=0.1)
    roll = 0.1 * np.sin(w * t)
    a5 = 0.7 * 0.1 * w * np.cos(w * t)
    gain = start_phase.roll_rate_gain(np.stack([roll]), np.stack([a5]), dt, 10, 135)
    assert gain[0] == pytest.approx(0.7, rel=(w * dt) ** 2 / 6 * 1.5)
