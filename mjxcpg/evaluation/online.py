"""Online additional learning: continue a learned policy on another robot (the paper's last
experiment, where policies learned in simulation that failed on QRIO learned on the robot).

One learner of a finished run is taken from its checkpoint (critic, policy mean and sigma
weights), placed on the chosen robot (``hardware`` by default, see ``mjxcpg.physics.hardware``) and
learns on, trial after trial, with the learner and the trial protocol of its run except:

* trials of ``trial_seconds`` (16 s, the paper's on QRIO);
* the reward's height and velocity and the fall test come from the robot's own sensors
  (``mjxcpg.control.estimator``), not the simulator's state, unless ``reward="truth"``;
* a fresh trial count and success criterion (20 successive trials without a fall).

The result directory is a run directory: ``load_run(out, robot=...)`` reloads the policy
(e.g. ``transfer.walk_policies``), ``online.json`` holds trials to success, per-trial returns
and falls, and whether the final policy walks 20 s by ground truth.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from mjxcpg.control.estimator import EstimatorParams
from mjxcpg.learning.learner import init_learner
from mjxcpg.report import learning as report
from mjxcpg.report import plots
from mjxcpg.training import config, runs, train

REWARD_SOURCES = ("estimate", "truth")


def continued_spec(spec: train.RunSpec, learner: int, trials: int, trial_seconds: float) -> train.RunSpec:
    """A one-learner spec for learner ``learner`` of ``spec``, with a new trial budget and length."""
    trial = dataclasses.replace(spec.trial, trial_seconds=trial_seconds, max_trials=trials)
    k_e = None if spec.k_e is None else (spec.k_e[learner],)
    return config.validate(dataclasses.replace(spec, k_s=(spec.k_s[learner],), seeds=(spec.seeds[learner],),
                                               k_e=k_e, trial=trial))


def learn_online(source: Path, learner: int, out: Path, trials: int = 400, robot: str = "hardware",
                 reward: str | None = None, engine: str | None = None, trial_seconds: float = 16.0,
                 force: bool = False, progress: bool = True, tensorboard: bool = True) -> dict:
    """Continue learner ``learner`` of the run in ``source`` on ``robot``; write ``out``.

    ``reward``: "estimate" (the robot's sensors; the default on the hardware robot) or
    "truth" (the simulator's state; the default on the nominal one).
    Returns the summary that ``out/online.json`` holds, without the per-trial lists.
    """
    reward = reward or ("estimate" if robot == "hardware" else "truth")
    if reward not in REWARD_SOURCES:
        raise ValueError(f"unknown reward source {reward!r}; choose one of {', '.join(REWARD_SOURCES)}")
    source_spec, _ = runs.read_config(source)  # a bad source is refused before ``out`` is made
    runs.check_learners(source_spec, [learner])
    if Path(source).resolve().is_relative_to(Path(out).resolve()):
        raise runs.RunError(f"--out {out} is or holds the run learned from; choose another directory")
    with runs.locked(out):
        runs.clear_for_new_run(out, force)
        return _learn_online_locked(source, learner, out, trials, robot, reward, engine, trial_seconds, progress,
                                    tensorboard)


def _learn_online_locked(source: Path, learner: int, out: Path, trials: int, robot: str, reward: str,
                         engine: str | None, trial_seconds: float, progress: bool, tensorboard: bool) -> dict:
    """``learn_online`` once ``out`` is locked and empty."""
    source_spec, sim, _, source_state = runs.load_run(source, engine, robot=robot)
    spec = continued_spec(source_spec, learner, trials, trial_seconds)
    task = train.make_task(sim, spec)
    if reward == "estimate":
        task = dataclasses.replace(task, estimator=EstimatorParams.of(sim.model))
    weights = jax.tree.map(lambda w: w[learner], source_state.learners.weights)
    fresh = init_learner(task, spec.k_s[0], spec.seeds[0], None if spec.k_e is None else spec.k_e[0])
    fresh = fresh._replace(weights=weights)
    state = train.RunState(physics=sim.engine.init(sim.qpos0, 1),
                           learners=jax.tree.map(lambda x: x[None], fresh))

    origin = {"from": str(source), "learner": learner, "robot": robot, "reward": reward}
    runs.write_record(out, spec, sim.engine.name, online=origin)
    start = time.perf_counter()
    state = runs.learn_to_end(out, sim, task, spec, state, None, progress, tensorboard)
    wall_s = time.perf_counter() - start

    result = train.learner_results(spec, state.learners)[0]
    walk_check = report.final_policy_gaits(sim, task, state.learners.weights)[0]
    summary = origin | {
        "engine": sim.engine.name, "k_s": spec.k_s[0], "seed": spec.seeds[0],
        "trial_seconds": trial_seconds, "succeeded": result["succeeded"],
        "trials_to_success": result["trials_to_success"], "trials": result["trials"],
        "falls_in_first_20": sum(result["falls"][:20]),
        "final_policy_walks_20s": not walk_check["fell"], "final_policy_mean_vx": walk_check["mean_vx"],
        "wall_s": wall_s,
    }
    out.mkdir(parents=True, exist_ok=True)
    _write_run(out, spec, sim.engine.name, state, summary)
    (out / "online.json").write_text(json.dumps(summary | {"returns": result["returns"],
                                                           "falls": result["falls"]}, indent=1))
    plots.learning_curves([result], out / "learning_curve.png",
                          title=f"online learning on the {robot} robot (cf. Fig 9)")
    return summary


def _write_run(out: Path, spec: train.RunSpec, engine: str, state: train.RunState, summary: dict) -> None:
    """``out`` as a run directory: config.json and a checkpoint that ``runs.load_run`` reads.

    The checkpoint holds the learners (without the estimator's state, which a simulation run
    has not) and the nominal robot standing, the layout every run directory's physics has."""
    nominal = spec.simulation(engine)
    saved = train.RunState(physics=nominal.engine.init(nominal.qpos0, spec.batch),
                           learners=jax.tree.map(jnp.asarray, state.learners._replace(estimate=None)))
    runs.write_run(out, spec, engine, saved, online={k: summary[k] for k in ("from", "learner", "robot", "reward")})
