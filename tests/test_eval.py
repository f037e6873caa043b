"""``mjxcpg eval``: the evaluation protocols, the pelvis push of the engines, the report and
its one-line errors.  Small budgets throughout; the paper's budgets run in ``make test-slow``."""

import dataclasses
import json
import shutil

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from learned_run import make_learned_run

from mjxcpg.cli import main
from mjxcpg.control.sim import make_simulation
from mjxcpg.evaluation import evaluate
from mjxcpg.evaluation import protocol as eval_protocol
from mjxcpg.training import runs, train

SMALL = ["--fixed-point-steps", "4", "--perturbations", "4", "--slope-seconds", "3",
         "--max-slope-deg", "1", "--push-rounds", "1"]


@pytest.fixture(scope="module")
def learned_run(tmp_path_factory):
    """One learner whose policy (tests/data) walks, in a run directory."""
    return make_learned_run(tmp_path_factory.mktemp("eval") / "run")


@pytest.fixture(scope="module")
def evaluated(learned_run, tmp_path_factory):
    """``mjxcpg eval`` of that run with small budgets, written to a separate directory."""
    out = tmp_path_factory.mktemp("eval_out")
    assert main(["eval", "--run", str(learned_run), "--engine", "native", "--out", str(out),
                 "--quiet", "--json"] + SMALL) == 0
    return out


def test_eval_writes_json_plots_and_report(evaluated):
    result = json.loads((evaluated / "eval" / "evaluation.json").read_text())
    learner = result["learners"][0]
    rm = learner["return_map"]
    assert learner["succeeded"] and not rm["fell"]
    assert rm["mean_vx"] > 0.02 and 0.5 < rm["gait_cycle_s"] < 1.5
    assert rm["fixed_point_steps"] == 4 and rm["perturbations"] == 4
    assert rm["fixed_point"] > 0, "the left foot lands ahead of the right while walking forward"
    assert abs(rm["eigenvalue"]) < 1, "a walking learned policy is locally stable"
    assert learner["slopes"]["uphill_deg"] is not None and learner["slopes"]["downhill_deg"] <= 0
    assert set(learner["pushes"]) == set(eval_protocol.PUSH_DIRECTIONS)
    report = (evaluated / "report.md").read_text()
    for figure in ("-0.0101", "+3", "-4", "0.077", "## Table 1", "## Pushes"):
        assert figure in report
    for line in report.splitlines():
        if line.startswith("!["):
            assert (evaluated / line[line.index("(") + 1:-1]).is_file(), line


def test_return_map_is_deterministic_and_robots_do_not_interact(learned_run):
    """Two copies of the same learner under the same key in one batch: identical figures,
    and identical again on a second evaluation."""
    _, sim, task, state = runs.load_run(learned_run, "native")
    params = eval_protocol.EvalParams(fixed_point_steps=3, perturbations=3)
    weights = jax.tree.map(lambda w: jnp.concatenate([w, w]), state.learners.weights)
    first = evaluate.evaluate_return_map(sim, task, weights, [0, 0], params)
    again = evaluate.evaluate_return_map(sim, task, weights, [0, 0], params)
    assert first[0] == first[1] == again[0]
    assert first[0]["perturbations"] == 3 and len(set(first[0]["offsets"])) == 3


def test_a_control_run_is_evaluated_with_its_own_feedback(learned_run):
    """A run of the a_5 = 0 control (``trial.actor = "zero"``) is evaluated with a_5 = 0
    whatever its weights: as the policy whose mean weights are all 0, since its a_5 is
    a_max g(0) = 0 (g odd), and not as the learned policy its weights hold."""
    spec, sim, task, state = runs.load_run(learned_run, "native")
    params = eval_protocol.EvalParams(fixed_point_steps=3, perturbations=3)
    control_task = train.make_task(sim, dataclasses.replace(
        spec, trial=dataclasses.replace(spec.trial, actor="zero")))
    weights = state.learners.weights
    zero_mean = weights._replace(mean=jnp.zeros_like(weights.mean))
    control = evaluate.evaluate_return_map(sim, control_task, weights, [0], params)
    assert control == evaluate.evaluate_return_map(sim, task, zero_mean, [0], params)
    assert control[0]["mean_vx"] != evaluate.evaluate_return_map(sim, task, weights, [0], params)[0]["mean_vx"]


def test_pelvis_force_native_equals_scalar_and_pushes_the_right_way():
    forces = jnp.array([[30.0, 0, 0], [0, 30.0, 0], [0, 0, 0]])
    ends = []
    for engine in ("mujoco", "native"):
        sim = make_simulation(engine)
        ctrl = jnp.tile(jnp.asarray(sim.layout.ctrl_home, jnp.float32), (3, 1))
        step = jax.jit(lambda s, engine=sim.engine, ctrl=ctrl: engine.step(s, ctrl, pelvis_force=forces))
        state = sim.engine.init(sim.qpos0, 3)
        for _ in range(10):
            state = step(state)
        plain = sim.engine.step(state, ctrl)  # no force: the pushes must not linger
        ends.append(jax.device_get((state, plain)))
    chex.assert_trees_all_equal(ends[0], ends[1])
    sensors = make_simulation("mujoco").engine.sensors(ends[0][0])
    qvel = np.asarray(sensors.qvel)
    assert qvel[0, 0] > qvel[2, 0] + 0.05 and qvel[1, 1] > qvel[2, 1] + 0.05


@pytest.mark.slow
def test_pelvis_force_on_mjx_pushes_the_right_way():
    sim = make_simulation("mjx")
    ctrl = jnp.tile(jnp.asarray(sim.layout.ctrl_home, jnp.float32), (2, 1))
    step = jax.jit(lambda s, f: sim.engine.step(s, ctrl, pelvis_force=f))
    state = sim.engine.init(sim.qpos0, 2)
    for _ in range(10):
        state = step(state, jnp.array([[30.0, 0, 0], [0, 0, 0]]))
    assert float(state.qvel[0, 0]) > float(state.qvel[1, 0]) + 0.05
    assert float(jnp.abs(state.xfrc_applied).max()) == 0.0


def test_return_map_protocol_phases():
    """Baseline touchdowns, then perturbation onset, x_n at the next touchdown, x_{n+1} at
    the one after, then done; the offset is applied exactly while perturbing."""
    sim = make_simulation("mujoco")
    params = eval_protocol.EvalParams(fixed_point_steps=2, perturbations=1, settle_seconds=0.0,
                                 recovery_seconds=0.008, onset_jitter_seconds=0.008)
    protocol = eval_protocol.make_protocol("return_map", params, sim.layout, sim.control_dt)
    probe = eval_protocol.init_probe(protocol, jax.random.PRNGKey(0), jnp.zeros(3))
    advance = jax.jit(lambda p, t, td, i: eval_protocol.advance_probe(protocol, p, t, td, i))
    drive = jax.jit(lambda p, t: eval_protocol.probe_drive(protocol, p, t)[0])
    touchdowns = {5: 0, 10: 1, 15: 2, 20: 3, 25: 4}   # control period -> touchdown index
    offsets, phases = [], []
    for t in range(30):
        probe = advance(probe, jnp.int32(t), jnp.bool_(t in touchdowns), jnp.int32(touchdowns.get(t, -1)))
        offsets.append(float(drive(probe, jnp.int32(t))))
        phases.append(int(probe.phase))
    assert phases[15] == eval_protocol.WAITING and phases[16] == eval_protocol.PERTURBING
    assert phases[20] == eval_protocol.AFTER and phases[25] == eval_protocol.DONE
    assert int(probe.perturbed_touchdown[0]) == 3
    applied = [t for t, o in enumerate(offsets) if o != 0]
    assert applied == list(range(16, 20)) and offsets[16] == float(probe.offsets[0])


def test_tilted_floor_reaches_the_c_engines():
    """The floor's normal leans back (toward -x) on an uphill slope, in MuJoCo C's own frames."""
    import math

    import mujoco

    from mjxcpg.physics.model import load_model

    model = load_model(5.0)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    normal = data.geom_xmat[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(normal, [-math.sin(math.radians(5.0)), 0.0, math.cos(math.radians(5.0))], atol=1e-6)


@pytest.mark.parametrize("slope_deg", [4.0, -4.0])
def test_standing_pose_on_a_slope_rests_every_sole_corner_on_the_floor(slope_deg):
    """Set down on an incline, the robot stands tilted with the floor: its eight sole corners
    (3 mm spheres) all 1 mm above the floor plane along its normal, as on level ground."""
    import math

    import mujoco

    from mjxcpg.physics.model import load_model

    level, tilted = make_simulation("mujoco"), make_simulation("mujoco", slope_deg=slope_deg)
    model = load_model(slope_deg)
    data = mujoco.MjData(model)
    data.qpos[:] = tilted.qpos0
    mujoco.mj_kinematics(model, data)
    slope = math.radians(slope_deg)
    normal = np.array([-math.sin(slope), 0.0, math.cos(slope)])
    corners = [i for i in range(model.ngeom) if "sole_" in (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, i) or "")]
    assert len(corners) == 8
    clearance = [data.geom_xpos[i] @ normal - model.geom_size[i][0] for i in corners]
    np.testing.assert_allclose(clearance, 0.001, atol=1e-6)
    np.testing.assert_array_equal(tilted.qpos0[7:], level.qpos0[7:])  # the same joint angles


def test_heading_drift_unwraps_across_the_half_turn():
    """A heading that turns from +170 to -170 degrees (through 180) has drifted by +20, not -340."""
    headings = np.radians([170.0, 175.0, 180.0, -175.0, -170.0])
    log = evaluate.TouchdownLog(count=np.array([5]), step=np.arange(5)[None], length=np.zeros((1, 5)),
                                position=np.zeros((1, 5)), heading=headings[None], work=np.zeros((1, 5)))
    drift, largest = evaluate._heading_drift(log, 0, 0, 4)
    assert drift == pytest.approx(20.0) and largest == pytest.approx(20.0)
    assert evaluate._heading_drift(log, 0, 4, 4) == (None, None)  # fewer than one cycle


def test_cycles_cost_of_transport_is_work_over_weight_times_distance():
    """Touchdowns every 0.9 s, 0.06 m apart, with 4.5 J of positive work between them, for a
    robot of 66 N: over three cycles CoT = 4.5 / (66 x 0.06), speed 0.06 / 0.9."""
    dt, period = 0.008, round(0.9 / 0.008)
    n = np.arange(6)
    log = evaluate.TouchdownLog(count=np.array([6]), step=(n * period)[None], length=np.full((1, 6), 0.03),
                                position=(0.06 * n)[None], heading=np.zeros((1, 6)), work=(4.5 * n + 10.0)[None])
    cycles = evaluate._cycles(log, 0, 1, 3, dt, 66.0)
    assert cycles.cost_of_transport == pytest.approx(4.5 / (66.0 * 0.06))
    assert cycles.mean_vx == pytest.approx(0.06 / (period * dt))


def test_least_squares_slope_recovers_a_line():
    x = np.linspace(0.01, 0.05, 20)
    fit = evaluate.least_squares_slope(x, -0.3 * x + 0.04)
    assert fit["slope"] == pytest.approx(-0.3) and fit["intercept"] == pytest.approx(0.04)
    assert fit["slope_stderr"] == pytest.approx(0.0, abs=1e-9)
    assert evaluate.least_squares_slope(x[:2], x[:2])["slope"] is None


@pytest.mark.parametrize("case", ["missing", "no-checkpoint", "learner-out-of-range"])
def test_eval_errors_are_one_line(learned_run, tmp_path, case, capsys):
    run = tmp_path / "run"
    argv = ["eval", "--run", str(run), "--quiet"]
    if case == "no-checkpoint":
        shutil.copytree(learned_run, run)
        shutil.rmtree(run / "checkpoints")
    elif case == "learner-out-of-range":
        shutil.copytree(learned_run, run)
        argv += ["--learner", "0", "3"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg: error:") and "\n" not in err
    assert {"missing": "no run directory", "no-checkpoint": "no checkpoint",
            "learner-out-of-range": "out of range"}[case] in err
    assert not (run / "eval").exists()


def test_eval_replaces_an_earlier_evaluation_only_with_force(learned_run, tmp_path, capsys):
    """A second eval into the same OUT is refused, nothing touched; with --force it replaces
    the report and the earlier plots, which it might not draw again."""
    (tmp_path / "report.md").write_text("the earlier evaluation's report\n")
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "earlier_plot.png").write_bytes(b"earlier")
    argv = ["eval", "--run", str(learned_run), "--engine", "native", "--out", str(tmp_path), "--quiet",
            "--fixed-point-steps", "2", "--perturbations", "1", "--skip", "slopes", "pushes"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg: error:") and "\n" not in err and "--force" in err
    assert (tmp_path / "report.md").read_text() == "the earlier evaluation's report\n"
    assert (tmp_path / "eval" / "earlier_plot.png").read_bytes() == b"earlier"
    assert main(argv + ["--force"]) == 0
    assert (tmp_path / "report.md").read_text() != "the earlier evaluation's report\n"
    assert not (tmp_path / "eval" / "earlier_plot.png").exists()
    assert (tmp_path / "eval" / "evaluation.json").is_file()


def test_eval_out_that_is_a_file_is_one_line(learned_run, tmp_path, capsys):
    out = tmp_path / "results.txt"
    out.write_text("a user's file")
    assert main(["eval", "--run", str(learned_run), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mjxcpg: error: --out {out} is a file, not a directory"
    assert out.read_text() == "a user's file"


@pytest.mark.slow
def test_paper_budgets_on_the_learned_policy(learned_run, tmp_path):
    """The paper's counts (100 unperturbed steps, 50 perturbations, 20 s per slope)."""
    assert main(["eval", "--run", str(learned_run), "--engine", "native", "--out", str(tmp_path),
                 "--quiet"]) == 0
    rm = json.loads((tmp_path / "eval" / "evaluation.json").read_text())["learners"][0]["return_map"]
    assert rm["perturbations"] == 50 and rm["fixed_point_steps"] == 100 and abs(rm["eigenvalue"]) < 1


def test_hardware_evaluation_does_not_overwrite_the_nominal_one(learned_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(learned_run, run)
    (run / "report.md").write_text("the nominal robot's report\n")
    argv = ["eval", "--run", str(run), "--engine", "native", "--robot", "hardware", "--quiet",
            "--fixed-point-steps", "2", "--skip", "return_map", "slopes", "pushes", "transfer"]
    assert main(argv) == 0
    assert (run / "report.md").read_text() == "the nominal robot's report\n"
    assert "robot `hardware`" in (run / "hardware" / "report.md").read_text()
