"""The actuators' positive work, as every engine integrates it, against closed forms; the cost
of transport of a walk against its hand-computed value."""

import jax
import mujoco
import numpy as np
import pytest

from mjxcpg.control import walk
from mjxcpg.physics import engines
from mjxcpg.physics.model import with_power_sensors

TORQUE = 0.5        # N m
TIMESTEP = 0.004    # s, the robot's physics step
SUBSTEPS = 2        # physics steps per control period, as the robot's

# One hinge driven by a torque motor, nothing else acting on it (no gravity, damping,
# friction or contact), stepped with MuJoCo's semi-implicit Euler.  The floor, a metre below,
# never touches it; without any geometry that could collide, MJX's actuatorfrc sensor read 0.
WHEEL = f"""
<mujoco>
  <option timestep="{TIMESTEP}" gravity="0 0 0" integrator="Euler"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1" pos="0 0 -1"/>
    <body name="pelvis">
      <joint name="spin" type="hinge" axis="0 0 1"/>
      <geom type="cylinder" size="0.1 0.02" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor name="spin" joint="spin"/></actuator>
</mujoco>
"""


def wheel_model() -> mujoco.MjModel:
    return with_power_sensors(mujoco.MjSpec.from_string(WHEEL)).compile()


def spin(engine: engines.Engine, torques: list[float], batch: int = 1, pushed: bool = False):
    """Per control period, one torque for every robot: the work each period reported, and the
    final angle and angular velocity of the first robot."""
    state = engine.init(np.zeros(1), batch)
    step = jax.jit(engine.step)
    work = []
    for torque in torques:
        ctrl = np.full((batch, 1), torque, np.float32)
        kwargs = {"pelvis_force": np.zeros((batch, 3), np.float32)} if pushed else {}
        state = step(state, ctrl, **kwargs)
        work.append(np.asarray(engine.sensors(state).positive_work))
    sensors = engine.sensors(state)
    return np.array(work), float(sensors.qpos[0, 0]), float(sensors.qvel[0, 0])


ENGINE_CASES = [("mujoco", 1, False), ("native", 1, False), ("native", 16, False),
                ("native", 2, True), ("mjx", 1, False)]


@pytest.mark.parametrize("name,batch,pushed", ENGINE_CASES,
                         ids=["mujoco", "native-in-xla", "native-threads", "native-rollout", "mjx"])
def test_a_constant_torque_does_torque_times_angle(name, batch, pushed):
    """From rest under a constant torque tau the motor does tau x angle of work.  Each physics
    step's power is read before the step integrates (the sensors' velocity is the step's
    starting one), and semi-implicit Euler moves the angle with the step's final velocity, so
    the sum falls short of tau x angle by exactly tau x (final velocity) x step."""
    engine = engines.make_engine(name, wheel_model(), SUBSTEPS)
    periods = 100
    work, angle, velocity = spin(engine, [TORQUE] * periods, batch, pushed)
    total = work.sum(axis=0)
    np.testing.assert_allclose(total, TORQUE * (angle - velocity * TIMESTEP), rtol=1e-4)  # float32 state
    assert total == pytest.approx(TORQUE * angle, rel=2 * TIMESTEP / (periods * SUBSTEPS * TIMESTEP) + 1e-4)
    np.testing.assert_allclose(work, work[:, :1] * np.ones(batch))  # every robot alike


@pytest.mark.parametrize("name", ["mujoco", "native", "mjx"])
def test_braking_counts_no_work(name):
    """Spun up for 50 periods, then braked by the opposite torque for 25 (it turns on, slowing
    to half its speed): the braking motor does negative work, which counts as none."""
    engine = engines.make_engine(name, wheel_model(), SUBSTEPS)
    work, _, velocity = spin(engine, [TORQUE] * 50 + [-TORQUE] * 25)
    assert velocity > 0
    np.testing.assert_array_equal(work[50:], 0.0)
    _, spun_angle, spun_velocity = spin(engine, [TORQUE] * 50)
    assert work[:50].sum() == pytest.approx(TORQUE * (spun_angle - spun_velocity * TIMESTEP), rel=1e-4)


def test_cost_of_transport_of_a_steady_walk():
    """A robot of weight m g walking at v while its actuators do P watts of positive work:
    CoT = P / (m g v), counted after the settling time only."""
    dt, steps, weight, speed, power = 0.008, 1000, 40.0, 0.05, 3.0
    t = np.arange(steps) * dt
    work = np.full(steps, power * dt)
    work[:100] = 50.0  # a costly start, left out with the settling
    ones = np.ones((1, steps))
    trace = walk.Trace(height=0.28 * ones, forward_position=(speed * t)[None], force_left=ones, force_right=ones,
                       roll=np.sin(2 * np.pi * t)[None], a5=0 * ones, fallen=np.zeros((1, steps), bool),
                       positive_work=work[None])
    gait = walk.summarise(trace, dt, weight, settle_s=1.0)[0]
    assert gait.cost_of_transport == pytest.approx(power / (weight * speed), rel=1e-6)
    assert walk.cost_of_transport(1.0, weight, 0.0) is None   # it did not go forward


def test_the_energy_reward_is_eq_27_less_k_e_power_over_weight():
    """r = k_H (h - h') + k_S v - k_E P / (m g), computed by hand: k_H 10, h' 0.2, h 0.21,
    k_S 5, v 0.06, k_E 2, P 7.2 W on a robot of 72 N (P / (m g) = 0.1 m/s):
    0.1 + 0.3 - 0.2 = 0.2; without an energy gain the paper's 0.4, whatever the power."""
    from mjxcpg.learning.learner import TrialParams, reward

    trial = TrialParams(k_h=10.0, h_ref=0.2)
    assert float(reward(trial, 5.0, 0.21, 0.06, 2.0, 7.2 / 72.0)) == pytest.approx(0.2, abs=1e-12)
    assert float(reward(trial, 5.0, 0.21, 0.06, None, 1e6)) == pytest.approx(0.4, abs=1e-12)


def test_the_energy_cells_give_power_over_weight_and_fractions_of_k_e_0():
    from mjxcpg.report.evaluation import energy_cells

    def learner(k_e, succeeded, fell, vx, cot):
        return {"k_s": 2.0, "k_e": k_e, "succeeded": succeeded,
                "return_map": {"fell": fell, "mean_vx": vx, "cost_of_transport": cot}}

    # by hand: k_E = 0 walks 0.05 m/s at CoT 1.2 and 0.07 at 1.0 (P/(m g) 0.06, 0.07);
    # k_E = 1 walks 0.06 at CoT 0.9; a failed and a fallen learner are left out
    result = {"learners": [learner(0.0, True, False, 0.05, 1.2), learner(0.0, True, False, 0.07, 1.0),
                           learner(1.0, True, False, 0.06, 0.9), learner(1.0, False, False, 0.2, 0.1),
                           learner(1.0, True, True, 0.2, 0.1)]}
    base, energy = energy_cells(result)
    assert (base["learners"], base["succeeded"], base["walking"]) == (2, 2, 2)
    assert (energy["learners"], energy["succeeded"], energy["walking"]) == (3, 2, 1)
    np.testing.assert_allclose(base["power_over_weight"]["value"], 0.065)
    np.testing.assert_allclose(energy["power_over_weight"]["value"], 0.054)
    np.testing.assert_allclose(energy["mean_vx_of_k_e_0"], 0.06 / 0.06)
    np.testing.assert_allclose(energy["cost_of_transport_of_k_e_0"], 0.9 / 1.1)
