"""Walking where it is told: the reward's velocity along a commanded heading, and the
heading study's measure of a walk, each against values computed by hand."""

import math
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.control.controller import ControllerParams
from mjxcpg.control.walk import Trace
from mjxcpg.learning.learner import commanded_velocity
from mjxcpg.physics.model import Observation


def observation(**fields) -> Observation:
    zeros = {name: jnp.float32(0.0) for name in Observation._fields}
    return Observation(**(zeros | {"gyro": jnp.zeros(3)} | fields))


def test_the_reward_reads_the_velocity_along_the_command():
    """v_x 0.1, v_y 0.05 m/s: along +30 degrees 0.1 cos 30 + 0.05 sin 30 = 0.11160; along
    -30 degrees 0.08660 - 0.025 = 0.06160; along +90 degrees v_y; at 0, v_x itself (the
    paper's eq 27, the lateral velocity unread)."""
    obs = observation(forward_velocity=jnp.float32(0.1), lateral_velocity=jnp.float32(0.05))

    def along(degrees):
        return float(commanded_velocity(ControllerParams(heading_command=math.radians(degrees)), obs))
    assert along(30) == pytest.approx(0.111603, abs=1e-6)
    assert along(-30) == pytest.approx(0.061603, abs=1e-6)
    assert along(90) == pytest.approx(0.05, abs=1e-6)
    assert commanded_velocity(ControllerParams(), obs) is obs.forward_velocity


def test_the_heading_study_measures_a_walk_by_hand():
    """A robot turned 20 degrees to the left, walking 0.05 m/s along its heading for 10 s
    (1,001 periods of 0.01 s): after 5 s its mean heading is 20, its largest error from a
    command of 15 is 5, and its speed along the command 0.05 cos 5 = 0.049810 m/s; a robot
    that fell is counted as such, at its fall's time."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    import heading_study

    dt, steps, yaw = 0.01, 1001, math.radians(20)
    t = np.arange(steps) * dt
    qpos = np.zeros((2, steps, 7))
    qpos[:, :, 0], qpos[:, :, 1] = 0.05 * t * math.cos(yaw), 0.05 * t * math.sin(yaw)
    qpos[:, :, 3], qpos[:, :, 6] = math.cos(yaw / 2), math.sin(yaw / 2)   # a turn about z
    fallen = np.zeros((2, steps), bool)
    fallen[1, 700:] = True
    zeros = np.zeros((2, steps))
    trace = Trace(zeros, zeros, zeros, zeros, zeros, zeros, fallen, zeros, qpos)

    walked = heading_study.heading_walk(trace, 0, dt, 15.0, after_s=5.0)
    assert walked["fell"] is False
    assert walked["mean_heading_deg"] == pytest.approx(20.0, abs=1e-9)
    assert walked["largest_error_deg"] == pytest.approx(5.0, abs=1e-9)
    assert walked["speed_along_command"] == pytest.approx(0.05 * math.cos(math.radians(5)), abs=1e-9)
    fell = heading_study.heading_walk(trace, 1, dt, 15.0, after_s=5.0)
    assert fell == {"fell": True, "fell_at_s": pytest.approx(7.0)}
    cell = heading_study.cell([{"learner": 0, **walked}, {"learner": 1, "fell": True}], 15.0)
    assert (cell["walks"], cell["no_fall"], cell["within"]) == (2, 1, 1)


def test_the_heading_config_is_the_paper_set_up_at_k_s_10():
    """The direction study learns on the set-up `make run` reproduces, only its learners differ."""
    from mjxcpg.training import config

    heading, paper = config.load_spec("heading"), config.load_spec("paper")
    assert (heading.controller, heading.trial, heading.learner) == (paper.controller, paper.trial, paper.learner)
    assert set(heading.k_s) == {10.0} and len(set(heading.seeds)) == 10
    assert not set(heading.seeds) & set(paper.seeds)
