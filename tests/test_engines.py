"""MJX, the batched engine, against MuJoCo C, the scalar reference (issue 4, deliverable 5).

Measured figures and the reasons for every tolerance are in ``docs/engines.md``.  In short:
MJX runs in float32 and MuJoCo C in float64, with the same Newton solver (2 iterations, 4
line-search iterations) from the same warm start, so where both see the same contacts one
step agrees to float32 rounding (in 97% of such states; the rest take another branch of the
unconverged solver).  Where they do not, the two engines *model* contact
differently: MJX's plane-box collision keeps only the sole corners within a 1 mm skin of
the deepest one, MuJoCo C keeps every penetrating corner, so a tilted sole (heel strike,
toe-off) carries its load on fewer points in MJX.  That is a difference of physics, not of
arithmetic, and it is bounded here loosely, then judged where it matters: by the pelvis
trajectory of a short walk and by the walking speed of the same learned policy.
"""

from __future__ import annotations

import json
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import orbax.checkpoint as ocp
import pytest
from conftest import HAND, LEARNED, load_learned_policy

from mjxcpg import engines, runs, walk
from mjxcpg.cli import main
from mjxcpg.config import load_spec
from mjxcpg.controller import control_step, joint_targets, roll_rate_feedback
from mjxcpg.robot import Layout, observe
from mjxcpg.sim import make_simulation

SEED = 0
ONE_STEP_STATES = 64
WALK_SECONDS_FOR_STATES = 5.0   # states are sampled from this C walk, after its first second
SOLE_GEOMS = ("l_sole", "r_sole")

# One physics step (4 ms) from the same state; figures measured on the test's 64 states and on
# 256 of the same kind (docs/engines.md).  Where both engines find the same penetrating sole
# corners, most states agree to float32 arithmetic (measured maxima over 64 / 256 states: qpos
# 4.1e-7 / 1.2e-7, velocity-change error 3.8e-5 / 1.1e-5, sole force 6.5e-5 / 2.5e-5 m g, gyro
# and orientation 6e-7 / 7e-7); a few (0 of 45 / 6 of 176) take another branch of the
# 2-iteration solver.
TIGHT_QPOS_ATOL = 2e-6            # m or rad; a step moves qpos by |qvel| dt = 1e-3 to 1.5e-2
TIGHT_VELOCITY_CHANGE_REL = 2e-4  # of |qvel_c - qvel_start| = 3 to 8 (rad or m)/s
TIGHT_TOUCH_REL = 5e-4            # of the robot's weight m g = 66 N (sole forces reach 190 N)
SENSOR_READ_ATOL = 5e-6           # gyro (rad/s) and orientation quaternion: read before the step
MIN_TIGHT_FRACTION = 0.9          # of the same-contact states; measured 1.0 / 0.97
SAME_CONTACTS_VELOCITY_CHANGE_REL = 0.1   # measured at most 0.051
SAME_CONTACTS_TOUCH_REL = 0.05            # measured at most 0.022 m g
SAME_CONTACTS_QPOS_ATOL = 1e-3            # measured at most 5e-4
# Where MJX's contact set differs from C's (31% of the states; see the module docstring).
OTHER_CONTACTS_VELOCITY_CHANGE_REL = 1.0  # measured at most 0.52 / 0.74, median 0.27 / 0.18
OTHER_CONTACTS_QPOS_ATOL = 0.03           # measured at most 0.006 / 0.013
MIN_SAME_CONTACT_FRACTION = 0.4           # states on the floor with the same contacts; measured 0.6

# The hand-designed walk from standing (measured maxima: first 1 s, height 1.2 mm, forward
# position 4.4 mm; first 2 s, 4.7 mm and 16 mm, of 0.145 m walked).
ROLLOUT_SECONDS = 2.0
FIRST_SECOND_HEIGHT_ATOL = 0.003   # m; pelvis at 0.283 m, swinging 15 mm within a step
FIRST_SECOND_FORWARD_ATOL = 0.01   # m; 0.05 m walked
ROLLOUT_HEIGHT_ATOL = 0.01         # m
ROLLOUT_HEIGHT_RMS = 0.0025        # m; measured 0.9 mm
ROLLOUT_FORWARD_ATOL = 0.03        # m; 20% of the distance walked
# The learned policy's mean speed over 18 s (measured: C 0.062 m/s, MJX 0.053 m/s, 15% apart;
# C's own spread over 16 starts perturbed by 1e-4 rad is +-2%).
WALKING_SPEED_REL = 0.10           # the criterion
LEARNED_SPEED_REL_MEASURED_BOUND = 0.25


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

    qpos, qvel, ctrl = jax.device_get(run(engine.init(sim.qpos0, 1), walk.initial_cpg(1)))
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


def c_physics_state(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """The C engines' state rows (mjSTATE_FULLPHYSICS) for robots at ``qpos``, ``qvel``."""
    data = mujoco.MjData(model)
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    rows = np.empty((len(qpos), size))
    for b in range(len(qpos)):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = qpos[b], qvel[b]
        mujoco.mj_getState(model, data, rows[b], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return rows


def step_c(model: mujoco.MjModel, states: StartStates) -> EngineOutput:
    """One physics step of the scalar engine (``MujocoEngine``, zero warm start)."""
    engine = engines.MujocoEngine(model, substeps=1)
    physics = jnp.asarray(c_physics_state(model, states.qpos, states.qvel), jnp.float32)
    start = engines.CState(physics=physics, sensordata=jnp.zeros((len(physics), model.nsensordata)))
    stepped = engine.step(start, jnp.asarray(states.ctrl, jnp.float32))
    sensors = jax.device_get(engine.sensors(stepped))
    return EngineOutput(*(np.asarray(x, np.float64) for x in sensors))


def step_mjx(model: mujoco.MjModel, qpos0: np.ndarray, states: StartStates) -> tuple[EngineOutput, np.ndarray]:
    """One physics step of ``MjxEngine`` from a zero warm start, as the C engines start, and
    the number of penetrating contacts per sole (states, soles) MJX found at the start."""
    engine = engines.MjxEngine(model, substeps=1)
    batch = len(states.qpos)
    # mjx.make_data, not engine.init: its mjx.forward would be one more slow compile, and
    # the step computes everything from qpos, qvel and ctrl anyway.
    blank = engine._mjx.make_data(model, impl="jax")
    start = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), blank)
    start = start.replace(qpos=jnp.asarray(states.qpos, jnp.float32),
                          qvel=jnp.asarray(states.qvel, jnp.float32),
                          qacc_warmstart=jnp.zeros((batch, model.nv), jnp.float32))
    stepped = jax.jit(engine.step)(start, jnp.asarray(states.ctrl, jnp.float32))
    contact = stepped._impl.contact  # MJX's contacts of this step (at the starting state)
    geom, dist = np.asarray(contact.geom), np.asarray(contact.dist)
    counts = np.stack([((geom[..., 1] == sole) & (dist < 0)).sum(axis=-1) for sole in sole_ids(model)], axis=-1)
    sensors = jax.device_get(engine.sensors(stepped))
    return EngineOutput(*(np.asarray(x, np.float64) for x in sensors)), counts


def sole_ids(model: mujoco.MjModel) -> list[int]:
    return [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name) for name in SOLE_GEOMS]


def c_contact_counts(model: mujoco.MjModel, states: StartStates) -> np.ndarray:
    """Penetrating contacts per sole (states, soles) that MuJoCo C finds at each state."""
    data = mujoco.MjData(model)
    soles = sole_ids(model)
    counts = np.zeros((len(states.qpos), len(soles)), int)
    for b in range(len(states.qpos)):
        data.qpos[:], data.qvel[:] = states.qpos[b], states.qvel[b]
        mujoco.mj_forward(model, data)
        for k in range(data.ncon):
            contact = data.contact[k]
            if contact.dist < 0 and contact.geom[1] in soles:
                counts[b, soles.index(contact.geom[1])] += 1
    return counts


class OneStepComparison(NamedTuple):
    states: StartStates
    c: EngineOutput
    mjx: EngineOutput
    same_contacts: np.ndarray   # (states,) bool: MJX and C found the same contacts per sole
    in_contact: np.ndarray      # (states,) bool: some sole touches the floor


@pytest.fixture(scope="module")
def one_step(mujoco_sim) -> OneStepComparison:
    model = mujoco_sim.model
    states = perturbed_walking_states(mujoco_sim, ONE_STEP_STATES, SEED)
    c = step_c(model, states)
    mjx, mjx_counts = step_mjx(model, mujoco_sim.qpos0, states)
    c_counts = c_contact_counts(model, states)
    return OneStepComparison(states, c, mjx, same_contacts=np.all(mjx_counts == c_counts, axis=1),
                             in_contact=c_counts.sum(axis=1) > 0)


def velocity_change_error(comparison: OneStepComparison) -> np.ndarray:
    """Per state: |qvel_mjx - qvel_c| / |qvel_c - qvel_start|, the error relative to the
    velocity change of the step, i.e. to the step's acceleration (norms over all dofs)."""
    change = np.linalg.norm(comparison.c.qvel - comparison.states.qvel, axis=1)
    return np.linalg.norm(comparison.mjx.qvel - comparison.c.qvel, axis=1) / change


def touch_error(comparison: OneStepComparison, layout: Layout) -> np.ndarray:
    """Per state: the largest sole-force difference, in units of the robot's weight."""
    touch = [layout.left_touch, layout.right_touch]
    difference = comparison.mjx.sensordata[:, touch] - comparison.c.sensordata[:, touch]
    return np.abs(difference).max(axis=1) / layout.weight


def read_sensor_error(comparison: OneStepComparison, layout: Layout) -> np.ndarray:
    """Per state: the largest difference of the gyro and orientation readings."""
    read = list(range(layout.gyro, layout.gyro + 3)) + list(range(layout.quat, layout.quat + 4))
    return np.abs(comparison.mjx.sensordata[:, read] - comparison.c.sensordata[:, read]).max(axis=1)


def test_sampled_states_cover_walking_contacts(one_step):
    """The sample is of walking: most states have a sole on the floor, enough of them with the
    same contacts in both engines for the tight comparison to mean something, and some where
    MJX's contact approximation is exercised."""
    assert one_step.in_contact.mean() > 0.8
    assert (one_step.same_contacts & one_step.in_contact).mean() >= MIN_SAME_CONTACT_FRACTION
    assert (~one_step.same_contacts).any()


def test_one_step_agrees_where_contacts_agree(one_step, mujoco_sim):
    """One 4 ms physics step from 64 perturbed walking states, MJX (float32) vs MuJoCo C
    (float64), both from a zero solver warm start, on the states where both find the same
    penetrating sole corners.

    At least 90% of these states (measured: all 45 here, 97% of 176 in a sample of 256)
    agree to float32 arithmetic: qpos within 2e-6 (a step moves it by 1e-3 to 1.5e-2), the
    velocity change of the step within 2e-4 of its size (3 to 8 in norm; this is the error of
    the acceleration, contact forces included), the sole forces within 5e-4 of the weight
    m g = 66 N.  Measured maxima here: 4.1e-7, 3.8e-5, 6.5e-5 (5 to 8 times smaller).  The
    rest take another branch of the unconverged 2-iteration Newton solver (its warm-start
    choice or line search) and still agree within 10% of the velocity change (measured at most
    5.1% in the sample of 256), 0.05 m g (0.022) and 1e-3 in qpos (5e-4).  Gyro and
    orientation are read at the start of the step: 5e-6 (measured 7e-7).
    """
    same = one_step.same_contacts
    c, x = one_step.c, one_step.mjx
    velocity = velocity_change_error(one_step)[same]
    touch = touch_error(one_step, mujoco_sim.layout)[same]
    qpos = np.abs(x.qpos - c.qpos).max(axis=1)[same]
    tight = (velocity <= TIGHT_VELOCITY_CHANGE_REL) & (touch <= TIGHT_TOUCH_REL) & (qpos <= TIGHT_QPOS_ATOL)
    assert tight.mean() >= MIN_TIGHT_FRACTION, f"{tight.sum()} of {tight.size} states agree to float32 rounding"
    assert velocity.max() <= SAME_CONTACTS_VELOCITY_CHANGE_REL
    assert touch.max() <= SAME_CONTACTS_TOUCH_REL
    assert qpos.max() <= SAME_CONTACTS_QPOS_ATOL
    assert read_sensor_error(one_step, mujoco_sim.layout).max() <= SENSOR_READ_ATOL


def test_one_step_is_close_where_mjx_drops_contact_points(one_step):
    """Where MJX keeps fewer sole corners than C (its 1 mm contact skin), the step differs in
    physics, not in rounding: the velocity change differs by less than its own size
    (measured at most 52% here, 74% over 256 states) and qpos by less than 0.03 (measured
    0.006, 0.013: a velocity error of 3 rad/s for 4 ms).  The sole forces may move by 3 m g from one
    corner to another and are not compared here; the rollout and the walks judge the effect."""
    other = ~one_step.same_contacts
    assert velocity_change_error(one_step)[other].max() < OTHER_CONTACTS_VELOCITY_CHANGE_REL
    np.testing.assert_allclose(one_step.mjx.qpos[other], one_step.c.qpos[other], rtol=0,
                               atol=OTHER_CONTACTS_QPOS_ATOL)


def test_short_rollout_agrees_in_pelvis_height_and_forward_position(session_walk_mujoco, session_walk_mjx,
                                                                    mujoco_sim):
    """The hand-designed controller (a_5 = d theta_roll/dt) from standing on both engines:
    the first 2 s of the session's 20 s walks.  The pelvis stands at 0.283 m and swings about
    15 mm within each step; the robot walks 0.145 m in 2 s.

    * First second: height within 3 mm, forward position within 10 mm (measured 1.2, 4.4 mm).
    * First 2 s: height within 10 mm, RMS 2.5 mm, forward position within 30 mm (measured 4.7
      mm, 0.9 mm, 16 mm).  The trajectories part slowly as MJX's contact approximation shifts
      a heel strike by a few control periods; over 20 s the speeds differ by 6% (test_walk.py).
    """
    c, x = session_walk_mujoco.trace, session_walk_mjx.trace
    first = round(1.0 / mujoco_sim.control_dt)
    steps = round(ROLLOUT_SECONDS / mujoco_sim.control_dt)
    assert not c.fallen[HAND, :steps].any() and not x.fallen[HAND, :steps].any()
    height = x.height[HAND, :steps] - c.height[HAND, :steps]
    forward = x.forward_position[HAND, :steps] - c.forward_position[HAND, :steps]
    assert np.abs(height[:first]).max() <= FIRST_SECOND_HEIGHT_ATOL
    assert np.abs(forward[:first]).max() <= FIRST_SECOND_FORWARD_ATOL
    assert np.abs(height).max() <= ROLLOUT_HEIGHT_ATOL
    assert np.sqrt(np.mean(height**2)) <= ROLLOUT_HEIGHT_RMS
    assert np.abs(forward).max() <= ROLLOUT_FORWARD_ATOL


def test_learned_policy_walks_on_both_engines(walks_mujoco, walks_mjx):
    """The policy stored in tests/data (learned on the native C engine) walks 20 s without a
    fall on both engines, forward, at mean speeds (after 2 s of settling) within 25% of each
    other: measured C 0.062 m/s, MJX 0.053 m/s.  The issue's 10% is the next test."""
    c, x = walks_mujoco[LEARNED], walks_mjx[LEARNED]
    assert not c.fell and not x.fell
    assert c.mean_vx > 0.03 and x.mean_vx > 0.03
    assert abs(x.mean_vx - c.mean_vx) / c.mean_vx < LEARNED_SPEED_REL_MEASURED_BOUND


@pytest.mark.xfail(strict=True, reason="measured: MJX walks the stored learned policy 15% slower than C "
                   "(0.053 vs 0.062 m/s); C's own spread is +-2%, so this is MJX's contact model "
                   "(docs/engines.md)")
def test_learned_policy_speed_within_ten_percent(walks_mujoco, walks_mjx):
    """Issue 4's criterion: the same learned policy walks at speeds within 10% on both engines.
    The hand-designed controller meets it (6%, test_walk.py); this policy, with its weaker
    propulsive feedback, does not: strict, so that a fix shows up as an unexpected pass."""
    c, x = walks_mujoco[LEARNED], walks_mjx[LEARNED]
    assert abs(x.mean_vx - c.mean_vx) / c.mean_vx < WALKING_SPEED_REL


def test_stored_policy_record_is_consistent():
    """The stored policy says how it was made, and it succeeded."""
    record = load_learned_policy()
    assert record["command"].startswith("mjxcpg learn --k-s 10 --seed 1 --engine native")
    assert record["trials_to_success"] is not None and record["trials_to_success"] > 0
    assert len(record["policy_mean_weights"]) == record["basis_grid"] ** 2
    assert np.all(np.isfinite(record["policy_mean_weights"]))


def test_checkpoint_round_trip_keeps_empty_leaves(tmp_path):
    """MJX's state holds empty arrays (``act`` and others of this model); orbax cannot save
    them, so a checkpoint leaves them out and a restore takes them from its template."""
    spec = load_spec("quick")
    state = {"empty": np.zeros((spec.batch, 0), np.float32), "qpos": np.arange(6.0).reshape(spec.batch, 2)}
    manager = runs._manager(tmp_path)
    manager.save(1, args=ocp.args.StandardSave(runs._leaves(state, spec)))
    manager.wait_until_finished()
    restored = runs.restore_state(manager, jax.tree.map(np.zeros_like, state), spec)
    assert restored["empty"].shape == (spec.batch, 0)
    np.testing.assert_array_equal(restored["qpos"], state["qpos"])


@pytest.fixture(scope="module")
def quick_mjx_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("quick_mjx") / "run"
    assert main(["sweep", "--config", "quick", "--out", str(out), "--quiet", "--engine", "mjx"]) == 0
    return out


@pytest.mark.slow
def test_mjx_runs_the_quick_sweep(quick_mjx_run):
    """The MJX path runs the `quick` config end to end on the CPU (minutes: two large MJX
    compiles, the learning chunk and the report's walk), and its bookkeeping adds up: one
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
    start = start.replace(qvel=start.qvel.at[:, 0].set(jnp.linspace(-0.2, 0.2, batch)))
    ctrl = jnp.tile(joint_targets(sim.params, sim.layout, jnp.zeros(6)), (batch, 1))  # standing targets
    whole = jax.jit(lambda s, u: sim.engine.step(s, u))(start, ctrl)
    monkeypatch.setattr(engines, "_CPU_SLICE", 2)
    step_in_slices = lambda s, u: sim.engine.step(s, u)  # a new function: traced afresh
    top_level = jax.make_jaxpr(step_in_slices)(start, ctrl).jaxpr.eqns
    assert any(e.primitive.name == "scan" and e.params["length"] == 3 for e in top_level)  # 5 robots, 2 + 2 + 2
    sliced = jax.jit(step_in_slices)(start, ctrl)
    np.testing.assert_allclose(sliced.qpos, whole.qpos, atol=1e-5)
    np.testing.assert_allclose(sliced.qvel, whole.qvel, atol=1e-3)
