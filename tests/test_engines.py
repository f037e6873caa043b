"""MJX, the batched engine, against MuJoCo C, the scalar reference.

Measured figures and the reasons for every tolerance are in ``docs/engines.md``.  The soles
touch the floor through spheres at their corners, a contact both engines compute the same
way, and the Newton solver runs until it converges, so that its result does not depend on
either engine's line search.  Then MJX and C compute the same step: in float64 they agree
to within 1e-9 of the step's velocity change, and MJX's float32 differs from C's float64 by
float32 rounding, amplified by the conditioning of the solve.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import orbax.checkpoint as ocp
import pytest
from conftest import HAND, LEARNED, load_learned_policy, model_fingerprint

from mjxcpg.cli import main
from mjxcpg.control import walk
from mjxcpg.control.controller import control_step, joint_targets, roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.physics import engines, native_step
from mjxcpg.physics.model import Layout, observe
from mjxcpg.robots.qrio import QRIO
from mjxcpg.training import checkpoints
from mjxcpg.training.config import load_spec
from mjxcpg.training.train import RunState

SEED = 0
ONE_STEP_STATES = 100
WALK_SECONDS_FOR_STATES = 5.0   # states are sampled from this C walk, after its first second
FEET = ("l_foot", "r_foot")

# One 4 ms physics step from the same state.  MJX computes in float32, C in float64.  The
# step solves for the acceleration with a Newton Hessian whose condition number is at most
# 6.2e3 over walking states (median 2.4e3); float32's unit roundoff is 2^-24 = 6e-8, so the
# relative error of a float32 solve is up to about 6.2e3 * 6e-8 = 3.7e-4.
FLOAT32_VELOCITY_CHANGE_REL = 4e-4  # of |qvel_c - qvel_start| (3 to 8 in norm): the acceleration's error
FLOAT32_TOUCH_REL = 4e-4            # of max(sole force, m g): forces come out of the same solve
FLOAT32_QPOS_ATOL = 2e-5            # m or rad: 4e-4 of a velocity change of 8, over dt = 4 ms, is 1.3e-5
SENSOR_READ_ATOL = 5e-6             # gyro (rad/s), orientation: read before the step, |x| < 10, 8 ulps
MIN_FLOAT32_FRACTION = 0.95         # of the states within these tolerances ...
FLOAT32_OUTLIER_FACTOR = 10.0       # ... and every state within 10 times them
# MJX in float64 against C: the same algorithm in the same arithmetic, so the same result to
# double rounding (1e-16) times the solve's condition number (6.2e3), unless the solver's
# stopping test (MuJoCo's tolerance, 1e-8 of the cost's scale) stops one engine an iteration
# earlier: 1e-9 allows neither a skipped iteration nor another contact set.
FLOAT64_VELOCITY_CHANGE_REL = 1e-9

# The hand-designed walk from standing: the pelvis stands at 0.283 m, swings 15 mm within a
# step and walks about 0.15 m in 2 s.  Both engines integrate the same physics, so the
# trajectories part no more than C's own from starts that differ by float32 rounding.
ROLLOUT_SECONDS = 2.0
ROLLOUT_ATOL = 0.002               # m: C against itself from float32-sized start perturbations
# Mean speed over 18 s (after 2 s of settling).  C's own spread over 16 starts perturbed by
# 1e-4 rad is +-2% for a learned policy and +-0.5% for the hand-designed one (docs/engines.md).
HAND_SPEED_REL = 0.03
LEARNED_SPEED_REL = 0.05


class StartStates(NamedTuple):
    """Robot states and servo targets, float32-representable, one row per state."""

    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray


class EngineOutput(NamedTuple):
    qpos: np.ndarray
    qvel: np.ndarray
    sensordata: np.ndarray


def hand_walk_states(sim, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel and servo targets at every control period of a C walk under the
    hand-designed feedback a_5 = d theta_roll/dt: (steps, nq), (steps, nv), (steps, nu)."""
    layout, params, engine = sim.layout, sim.params, sim.engine

    def one_robot(cpg_state, sensors):
        obs = observe(layout, sensors)
        return control_step(params, layout, cpg_state, obs, roll_rate_feedback(obs, 1.0))

    def body(carry, _):
        physics, cpg_state = carry
        sensors = engine.sensors(physics)
        cpg_state, ctrl = jax.vmap(one_robot)(cpg_state, sensors)
        return (engine.step(physics, ctrl), cpg_state), (sensors.qpos[0], sensors.qvel[0], ctrl[0])

    @jax.jit
    def run(physics, cpg_state):
        return jax.lax.scan(body, (physics, cpg_state), None, length=steps)[1]

    qpos, qvel, ctrl = jax.device_get(run(engine.init(sim.qpos0, 1), walk.initial_controller(1)))
    return np.asarray(qpos), np.asarray(qvel), np.asarray(ctrl)


def perturbed_walking_states(sim, count: int, seed: int) -> StartStates:
    """``count`` states of a C walk of the hand controller, each perturbed at random: joint
    angles by 0.02 rad, pelvis height by 1 mm, every velocity by 0.1 (rad or m)/s and the servo
    targets by 0.02 rad (standard deviations).  The soles stay near the floor, so the contacts
    are those of walking: none, a flat sole, a heel or toe edge, one or two feet."""
    steps = round(WALK_SECONDS_FOR_STATES / sim.control_dt)
    qpos, qvel, ctrl = hand_walk_states(sim, steps)
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(np.arange(round(1.0 / sim.control_dt), steps), count, replace=False))
    qpos, qvel, ctrl = (np.array(x[rows], np.float64) for x in (qpos, qvel, ctrl))
    qpos[:, 7:] += rng.normal(0.0, 0.02, qpos[:, 7:].shape)   # hinge joints (after the free joint)
    qpos[:, 2] += rng.normal(0.0, 0.001, count)
    qvel += rng.normal(0.0, 0.1, qvel.shape)
    ctrl += rng.normal(0.0, 0.02, ctrl.shape)
    # Both engines must start from the same numbers: round to float32 once.
    return StartStates(*(x.astype(np.float32).astype(np.float64) for x in (qpos, qvel, ctrl)))


def step_c(model: mujoco.MjModel, states: StartStates) -> EngineOutput:
    """One physics step of MuJoCo C in float64 from a zero warm start, as the C engines step
    (they start every control period cold), with outputs kept in float64."""
    data = mujoco.MjData(model)
    out = EngineOutput(np.empty_like(states.qpos), np.empty_like(states.qvel),
                       np.empty((len(states.qpos), model.nsensordata)))
    for b in range(len(states.qpos)):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:], data.ctrl[:] = states.qpos[b], states.qvel[b], states.ctrl[b]
        mujoco.mj_step(model, data)
        out.qpos[b], out.qvel[b], out.sensordata[b] = data.qpos, data.qvel, data.sensordata
    return out


def step_mjx(model: mujoco.MjModel, states: StartStates) -> tuple[EngineOutput, np.ndarray]:
    """One physics step of ``MjxEngine`` from a zero warm start, in the precision JAX is set
    to, and the number of penetrating contacts per foot (states, feet) MJX found at the start."""
    engine = engines.MjxEngine(model, substeps=1)
    dtype = jnp.zeros(()).dtype  # float64 under jax.enable_x64
    batch = len(states.qpos)
    # mjx.make_data, not engine.init: its mjx.forward would be one more slow compile, and
    # the step computes everything from qpos, qvel and ctrl anyway.
    blank = engine._mjx.make_data(model, impl="jax")
    start = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), blank)
    start = start.replace(qpos=jnp.asarray(states.qpos, dtype), qvel=jnp.asarray(states.qvel, dtype),
                          qacc_warmstart=jnp.zeros((batch, model.nv), dtype))
    start = engines.MjxState(data=start, positive_work=jnp.zeros(batch, dtype))
    stepped = jax.jit(engine.step)(start, jnp.asarray(states.ctrl, dtype))
    contact = stepped.data._impl.contact  # MJX's contacts of this step (at the starting state)
    geom, dist = np.asarray(contact.geom), np.asarray(contact.dist)
    counts = np.stack([(np.isin(geom, points).any(axis=-1) & (dist < 0)).sum(axis=-1)
                       for points in foot_contact_geoms(model)], axis=-1)
    sensors = jax.device_get(engine.sensors(stepped))
    return EngineOutput(*(np.asarray(x, np.float64) for x in (sensors.qpos, sensors.qvel, sensors.sensordata))), counts


def foot_contact_geoms(model: mujoco.MjModel) -> list[np.ndarray]:
    """Per foot, the geoms that collide (the sole's corner spheres)."""
    out = []
    for name in FEET:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        out.append(np.flatnonzero((model.geom_bodyid == body) & (model.geom_contype != 0)))
    return out


def c_contact_counts(model: mujoco.MjModel, states: StartStates) -> np.ndarray:
    """Penetrating contacts per foot (states, feet) that MuJoCo C finds at each state."""
    data = mujoco.MjData(model)
    feet = foot_contact_geoms(model)
    counts = np.zeros((len(states.qpos), len(feet)), int)
    for b in range(len(states.qpos)):
        data.qpos[:], data.qvel[:] = states.qpos[b], states.qvel[b]
        mujoco.mj_forward(model, data)
        for k in range(data.ncon):
            contact = data.contact[k]
            for f, points in enumerate(feet):
                counts[b, f] += contact.dist < 0 and bool(np.isin(contact.geom, points).any())
    return counts


class OneStepComparison(NamedTuple):
    states: StartStates
    c: EngineOutput
    mjx: EngineOutput            # float32, as the engine runs
    mjx_float64: EngineOutput
    c_contacts: np.ndarray       # (states, feet) penetrating contact points
    mjx_contacts: np.ndarray


@pytest.fixture(scope="module")
def one_step(mujoco_sim) -> OneStepComparison:
    model = mujoco_sim.model
    states = perturbed_walking_states(mujoco_sim, ONE_STEP_STATES, SEED)
    mjx, mjx_contacts = step_mjx(model, states)
    with jax.enable_x64(True):
        mjx_float64, _ = step_mjx(model, states)
    return OneStepComparison(states, step_c(model, states), mjx, mjx_float64,
                             c_contact_counts(model, states), mjx_contacts)


def velocity_change_error(comparison: OneStepComparison, mjx: EngineOutput) -> np.ndarray:
    """Per state: |qvel_mjx - qvel_c| / |qvel_c - qvel_start|, the error relative to the
    velocity change of the step, i.e. to the step's acceleration (norms over all dofs)."""
    change = np.linalg.norm(comparison.c.qvel - comparison.states.qvel, axis=1)
    return np.linalg.norm(mjx.qvel - comparison.c.qvel, axis=1) / change


def touch_error(comparison: OneStepComparison, layout: Layout) -> np.ndarray:
    """Per state: the largest sole-force difference, relative to the larger of C's force and
    the robot's weight m g = 66 N."""
    touch = [layout.left_touch, layout.right_touch]
    c = comparison.c.sensordata[:, touch]
    difference = np.abs(comparison.mjx.sensordata[:, touch] - c)
    return (difference / np.maximum(np.abs(c), layout.weight)).max(axis=1)


def read_sensor_error(comparison: OneStepComparison, layout: Layout) -> np.ndarray:
    """Per state: the largest difference of the gyro and orientation readings."""
    read = list(range(layout.gyro, layout.gyro + 3)) + list(range(layout.quat, layout.quat + 4))
    return np.abs(comparison.mjx.sensordata[:, read] - comparison.c.sensordata[:, read]).max(axis=1)


def test_sampled_states_cover_walking_contacts(one_step):
    """The sample is of walking: most states have a sole on the floor, some on one or two
    corners (a heel strike, a toe-off, a sole rolling), some on three or more (a sole flat,
    or both feet down)."""
    points = one_step.c_contacts.sum(axis=1)
    assert (points > 0).mean() > 0.8
    assert ((points >= 1) & (points <= 2)).mean() >= 0.2
    assert (points >= 3).mean() >= 0.05


def test_engines_find_the_same_contacts(one_step):
    """Sphere against plane is one contact point, computed alike by both engines: in every
    state each foot has the same penetrating points in MJX and in C."""
    np.testing.assert_array_equal(one_step.mjx_contacts, one_step.c_contacts)


def test_mjx_in_float64_computes_cs_step(one_step):
    """MJX run in float64 is C's algorithm: in every state the step's velocity change agrees
    within 1e-9 of its size (measured at most 4e-15, median 6e-16)."""
    error = velocity_change_error(one_step, one_step.mjx_float64)
    assert error.max() <= FLOAT64_VELOCITY_CHANGE_REL, np.sort(error)[-5:]


@pytest.mark.slow
def test_mjx_engine_starts_in_the_precision_jax_runs_in(mujoco_sim):
    """Under x64 the state ``MjxEngine.init`` returns is float64 throughout, as MJX's own
    data is, so that a float64 walk steps from it (a float32 position in it breaks the
    step's loop)."""
    with jax.enable_x64(True):
        engine = engines.MjxEngine(mujoco_sim.model, substeps=1)
        state = engine.init(mujoco_sim.qpos0, 2)
        floats = {x.dtype for x in jax.tree.leaves(state) if jnp.issubdtype(x.dtype, jnp.floating)}
        assert floats == {jnp.dtype(jnp.float64)}
        stepped = jax.jit(engine.step)(state, jnp.zeros((2, mujoco_sim.model.nu)))
        assert stepped.data.qpos.dtype == jnp.float64 and np.isfinite(np.asarray(stepped.data.qpos)).all()


def test_one_step_agrees_to_float32_rounding(one_step, mujoco_sim):
    """One 4 ms step from 100 perturbed walking states, MJX (float32) against C (float64),
    both from a zero warm start.  At least 95% of the states agree within the float32
    tolerances (module constants: the velocity change within 4e-4 of its size, sole forces
    within 4e-4 of the larger of the force and m g, qpos within 2e-5), and none is off by more
    than 10 times them (measured: all within, the worst at 0.17 times them).  Gyro and
    orientation are read at the start of the step: 5e-6 (measured 1e-6)."""
    velocity = velocity_change_error(one_step, one_step.mjx) / FLOAT32_VELOCITY_CHANGE_REL
    touch = touch_error(one_step, mujoco_sim.layout) / FLOAT32_TOUCH_REL
    qpos = np.abs(one_step.mjx.qpos - one_step.c.qpos).max(axis=1) / FLOAT32_QPOS_ATOL
    worst = np.maximum.reduce([velocity, touch, qpos])  # in units of the tolerances
    assert (worst <= 1).mean() >= MIN_FLOAT32_FRACTION, f"{(worst <= 1).sum()} of {worst.size} within tolerance"
    assert worst.max() <= FLOAT32_OUTLIER_FACTOR, f"worst state at {worst.max():.1f} times the tolerances"
    assert read_sensor_error(one_step, mujoco_sim.layout).max() <= SENSOR_READ_ATOL


def test_short_rollout_agrees_in_pelvis_height_and_forward_position(session_walk_mujoco, session_walk_mjx,
                                                                    mujoco_sim):
    """The hand-designed controller (a_5 = d theta_roll/dt) from standing on both engines:
    the first 2 s of the session's 20 s walks.  The pelvis stays within 2 mm in height and in
    forward position: C against itself, started with every joint moved by 1e-6 rad (a
    float32-sized change; 16 starts), parts by up to 1.9 mm in height and 1.1 mm forward
    over these 2 s (docs/engines.md).  Measured MJX against C: 0.09 mm and 0.12 mm."""
    c, x = session_walk_mujoco.trace, session_walk_mjx.trace
    steps = round(ROLLOUT_SECONDS / mujoco_sim.control_dt)
    assert not c.fallen[HAND, :steps].any() and not x.fallen[HAND, :steps].any()
    height = x.height[HAND, :steps] - c.height[HAND, :steps]
    forward = x.forward_position[HAND, :steps] - c.forward_position[HAND, :steps]
    assert np.abs(height).max() <= ROLLOUT_ATOL
    assert np.abs(forward).max() <= ROLLOUT_ATOL


def test_hand_designed_gait_speed_within_three_percent(walks_mujoco, walks_mjx):
    """The hand-designed gait walks 20 s on both engines without a fall, at mean speeds
    within 3% (measured C 0.0802, MJX 0.0803 m/s)."""
    c, x = walks_mujoco[HAND], walks_mjx[HAND]
    assert not c.fell and not x.fell
    assert abs(x.mean_vx - c.mean_vx) <= HAND_SPEED_REL * c.mean_vx


def test_learned_policy_speed_within_five_percent(walks_mujoco, walks_mjx):
    """The policy stored in tests/data (learned on the native C engine) walks 20 s on both
    engines without a fall, at mean speeds within 5% (measured C 0.0660, MJX 0.0668 m/s)."""
    c, x = walks_mujoco[LEARNED], walks_mjx[LEARNED]
    assert not c.fell and not x.fell
    assert c.mean_vx > 0.03
    assert abs(x.mean_vx - c.mean_vx) <= LEARNED_SPEED_REL * c.mean_vx


def test_stored_policy_was_learned_on_this_model():
    """The stored policy says how and at which commit it was made, it succeeded, and it was
    learned on the robot model the tests walk (regenerate it with
    tests/data/make_learned_policy.py when the model changes)."""
    record = load_learned_policy()
    assert record["command"].startswith("mjxcpg learn --k-s 10 --seed 1 --engine native")
    assert record["model_sha256"] == model_fingerprint(QRIO.mjcf_resource().read_text()), (
        f"tests/data policy was learned at {record['git_commit']} on another model")
    assert record["trials_to_success"] is not None and record["trials_to_success"] > 0
    assert len(record["policy_mean_weights"]) == record["basis_grid"] ** 2
    assert np.all(np.isfinite(record["policy_mean_weights"]))


def test_checkpoint_round_trip_keeps_empty_leaves(tmp_path):
    """MJX's state holds empty arrays (``act`` and others of this model); orbax cannot save
    them, so a checkpoint leaves them out and a restore takes them from its template."""
    spec = load_spec("quick")
    physics = {"empty": np.zeros((spec.batch, 0), np.float32), "qpos": np.arange(6.0).reshape(spec.batch, 2)}
    state = RunState(physics=physics, learners=Periods(period=np.arange(spec.batch)))
    manager = checkpoints.manager_of(tmp_path, writer=True)
    manager.save(1, args=ocp.args.StandardSave(checkpoints.checkpoint_leaves(state, spec)))
    manager.wait_until_finished()
    restored, notices = checkpoints.restore_learners(tmp_path, jax.tree.map(np.zeros_like, state), spec)
    assert restored.physics["empty"].shape == (spec.batch, 0) and notices == []
    np.testing.assert_array_equal(restored.physics["qpos"], physics["qpos"])


class Periods(NamedTuple):
    """The one field of a learner's state that reading checkpoints looks at."""

    period: np.ndarray


@pytest.fixture(scope="module")
def quick_mjx_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("quick_mjx") / "run"
    assert main(["sweep", "--config", "quick", "--out", str(out), "--quiet", "--engine", "mjx"]) == 0
    return out


@pytest.mark.slow
def test_mjx_runs_the_quick_sweep(quick_mjx_run):
    """The MJX path runs the `quick` config end to end on the CPU (two large MJX compiles, the
    learning chunk and the report's walk), and its bookkeeping adds up: one
    learner per (k_s, seed) of the config, trial counts within the budget, success only after
    ``success_streak`` successive trials without a fall, Table 1 totals matching summary.json.
    Outcomes are not compared with the C engines' run of `quick`: the physics differ."""
    spec = load_spec("quick")
    out = quick_mjx_run
    assert json.loads((out / "config.json").read_text())["engine"] == "mjx"
    summary = json.loads((out / "summary.json").read_text())
    returns = json.loads((out / "returns.json").read_text())
    assert summary["engine"] == "mjx"
    assert [(r["k_s"], r["seed"]) for r in summary["learners"]] == list(zip(spec.k_s, spec.seeds))
    streak, budget = spec.trial.success_streak, spec.trial.max_trials
    for learner, history in zip(summary["learners"], returns, strict=True):
        assert 1 <= learner["trials"] <= budget
        assert len(history["returns"]) == len(history["falls"]) == learner["trials"]
        assert np.all(np.isfinite(history["returns"]))
        if learner["succeeded"]:
            assert learner["trials_to_success"] == learner["trials"] >= streak
            assert not any(history["falls"][-streak:])
        else:
            assert learner["trials_to_success"] is None and learner["trials"] == budget
        assert np.isfinite(learner["mean_vx"])
    succeeded = sum(r["succeeded"] for r in summary["learners"])
    assert f"| all | {spec.batch} | {succeeded} |" in (out / "table1.md").read_text()
    assert list(out.glob("policy_map_*.png")) and list(out.glob("learning_curve_*.png"))


def test_mjx_slices_on_the_cpu_step_like_one_vmap(monkeypatch):
    """Above ``_CPU_SLICE`` robots MJX steps the batch in slices (a jaxlib deadlock, see
    ``MjxEngine._map``); sliced and whole, every robot steps alike, padding included."""
    sim = make_simulation("mjx")
    batch = 5
    start = sim.engine.init(sim.qpos0, batch)
    start = start._replace(data=start.data.replace(qvel=start.data.qvel.at[:, 0].set(jnp.linspace(-0.2, 0.2, batch))))
    ctrl = jnp.tile(joint_targets(sim.params, sim.layout, jnp.zeros(6)), (batch, 1))  # standing targets
    whole = jax.jit(lambda s, u: sim.engine.step(s, u))(start, ctrl)
    monkeypatch.setattr(engines, "_CPU_SLICE", 2)
    step_in_slices = lambda s, u: sim.engine.step(s, u)  # a new function: traced afresh
    top_level = jax.make_jaxpr(step_in_slices)(start, ctrl).jaxpr.eqns
    assert any(e.primitive.name == "scan" and e.params["length"] == 3 for e in top_level)  # 5 robots, 2 + 2 + 2
    sliced = jax.jit(step_in_slices)(start, ctrl)
    np.testing.assert_allclose(sliced.data.qpos, whole.data.qpos, atol=1e-5)
    np.testing.assert_allclose(sliced.data.qvel, whole.data.qvel, atol=1e-3)
    np.testing.assert_allclose(sliced.positive_work, whole.positive_work, rtol=1e-3)


@pytest.mark.parametrize("threaded", [False, True], ids=["one thread", "the threads"])
def test_native_step_inside_xla_equals_its_host_callback_bit_for_bit(threaded):
    """The FFI handler makes the host callback's MuJoCo calls: 100 control periods of a batch,
    with robots idle (kept as they were) and robots thrown so hard that MuJoCo diverges (NaN),
    give identical arrays on both paths: five robots on one thread, and a batch split unevenly
    over 3 threads (one more robot than they start at), an idle and a diverging robot in its
    first block and in its last."""
    if native_step.step_handler() is None:
        pytest.skip("no C++ compiler: the native engine has only its host callback here")
    sim = make_simulation("native")
    engine = engines.NativeEngine(sim.model, sim.engine.substeps, threads=3)
    batch = engines._ROBOTS_PER_THREAD * engine.threads + 1 if threaded else 5
    assert engine.threads_for(batch) == (3 if threaded else 1)
    start = engine.init(sim.qpos0, batch)
    nq = sim.model.nq
    # robots 1 and the last: a huge vertical speed; robots 2 and the one before the last: idle
    start = start._replace(physics=start.physics.at[jnp.array([1, batch - 1]), 1 + nq + 2].set(1e12))
    standing = joint_targets(sim.params, sim.layout, jnp.zeros(6))
    ctrls = standing + 0.2 * jnp.sin(jnp.arange(100.0)[:, None, None] / 7 + jnp.arange(float(batch))[None, :, None])
    active = jnp.ones(batch, bool).at[jnp.array([2, batch - 2])].set(False)

    def rollout(step):
        return jax.jit(lambda s, us: jax.lax.scan(lambda x, u: (step(x, u, active), x.physics), s, us))(start, ctrls)

    in_xla = rollout(engine.step)
    callback = rollout(lambda s, u, a: engines._CEngine.step(engine, s, u, a))
    for a, b in zip(jax.tree.leaves(in_xla), jax.tree.leaves(callback)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    final, _ = in_xla
    diverged, idle = [1, batch - 1], [2, batch - 2]
    assert np.isnan(np.asarray(final.physics[jnp.array(diverged)])).all()
    others = np.setdiff1d(np.arange(batch), diverged + idle)
    assert np.isfinite(np.asarray(final.physics[others])).all()
    np.testing.assert_array_equal(np.asarray(final.physics[jnp.array(idle)]), np.asarray(start.physics[jnp.array(idle)]))


def test_native_step_threads_added_after_use_wait_for_the_next_call():
    """The handler's pool grows when an engine with more threads steps after one with fewer:
    engines of 2, 3 and again 2 threads in turn, each batch split over its threads, each
    equal bit for bit to the host callback (a worker that joined late and ran a stale call
    would change or lose rows)."""
    if native_step.step_handler() is None:
        pytest.skip("no C++ compiler: the native engine has only its host callback here")
    sim = make_simulation("native")
    standing = joint_targets(sim.params, sim.layout, jnp.zeros(6))
    for threads in (2, 3, 2):
        engine = engines.NativeEngine(sim.model, sim.engine.substeps, threads=threads)
        batch = engines._ROBOTS_PER_THREAD * threads + 1
        start = engine.init(sim.qpos0, batch)
        ctrls = standing + 0.1 * jnp.sin(jnp.arange(30.0)[:, None, None] / 5 + jnp.arange(float(batch))[None, :, None])

        def rollout(step):
            return jax.jit(lambda s, us: jax.lax.scan(lambda x, u: (step(x, u), None), s, us)[0])(start, ctrls)

        in_xla, callback = rollout(engine.step), rollout(lambda s, u: engines._CEngine.step(engine, s, u))
        for a, b in zip(jax.tree.leaves(in_xla), jax.tree.leaves(callback)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_native_threads_follow_the_cpus_the_process_may_use(monkeypatch):
    """One thread per CPU of the process's affinity (as ``taskset`` or Slurm restricts it),
    not per core of the machine; ``MJXCPG_NATIVE_THREADS`` overrides it, and a bad value
    is refused."""
    monkeypatch.delenv("MJXCPG_NATIVE_THREADS", raising=False)
    one_cpu = min(os.sched_getaffinity(0))
    code = ("import os; os.sched_setaffinity(0, {%d}); "
            "from mjxcpg.physics.engines import native_threads; print(native_threads())" % one_cpu)
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip() == "1"
    monkeypatch.setenv("MJXCPG_NATIVE_THREADS", "5")
    assert engines.native_threads() == 5
    monkeypatch.setenv("MJXCPG_NATIVE_THREADS", "many")
    with pytest.raises(ValueError, match="MJXCPG_NATIVE_THREADS"):
        engines.native_threads()
