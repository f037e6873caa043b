"""The lockstep batch: resume gives identical results, a diverged robot is a counted fall,
the C engines agree, checkpoints reload, bad input is refused."""

import json
import signal
import subprocess
import sys
import time

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import HAND
from test_monitoring import tensorboard_scalars

from mjxcpg.cli import main
from mjxcpg.control.sim import make_simulation
from mjxcpg.control import walk
from mjxcpg.report import learning as report
from mjxcpg.training import config, train


def test_sweep_writes_the_report(finished_quick, quick_spec):
    summary = json.loads((finished_quick / "summary.json").read_text())
    assert len(summary["learners"]) == quick_spec.batch
    for learner in summary["learners"]:
        assert {"k_s", "seed", "succeeded", "trials_to_success", "mean_vx"} <= set(learner)
    assert "| all |" in (finished_quick / "table1.md").read_text()
    assert list(finished_quick.glob("policy_map_*.png")) and list(finished_quick.glob("learning_curve_*.png"))
    assert not (finished_quick / "tensorboard").exists()  # --no-tensorboard


def test_sigkill_then_resume_matches_uninterrupted_run(finished_quick, tmp_path):
    """The killed run writes TensorBoard events, the uninterrupted one none: the same results
    show that the events change nothing, and the events hold each trial once."""
    out = tmp_path / "killed"
    # checkpoints (and the events' flushes) apart in time, as by default: the events of the
    # chunks after the first checkpoint wait in memory, which the kill loses
    cmd = [sys.executable, "-m", "mjxcpg", "sweep", "--config", "quick", "--out", str(out), "--quiet",
           "--engine", "native", "--checkpoint-every", "0.5"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if len([p for p in (out / "checkpoints").glob("[0-9]*") if p.is_dir()]) >= 1:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.05)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    subprocess.run(cmd + ["--resume"], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    expected = json.loads((finished_quick / "returns.json").read_text())
    assert json.loads((out / "returns.json").read_text()) == expected
    assert (json.loads((out / "summary.json").read_text())["learners"]
            == json.loads((finished_quick / "summary.json").read_text())["learners"])
    for k, learner in enumerate(expected):
        scalars = tensorboard_scalars(out / "tensorboard" / f"learner_{k:02d}_ks{learner['k_s']:g}_seed{learner['seed']}")
        assert scalars["trial/return"] == [(t + 1, r) for t, r in enumerate(learner["returns"])]
        assert [v for _, v in scalars["trial/fell"]] == [float(f) for f in learner["falls"]]


def test_existing_output_is_never_overwritten(finished_quick, capsys):
    before = (finished_quick / "returns.json").read_text()
    assert main(["sweep", "--config", "quick", "--out", str(finished_quick), "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err
    assert (finished_quick / "returns.json").read_text() == before


def test_walk_with_a_learned_policy(finished_quick, capsys):
    assert main(["walk", "--checkpoint", str(finished_quick), "--learner", "1", "--seconds", "2",
                 "--engine", "mujoco", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["controller"] == "learned" and result["seconds"] > 0


@pytest.mark.parametrize("damage", ["missing", "truncated", "other-config"])
def test_bad_checkpoint_is_one_line_error(finished_quick, tmp_path, damage, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished_quick, run)
    if damage == "missing":
        shutil.rmtree(run / "checkpoints")
    elif damage == "truncated":
        for f in (run / "checkpoints").rglob("*"):
            if f.is_file() and f.stat().st_size > 0:
                f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
    else:
        record = json.loads((run / "config.json").read_text())
        record["spec"]["k_s"] = [1.0, 2.0]
        record["spec"]["seeds"] = [0, 1]
        (run / "config.json").write_text(json.dumps(record))
    assert main(["walk", "--checkpoint", str(run), "--seconds", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg: error:") and "\n" not in err


def test_diverged_robot_is_a_counted_fall_and_others_are_untouched(quick_spec):
    sim = make_simulation("mujoco", params=quick_spec.controller)
    task = train.make_task(sim, quick_spec)
    chunk = train.make_chunk(sim, task, 50)
    initial = sim.engine.init(sim.qpos0, quick_spec.batch)
    clean = train.init_run(sim, task, quick_spec)
    poisoned = clean._replace(physics=clean.physics._replace(
        physics=clean.physics.physics.at[1, 1:4].set(jnp.nan)))
    a, b = chunk(clean, initial), chunk(poisoned, initial)
    assert int(b.learners.book.trial[1]) == 1 and bool(b.learners.book.falls[1, 0])
    assert int(a.learners.book.trial[1]) == 0
    for i in (0, 2):
        np.testing.assert_array_equal(a.physics.physics[i], b.physics.physics[i])
        chex.assert_trees_all_equal(jax.tree.map(lambda t: t[i], a.learners),
                                    jax.tree.map(lambda t: t[i], b.learners))


def test_native_batch_equals_scalar_engine(quick_spec):
    results = []
    for engine in ("mujoco", "native"):
        sim = make_simulation(engine, params=quick_spec.controller)
        task = train.make_task(sim, quick_spec)
        run = train.make_chunk(sim, task, 300)(train.init_run(sim, task, quick_spec),
                                               sim.engine.init(sim.qpos0, quick_spec.batch))
        results.append(jax.device_get(run))
    chex.assert_trees_all_equal(results[0], results[1])


@pytest.mark.parametrize("text, key", [
    ("k_s = [1.0]\nseeds = [0]\nbogus = 1\n", "bogus"),
    ("k_s = [1.0]\nseeds = [0]\n[trial]\nmax_trials = 'many'\n", "trial.max_trials"),
    ("k_s = [1.0]\nseeds = [0]\n[trial]\nmax_trials = 0\n", "trial.max_trials"),
    ("k_s = [1.0, 2.0]\nseeds = [0]\n", "seeds"),
])
def test_bad_config_names_the_key(tmp_path, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=key.replace(".", r"\.").replace("[", r"\[")):
        config.load_spec(str(path))


def test_controls_run_beside_table1(finished_quick, tmp_path, walks_mujoco, mujoco_sim):
    """`mjxcpg controls` runs the four controls in the run's protocol and writes them into the
    run's table1.md.  Their 20 s walks (the first 1.5 s hand-designed, as the quick config's
    trials start) are independent checks: the hand-feedback control walks the session's
    hand-designed gait, and the a_5 = 0 control the a_5 = 0 gait after the same start, walked
    here on the scalar engine (the same physics, another engine and batch: within 1%).  A
    control summary of an earlier version, which walked from standing, is named as such."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished_quick, run)
    assert main(["controls", "--run", str(run), "--trials", "4", "--quiet"]) == 0
    table = (run / "table1.md").read_text()
    for label in ("(a) learning off", "(b) learning off, sigma at its smallest", "(c) a_5 = 0",
                  "(d) hand-designed feedback"):
        assert f"| {label}" in table
    assert "whose first 1.5 s are the hand-designed feedback" in table and "Walked otherwise" not in table
    stats = json.loads((run / "stats.json").read_text())
    zero = [r["velocity_20s"] for r in stats["arms"]["zero_feedback"]]
    hand = [r["velocity_20s"] for r in stats["arms"]["hand_feedback"]]
    zero_after_start = walk.summarise(walk.walk_from_standing(mujoco_sim, lambda obs, k: 0.0 * k, jnp.zeros(1),
                                                              20.0, hand_seconds=1.5), mujoco_sim.control_dt,
                                        mujoco_sim.layout.weight)[0]
    np.testing.assert_allclose(zero, zero_after_start.mean_vx, rtol=0.01)
    np.testing.assert_allclose(hand, walks_mujoco[HAND].mean_vx, rtol=0.01)
    for arm in ("learning_off", "learning_off_min_sigma", "zero_feedback", "hand_feedback"):
        assert all(r["trials"] <= 4 for r in stats["arms"][arm])

    earlier = run / "controls" / "zero_feedback" / "summary.json"
    record = json.loads(earlier.read_text())
    del record["walk"]
    earlier.write_text(json.dumps(record))
    report.write_table1(run)
    assert ("Walked otherwise, so their velocities do not compare with the learners': (c) a_5 = 0 over "
            "a 20 s walk from standing (an earlier version's summary)") in (run / "table1.md").read_text()


def test_controls_refuse_an_earlier_control_before_running_any(finished_quick, tmp_path, capsys):
    """An earlier ``--only zero_feedback``, then all four without --resume or --force: refused
    at once (the first three would have run for nothing), nothing written."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished_quick, run)
    earlier = run / "controls" / "zero_feedback"
    earlier.mkdir(parents=True)
    (earlier / "config.json").write_text("{}")
    table = (run / "table1.md").read_text()
    assert main(["controls", "--run", str(run), "--trials", "4", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg: error:") and "zero_feedback exists" in err and "\n" not in err
    assert sorted(p.name for p in (run / "controls").iterdir()) == ["zero_feedback"]
    assert (run / "table1.md").read_text() == table


def test_controls_need_a_finished_run(tmp_path, capsys):
    assert main(["controls", "--run", str(tmp_path / "nothing")]) == 2
    assert "no finished run" in capsys.readouterr().err


@pytest.mark.slow
def test_learning_beats_the_controls(tmp_path):
    """Three k_s = 10 learners in the stats config's set-up against controls (a) and (b) of
    the same protocol: no learner of control (a) (learning off, sigma as initialised) meets
    the success criterion, and the learners earn more reward over their last 20 trials than
    control (b) (learning off, sigma at its smallest), on average over the three seeds."""
    stats = config.spec_to_dict(config.load_spec("stats"))
    small = {"k_s": [10.0, 10.0, 10.0], "seeds": [100, 101, 102], "learner": stats["learner"],
             "trial": {"max_trials": 400, "trials_after_success": stats["trial"]["trials_after_success"]}}
    (tmp_path / "small.json").write_text(json.dumps(small))
    run = tmp_path / "run"
    assert main(["sweep", "--config", str(tmp_path / "small.json"), "--out", str(run), "--quiet"]) == 0
    assert main(["controls", "--run", str(run), "--only", "learning_off", "learning_off_min_sigma",
                 "--trials", "200", "--quiet"]) == 0
    arms = json.loads((run / "stats.json").read_text())["arms"]
    assert not any(r["succeeded"] for r in arms["learning_off"])
    learned = np.mean([r["final_return"] for r in arms["learners"]])
    assert learned > np.mean([r["final_return"] for r in arms["learning_off_min_sigma"]])


def test_transfer_needs_a_finished_run(tmp_path, capsys):
    assert main(["transfer", "--run", str(tmp_path / "nothing")]) == 2
    assert "no finished run" in capsys.readouterr().err
