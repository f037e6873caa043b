"""The "hardware" robot (docs/hardware.md), the sensor-based reward estimator and online
additional learning."""

import dataclasses
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from learned_run import make_learned_run
from mjxcpg.cli import main
from mjxcpg.control import estimator, walk
from mjxcpg.control.controller import control_step, hand_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.evaluation import online, transfer
from mjxcpg.learning.learner import init_learner
from mjxcpg.physics import engines, hardware
from mjxcpg.physics.model import Sensors, load_model, observe
from mjxcpg.training import runs, train
from mjxcpg.training.config import load_spec

DOC = Path(__file__).resolve().parent.parent / "docs" / "hardware.md"


# ---------------------------------------------------------------- the perturbed model

def test_hardware_model_differs_from_nominal_as_documented():
    nominal = load_model()
    hw = hardware.perturbed_model(nominal)
    m = hardware.HARDWARE
    mass = hw.body_mass[1:] / nominal.body_mass[1:]
    inertia = hw.body_inertia[1:] / nominal.body_inertia[1:]
    assert np.all(np.abs(mass - 1) <= m.mass_spread) and np.std(mass) > 0.02
    assert np.all(np.abs(inertia - 1) <= m.inertia_spread) and np.std(inertia) > 0.02
    np.testing.assert_allclose(inertia, inertia[:, :1] * np.ones(3))  # one factor per body
    assert hw.body_subtreemass[1] == pytest.approx(hw.body_mass[1:].sum())
    contact_points = [f"{side}_sole_{end}_{edge}" for side in "lr" for end in ("toe", "heel")
                      for edge in ("left", "right")]
    for name in ["floor"] + contact_points:  # every geom that collides
        geom = mujoco.mj_name2id(hw, mujoco.mjtObj.mjOBJ_GEOM, name)
        assert geom >= 0 and hw.geom_friction[geom, 0] == pytest.approx(0.7)
    np.testing.assert_allclose(hw.actuator_gainprm[:, 0], 120.0)
    np.testing.assert_allclose(hw.actuator_biasprm[:, 1], -120.0)
    hinge = nominal.jnt_dofadr[nominal.jnt_type == mujoco.mjtJoint.mjJNT_HINGE]
    np.testing.assert_allclose(hw.dof_damping[hinge], nominal.dof_damping[hinge] + 0.5)
    np.testing.assert_allclose(hw.dof_armature[hinge], 2 * nominal.dof_armature[hinge])
    np.testing.assert_array_equal(hw.dof_damping[:6], nominal.dof_damping[:6])  # the free joint
    np.testing.assert_array_equal(hw.body_pos, nominal.body_pos)                 # geometry kept
    # The per-body table in docs/hardware.md is the one the seed gives.
    rows = re.findall(r"^\| (\w+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|$", DOC.read_text(), re.M)
    mass_factor, inertia_factor = hardware.body_factors(nominal, m)
    assert len(rows) == nominal.nbody - 1
    for name, nominal_mass, mass_x, inertia_x in rows:
        body = mujoco.mj_name2id(nominal, mujoco.mjtObj.mjOBJ_BODY, name)
        assert float(nominal_mass) == pytest.approx(nominal.body_mass[body], abs=5e-4)
        assert float(mass_x) == pytest.approx(mass_factor[body], abs=5e-4)
        assert float(inertia_x) == pytest.approx(inertia_factor[body], abs=5e-4)


def test_hardware_simulation_keeps_the_nominal_controller():
    nominal, hw = make_simulation("mujoco"), make_simulation("mujoco", robot="hardware")
    assert isinstance(hw.engine, hardware.HardwareEngine) and hw.engine.name == "mujoco"
    assert hw.layout == nominal.layout                     # the controller's belief
    np.testing.assert_array_equal(hw.qpos0, nominal.qpos0)
    assert hw.model.body_mass.sum() != pytest.approx(nominal.model.body_mass.sum())
    with pytest.raises(ValueError, match="unknown robot"):
        make_simulation("mujoco", robot="qrio")


def test_the_harsh_robot_is_what_docs_hardware_md_says():
    """docs/hardware.md's harsh table, by hand: kp 90 N m/rad, friction 0.5, contact time
    constant 0.04 s, 4 periods of latency, masses within 15%, and every mismatch beyond
    the hardware robot's."""
    nominal, harsh = make_simulation("mujoco"), make_simulation("mujoco", robot="harsh")
    model = harsh.model
    colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    assert model.actuator_gainprm[:, 0] == pytest.approx(90.0)
    assert model.geom_friction[colliding, 0] == pytest.approx(0.5)
    assert model.geom_solref[colliding, 0] == pytest.approx(0.04)
    assert harsh.engine.mismatch.latency_periods == 4
    ratio = model.body_mass[1:] / nominal.model.body_mass[1:]
    assert ratio.min() >= 0.85 and ratio.max() <= 1.15 and np.abs(ratio - 1).max() > 0.10
    assert harsh.layout == nominal.layout
    hw, hx = hardware.HARDWARE, hardware.HARSH
    assert (hx.sole_friction < hw.sole_friction and hx.servo_kp_scale < hw.servo_kp_scale
            and hx.latency_periods > hw.latency_periods and hx.contact_timeconst_scale > hw.contact_timeconst_scale)
    # the hardware robot's floor is the nominal one's
    assert make_simulation("mujoco", robot="hardware").model.geom_solref[colliding, 0] == pytest.approx(0.02)



def test_the_harsher_robot_is_the_harsh_one_with_more_latency_on_a_softer_floor():
    """docs/hardware.md's harsher column, by hand: 6 periods (48 ms) of latency and a contact
    time constant of 0.06 s (three times MuJoCo's 0.02), every other mismatch the harsh robot's."""
    harsh, harsher = make_simulation("mujoco", robot="harsh"), make_simulation("mujoco", robot="harsher")
    colliding = (harsher.model.geom_contype != 0) | (harsher.model.geom_conaffinity != 0)
    assert harsher.engine.mismatch.latency_periods == 6
    assert harsher.model.geom_solref[colliding, 0] == pytest.approx(0.06)
    assert harsher.model.actuator_gainprm[:, 0] == pytest.approx(90.0)
    np.testing.assert_array_equal(harsher.model.body_mass, harsh.model.body_mass)
    others = {f.name for f in dataclasses.fields(hardware.HardwareMismatch)} - {"latency_periods",
                                                                                  "contact_timeconst_scale"}
    assert all(getattr(hardware.HARSHER, name) == getattr(hardware.HARSH, name) for name in others)

# ---------------------------------------------------------------- latency and noise

class Recorder(engines.Engine):
    """A stand-in engine in pure JAX: its state is the servo targets it last applied (and the
    push it was given); its sensors read a constant gyro (0.3 rad/s) and sole forces (20 N)."""

    name = "recorder"

    def init(self, qpos, batch):
        sensordata = np.zeros(self.model.nsensordata, np.float32)
        sensordata[0:3] = 0.3
        sensordata[7:9] = 20.0
        return {"applied": jnp.zeros((batch, self.model.nu)), "push": jnp.zeros((batch, 3)),
                "sensordata": jnp.tile(jnp.asarray(sensordata), (batch, 1))}

    def step(self, state, ctrl, active=None, pelvis_force=None):
        applied = ctrl if active is None else jnp.where(active[:, None], ctrl, state["applied"])
        push = state["push"] if pelvis_force is None else pelvis_force
        return state | {"applied": applied, "push": push}

    def sensors(self, state):
        batch = state["applied"].shape[0]
        return Sensors(qpos=jnp.zeros((batch, self.model.nq)), qvel=jnp.zeros((batch, self.model.nv)),
                       sensordata=state["sensordata"], positive_work=jnp.zeros(batch))


def _wrapped(**mismatch) -> hardware.HardwareEngine:
    model = load_model()
    assert (model.sensor_adr[0], model.sensor_adr[2], model.sensor_adr[3]) == (0, 7, 8)
    return hardware.HardwareEngine(Recorder(model, 1), dataclasses.replace(hardware.HARDWARE, **mismatch))


@pytest.mark.parametrize("periods", [0, 1, 2])
def test_delay_queue_delays_by_exactly_n_periods(periods):
    engine = _wrapped(latency_periods=periods)
    sim = make_simulation("mujoco")
    batch, steps, nu = 2, 6, engine.model.nu
    commands = jnp.arange(1, steps + 1, dtype=jnp.float32)[:, None, None] * jnp.ones((steps, batch, nu))

    def body(state, ctrl):
        state = engine.step(state, ctrl, pelvis_force=jnp.ones((batch, 3)))
        return state, state.inner["applied"]

    final, applied = jax.lax.scan(body, engine.init(sim.qpos0, batch), commands)
    standing = sim.qpos0[engine.model.jnt_qposadr[engine.model.actuator_trnid[:, 0]]]
    for t in range(steps):
        expected = commands[t - periods] if t >= periods else np.broadcast_to(standing, (batch, nu))
        np.testing.assert_allclose(applied[t], expected, atol=1e-6)
    np.testing.assert_array_equal(final.inner["push"], 1.0)  # extra keywords reach the engine
    # A robot that is not stepped keeps its queue.
    held = engine.step(final, commands[0] * 0 - 1, active=jnp.array([True, False]))
    np.testing.assert_array_equal(held.queue[1], final.queue[1])


def _readings(engine, steps=2000, batch=2):
    def body(state, _):
        return engine.step(state, jnp.zeros((batch, engine.model.nu))), engine.sensors(state).sensordata

    return np.asarray(jax.lax.scan(body, engine.init(np.zeros(engine.model.nq), batch), None, length=steps)[1])


def test_sensor_noise_is_deterministic_by_seed():
    engine = _wrapped()
    state = engine.init(np.zeros(engine.model.nq), 2)
    np.testing.assert_array_equal(engine.sensors(state).sensordata, engine.sensors(state).sensordata)
    first, again = _readings(engine), _readings(_wrapped())
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, _readings(_wrapped(noise_seed=1)))
    assert not np.allclose(first[:, 0], first[:, 1])           # each robot its own stream
    m = hardware.HARDWARE
    gyro_error, force_error = first[:, :, 0:3] - 0.3, first[:, :, 7:9] - 20.0
    assert np.std(gyro_error, axis=0) == pytest.approx(np.full((2, 3), m.gyro_noise_std), rel=0.1)
    assert np.std(force_error, axis=0) == pytest.approx(np.full((2, 2), m.force_noise_std), rel=0.1)
    bias = np.mean(gyro_error, axis=0)                          # constant per robot and axis
    assert np.all(np.abs(bias) < 5 * m.gyro_bias_std) and np.std(bias) > 0.1 * m.gyro_bias_std
    np.testing.assert_array_equal(first[:, :, 3:7], 0.0)        # orientation is not perturbed
    # A reset stands the robot up again, but its noise goes on rather than replaying.
    initial = engine.init(np.zeros(engine.model.nq), 2)
    later = engine.step(engine.step(initial, jnp.zeros((2, engine.model.nu))), jnp.zeros((2, engine.model.nu)))
    reset = engine.reset(later, initial, jnp.array([True, True]))
    assert not np.allclose(engine.sensors(reset).sensordata, engine.sensors(initial).sensordata)
    np.testing.assert_array_equal(reset.queue, initial.queue)


# ---------------------------------------------------------------- the estimator

def _estimated_walk(robot: str, seconds: float = 10.0):
    """The hand-designed gait for ``seconds``: the estimate and the ground truth per period."""
    sim = make_simulation("native", robot=robot)
    params = estimator.EstimatorParams.of(sim.model)
    dt = sim.control_dt

    def one(cpg_state, sensors, est):
        obs = observe(sim.layout, sensors)
        est, measured = estimator.estimate(params, est, sensors, obs, dt)
        cpg_state, ctrl = control_step(sim.params, sim.layout, cpg_state, obs, hand_feedback(sim.params, obs))
        return cpg_state, ctrl, est, (measured, obs.height, obs.forward_velocity, walk.has_fallen(sim.layout, obs))

    def body(carry, _):
        physics, cpg_state, est = carry
        cpg_state, ctrl, est, out = jax.vmap(one)(cpg_state, sim.engine.sensors(physics), est)
        return (sim.engine.step(physics, ctrl), cpg_state, est), out

    est0 = jax.tree.map(lambda x: x[None], estimator.init_state(params, sim.layout.pelvis_height(sim.params.z0)))
    carry = (sim.engine.init(sim.qpos0, 1), walk.initial_controller(1), est0)
    _, out = jax.jit(lambda c: jax.lax.scan(body, c, None, length=round(seconds / dt)))(carry)
    measured, height, velocity, fell = jax.tree.map(lambda x: np.asarray(x[:, 0]), out)
    return measured, height, velocity, fell, dt


def _low_pass(x: np.ndarray, dt: float, tau: float = 0.5) -> np.ndarray:
    """The learner's velocity filter (TrialParams.velocity_filter_s = 0.5 s)."""
    alpha = dt / tau
    return jax.lax.scan(lambda y, u: (y + alpha * (u - y),) * 2, jnp.float32(0), jnp.asarray(x))[1]


@pytest.mark.parametrize("robot, velocity_bias, velocity_rms", [
    ("nominal", 0.005, 0.008),
    # On the hardware robot the stance sole slips on the lower friction, and gyro noise and
    # bias enter the inclination: a looser bound than on the nominal robot.
    ("hardware", 0.02, 0.025),
])
def test_estimator_is_close_to_ground_truth_on_a_walk(robot, velocity_bias, velocity_rms):
    measured, height, velocity, fell, dt = _estimated_walk(robot)
    assert not fell.any() and not measured.fallen.any()
    steady = slice(round(2.0 / dt), None)                       # after 2 s of gait start-up
    height_error = (measured.height - height)[steady]
    assert abs(height_error.mean()) < 0.005 and np.sqrt(np.mean(height_error ** 2)) < 0.006
    assert np.abs(height_error).max() < 0.015
    assert abs(measured.forward_velocity[steady].mean() - velocity[steady].mean()) < velocity_bias
    filtered_error = (np.asarray(_low_pass(measured.forward_velocity, dt)) - np.asarray(_low_pass(velocity, dt)))
    assert np.sqrt(np.mean(filtered_error[steady] ** 2)) < velocity_rms


def test_estimator_sees_a_fall_from_tilt_and_height():
    sim = make_simulation("mujoco")
    params = estimator.EstimatorParams.of(sim.model)
    sensors = jax.tree.map(lambda x: x[0], sim.engine.sensors(sim.engine.init(sim.qpos0, 1)))
    state = estimator.init_state(params, sim.layout.pelvis_height(sim.params.z0))
    obs = observe(sim.layout, sensors)
    _, standing = estimator.estimate(params, state, sensors, obs, sim.control_dt)
    assert not standing.fallen and float(standing.height) == pytest.approx(float(obs.height), abs=0.01)
    _, tilted = estimator.estimate(params, state, sensors, obs._replace(roll=jnp.float32(1.2)), sim.control_dt)
    crouched = sensors._replace(qpos=sensors.qpos.at[jnp.array(params.left.qpos + params.right.qpos)].set(
        jnp.tile(jnp.array([0.0, 0.0, -1.2, 2.4, -1.2, 0.0]), 2)))
    low = estimator.init_state(params, 0.15)
    _, fallen = estimator.estimate(params, low, crouched, obs, sim.control_dt)
    assert tilted.fallen and fallen.fallen


def test_learner_reads_the_estimator_only_when_asked():
    sim = make_simulation("mujoco")
    task = train.make_task(sim, train.RunSpec(k_s=(10.0,), seeds=(0,)))
    truth = init_learner(task, 10.0, 0)
    assert truth.estimate is None  # no extra leaves: checkpoints of simulation runs still load
    estimating = init_learner(dataclasses.replace(task, estimator=estimator.EstimatorParams.of(sim.model)), 10.0, 0)
    assert isinstance(estimating.estimate, estimator.EstimatorState)
    assert len(jax.tree.leaves(estimating)) == len(jax.tree.leaves(truth)) + len(estimating.estimate)


# ---------------------------------------------------------------- command line

@pytest.mark.parametrize("argv, message", [
    (["learn", "--robot", "hardware"], "need --from"),
    (["learn", "--exploration", "initial"], "need --from"),
    (["learn", "--from", "/nonexistent/run", "--robot", "hardware"], "no run directory"),
    (["learn", "--from", "/nonexistent/run", "--k-s", "3"], "come from the checkpoint"),
    (["learn", "--from", "/nonexistent/run", "--platform", "child"], "come from the checkpoint"),
    (["learn", "--from", "/nonexistent/run", "--checkpoint-every", "0"], "--checkpoint-every does not apply"),
])
def test_online_learning_bad_input_is_one_line(argv, message, capsys, tmp_path):
    assert main(argv + ["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("exploration", ["1.5", "1", "0", "1e-50", "0.9999999999", "nan", "wide"])
def test_online_exploration_outside_eq26_range_is_one_line(exploration, capsys, tmp_path):
    """sigma = sigmoid(w^sigma) lies in (0, 1), and float32 rounds sigmoid(log(1e-50 / (1 - 1e-50)))
    to 0 and 1 - 1e-10 to 1: any such restart value is refused by the parser."""
    with pytest.raises(SystemExit) as exit_info:
        main(["learn", "--from", "/nonexistent/run", "--exploration", exploration, "--out", str(tmp_path / "out")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "or a sigma from 1e-06 to 0.999999" in err and "\n" not in err
    assert not (tmp_path / "out").exists()


def test_online_learning_never_replaces_its_source(finished_quick, capsys):
    before = {p: p.read_bytes() for p in finished_quick.rglob("*") if p.is_file() and p.name != ".lock"}
    for out in (finished_quick, finished_quick.parent):  # the run itself, or a directory holding it
        argv = ["learn", "--from", str(finished_quick), "--out", str(out), "--force", "--trials", "1"]
        assert main(argv) == 2
        assert "is or holds the run learned from" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in finished_quick.rglob("*") if p.is_file() and p.name != ".lock"} == before


# ---------------------------------------------------------------- transfer and online learning (slow)

@pytest.fixture(scope="module")
def learned_run(tmp_path_factory):
    return make_learned_run(tmp_path_factory.mktemp("learned") / "run")


@pytest.mark.slow
def test_transfer_reports_both_robots(learned_run):
    result = transfer.hardware_transfer(learned_run, repeats=2)
    assert result["succeeded_in_simulation"] == 1 and result["walk_nominal"] == 1
    (row,) = result["learners"]
    assert row["walked_nominal"] and row["mean_vx_nominal"] > 0.03
    assert row["walked_hardware"] == (row["walks_hardware"] == 2)
    assert result["walk_hardware"] == int(row["walked_hardware"])
    assert result["walk_hardware_any"] == int(row["walks_hardware"] > 0)
    with pytest.raises(runs.RunError, match="out of range"):
        transfer.walk_policies(learned_run, learners=[3])


@pytest.mark.slow
def test_hardware_walks_draw_their_sensor_noise_from_the_seed_given(learned_run):
    default = transfer.walk_policies(learned_run, seconds=3.0)
    assert transfer.walk_policies(learned_run, seconds=3.0, noise_seed=hardware.HARDWARE.noise_seed) == default
    other = transfer.walk_policies(learned_run, seconds=3.0, noise_seed=7)
    assert other[0]["mean_vx"] != default[0]["mean_vx"]   # other noise, another walk
    assert transfer.hardware_transfer(learned_run, seconds=1.0, noise_seed=7)["mismatch"]["noise_seed"] == 7


@pytest.mark.slow
def test_online_learning_continues_on_hardware(learned_run, tmp_path, capsys):
    out = tmp_path / "online"
    argv = ["learn", "--from", str(learned_run), "--learner", "0", "--robot", "hardware", "--trials", "2",
            "--out", str(out), "--quiet", "--json"]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    record = json.loads((out / "online.json").read_text())
    assert printed["reward"] == record["reward"] == "estimate" and record["trial_seconds"] == 16.0
    (row,) = record["learners"]
    assert row["learner"] == 0 and row["trials"] == len(row["returns"]) == len(row["falls"]) == 2
    assert (out / "learning_curve.png").is_file()
    spec, _, _, state = runs.load_run(out, robot="hardware")
    assert spec.trial.trial_seconds == 16.0 and spec.k_s == (10.0,)
    assert state.learners.weights.mean.shape == (1, 225)


@pytest.mark.slow
def test_online_learning_off_keeps_the_weights_it_started_from(learned_run, tmp_path):
    """The control: every learning rate 0, so the weights stay the source learner's, bit for
    bit, while the trials run (two learners in one batch, the same one twice)."""
    out = tmp_path / "online_off"
    summary = online.learn_online(learned_run, [0, 0], out, trials=2, robot="harsh", learning=False,
                                  progress=False, tensorboard=False)
    assert summary["learning"] is False and summary["robot"] == "harsh"
    _, _, _, source = runs.load_run(learned_run)
    _, _, _, state = runs.load_run(out, robot="harsh")
    for before, after in zip(jax.tree.leaves(source.learners.weights), jax.tree.leaves(state.learners.weights)):
        np.testing.assert_array_equal(np.asarray(after), np.repeat(np.asarray(before)[:1], 2, axis=0))


@pytest.mark.slow
def test_online_learning_can_restart_sigma_at_its_initial_value(tmp_path):
    """exploration="initial": sigma starts at eq (26)'s sigmoid(0) = 0.5 (the learner's
    init_w_sigma), the critic and mean as learned; "learned" keeps the source's sigma,
    sigmoid(-1.5) = 0.18243; a number is the sigma to start at; learning off, so nothing
    moves them during the trials."""
    source = make_learned_run(tmp_path / "source", w_sigma=-1.5)
    _, _, _, before = runs.load_run(source)
    first_sigma = {}
    for exploration in online.EXPLORATIONS + (0.2,):
        out = tmp_path / str(exploration)
        online.learn_online(source, [0], out, trials=2, robot="harsh", learning=False, exploration=exploration,
                            progress=False, tensorboard=False)
        (row,) = json.loads((out / "online.json").read_text())["learners"]
        first_sigma[exploration] = row["sigmas"][0]
        _, _, _, after = runs.load_run(out, robot="harsh")
        for name in ("critic", "mean"):
            np.testing.assert_array_equal(np.asarray(getattr(after.learners.weights, name)),
                                          np.asarray(getattr(before.learners.weights, name)))
    assert first_sigma["initial"] == 0.5  # exact in float32
    assert first_sigma["learned"] == pytest.approx(1.0 / (1.0 + np.exp(1.5)), rel=1e-6)  # float32 rounding
    assert first_sigma[0.2] == pytest.approx(0.2, rel=1e-6)  # w^sigma = log(0.2 / 0.8), rounded to float32


def test_online_trials_from_standing_hand_over_at_the_first_period():
    """start="standing": the learner acts from the first control period of every trial, and
    its final policy is walked from standing too; learning=False zeroes every rate."""
    spec = load_spec("paper")
    standing = online.continued_spec(spec, [4, 22], trials=200, trial_seconds=16.0, learning=False, start="standing")
    assert standing.k_s == (1.0, 10.0) and standing.seeds == (4, 22)
    assert standing.trial.hand_seconds == (0.0, 0.0) and standing.trial.walk_hand_seconds == 0.0
    assert standing.trial.trials_after_success == 0 and standing.learner.rate_scale == 0.0
    hand = online.continued_spec(spec, [4], trials=200, trial_seconds=16.0)
    assert hand.trial.hand_seconds == spec.trial.hand_seconds and hand.learner == spec.learner
    with pytest.raises(ValueError, match="unknown start"):
        online.continued_spec(spec, [4], trials=200, trial_seconds=16.0, start="lying")
