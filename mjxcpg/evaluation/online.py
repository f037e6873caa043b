"""Online additional learning: continue learned policies on another robot (the paper's last
experiment, where policies learned in simulation that failed on QRIO learned on the robot).

The chosen learners of a finished run are taken from its checkpoint (critic, policy mean and
sigma weights), placed on the chosen robot (``hardware`` by default, see
``mjxcpg.physics.hardware``) and learn on together, one batch row each, trial after trial,
with the learner and the trial protocol of their run except:

* trials of ``trial_seconds`` (16 s, the paper's on QRIO);
* the reward's height and velocity and the fall test come from the robot's own sensors
  (``mjxcpg.control.estimator``), not the simulator's state, unless ``reward="truth"``;
* a fresh trial count and success criterion (20 successive trials without a fall), and
  learning stops at success;
* with ``start="standing"``, every trial starts from standing with the policy acting from
  the first period (no hand-designed start): the start is then part of what is learned;
* with ``exploration="initial"``, sigma starts from its initial value (the learner's
  ``init_w_sigma``) instead of the learned one, the critic and mean as learned; with a
  number (``parse_exploration``), sigma starts at that value;
* with ``learning=False``, the control: the same trials, exploration noise included, with
  every learning rate 0.

The result directory is a run directory: ``load_run(out, robot=...)`` reloads the policies
(e.g. ``transfer.walk_policies``); ``online.json`` holds, per learner, trials to success,
per-trial returns, falls and sigma (at the trial's end), and whether the final policy walks
20 s by ground truth.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control.estimator import EstimatorParams
from mjxcpg.learning import ngnet
from mjxcpg.learning.learner import init_learner
from mjxcpg.physics import hardware
from mjxcpg.report import learning as report
from mjxcpg.report import plots
from mjxcpg.training import config, runs, train

REWARD_SOURCES = ("estimate", "truth")
STARTS = ("hand", "standing")  # a trial starts with the run's hand-designed start, or from standing
# sigma the online learning starts from: the run's learned one, or the initial one of its learner;
# ``parse_exploration`` also takes a sigma value to restart at
EXPLORATIONS = ("learned", "initial")


# the restart sigmas float32 holds apart from 0 and 1 through eq (26)'s sigmoid
SIGMA_RANGE = (1e-6, 1.0 - 1e-6)


def parse_exploration(value: str | float) -> str | float:
    """``value`` as an online exploration: one of ``EXPLORATIONS``, or a sigma in
    ``SIGMA_RANGE`` (eq (26)'s range, (0, 1), as far as float32 resolves it) that every
    learner's sigma restarts at."""
    if value in EXPLORATIONS:
        return value
    try:
        sigma = float(value)
    except (TypeError, ValueError):
        sigma = float("nan")
    low, high = SIGMA_RANGE
    if not low <= sigma <= high:
        raise ValueError(f"unknown exploration {value!r}; choose one of {', '.join(EXPLORATIONS)} "
                         f"or a sigma from {low:g} to {high:g}")
    return sigma


def continued_spec(spec: train.RunSpec, learners: Sequence[int], trials: int, trial_seconds: float,
                   learning: bool = True, start: str = "hand") -> train.RunSpec:
    """The spec of ``learners`` of ``spec`` learning on, with a new trial budget and length,
    ending at success; with ``learning=False`` every learning rate is 0; with
    ``start="standing"`` the policy takes over at the first period of every trial."""
    if start not in STARTS:
        raise ValueError(f"unknown start {start!r}; choose one of {', '.join(STARTS)}")
    hand = spec.trial.hand_seconds if start == "hand" else (0.0, 0.0)
    trial = dataclasses.replace(spec.trial, trial_seconds=trial_seconds, max_trials=trials, trials_after_success=0,
                                hand_seconds=hand)
    learner = spec.learner if learning else dataclasses.replace(spec.learner, rate_scale=0.0)
    k_e = None if spec.k_e is None else tuple(spec.k_e[k] for k in learners)
    return config.validate(dataclasses.replace(spec, k_s=tuple(spec.k_s[k] for k in learners),
                                               seeds=tuple(spec.seeds[k] for k in learners),
                                               k_e=k_e, trial=trial, learner=learner))


def learn_online(source: Path, learners: Sequence[int], out: Path, trials: int = 400, robot: str = "hardware",
                 reward: str | None = None, engine: str | None = None, trial_seconds: float = 16.0,
                 learning: bool = True, start: str = "hand", exploration: str | float = "learned", force: bool = False,
                 progress: bool = True, tensorboard: bool = True) -> dict:
    """Continue ``learners`` of the run in ``source`` on ``robot``, together; write ``out``.

    ``reward``: "estimate" (the robot's sensors; the default on a hardware robot) or
    "truth" (the simulator's state; the default on the nominal one).  ``learning=False``
    runs the control with learning off; ``start`` is one of ``STARTS``, ``exploration`` one of
    ``EXPLORATIONS`` or a sigma to restart at (``parse_exploration``).
    Returns the summary that ``out/online.json`` holds, without the per-trial lists.
    """
    reward = reward or ("estimate" if robot in hardware.MISMATCHES else "truth")
    if reward not in REWARD_SOURCES:
        raise ValueError(f"unknown reward source {reward!r}; choose one of {', '.join(REWARD_SOURCES)}")
    if start not in STARTS:
        raise ValueError(f"unknown start {start!r}; choose one of {', '.join(STARTS)}")
    exploration = parse_exploration(exploration)
    source_spec, _ = runs.read_config(source)  # a bad source is refused before ``out`` is made
    learners = runs.check_learners(source_spec, list(learners))
    if not learners:
        raise ValueError("no learner to learn on")
    if Path(source).resolve().is_relative_to(Path(out).resolve()):
        raise runs.RunError(f"--out {out} is or holds the run learned from; choose another directory")
    with runs.locked(out):
        runs.clear_for_new_run(out, force)
        return _learn_online_locked(source, learners, out, trials, robot, reward, engine, trial_seconds, learning,
                                    start, exploration, progress, tensorboard)


def _learn_online_locked(source: Path, learners: list[int], out: Path, trials: int, robot: str, reward: str,
                         engine: str | None, trial_seconds: float, learning: bool, start: str,
                         exploration: str | float, progress: bool, tensorboard: bool) -> dict:
    """``learn_online`` once ``out`` is locked and empty."""
    source_spec, sim, _, source_state = runs.load_run(source, engine, robot=robot)
    spec = continued_spec(source_spec, learners, trials, trial_seconds, learning, start)
    task = train.make_task(sim, spec)
    if reward == "estimate":
        task = dataclasses.replace(task, estimator=EstimatorParams.of(sim.model))
    rows = jnp.asarray(learners)
    fresh = [init_learner(task, k_s, seed, None if spec.k_e is None else spec.k_e[i])
             for i, (k_s, seed) in enumerate(zip(spec.k_s, spec.seeds))]
    fresh = jax.tree.map(lambda *x: jnp.stack(x), *fresh)
    weights = jax.tree.map(lambda w: w[rows], source_state.learners.weights)
    if exploration == "initial":
        weights = weights._replace(sigma=fresh.weights.sigma)  # init_learner's: the learner's init_w_sigma
    elif exploration != "learned":
        weights = weights._replace(sigma=jnp.full_like(fresh.weights.sigma, ngnet.policy_std_weight(exploration)))
    fresh = fresh._replace(weights=weights)
    state = train.RunState(physics=sim.engine.init(sim.qpos0, len(learners)), learners=fresh)

    origin = {"from": str(source), "learners": learners, "robot": robot, "reward": reward, "learning": learning,
              "start": start} | ({} if exploration == "learned" else {"exploration": exploration})
    runs.write_record(out, spec, sim.engine.name, online=origin)
    start = time.perf_counter()
    state = runs.learn_block(out, sim, task, spec, state, progress, tensorboard, checkpointed=False)
    wall_s = time.perf_counter() - start

    results = train.learner_results(spec, state.learners)
    walk_checks = report.final_policy_gaits(sim, task, state.learners.weights)
    rows_out = [{"learner": k, "k_s": spec.k_s[i], "seed": spec.seeds[i], "succeeded": r["succeeded"],
                 "trials_to_success": r["trials_to_success"], "trials": r["trials"],
                 "falls_in_first_20": sum(r["falls"][:20]),
                 "final_policy_walks_20s": not w["fell"], "final_policy_mean_vx": w["mean_vx"],
                 "returns": r["returns"], "falls": r["falls"], "sigmas": r["sigmas"]}
                for i, (k, r, w) in enumerate(zip(learners, results, walk_checks))]
    summary = origin | {"engine": sim.engine.name, "trial_seconds": trial_seconds, "trials": trials,
                        "succeeded": sum(r["succeeded"] for r in rows_out), "wall_s": wall_s}
    out.mkdir(parents=True, exist_ok=True)
    _write_run(out, spec, sim.engine.name, state, origin)
    (out / "online.json").write_text(json.dumps(summary | {"learners": rows_out}, indent=1))
    plots.learning_curves(results, out / "learning_curve.png",
                          title=f"online learning on the {robot} robot{'' if learning else ', learning off'} "
                                "(cf. Fig 9)")
    return summary


def _write_run(out: Path, spec: train.RunSpec, engine: str, state: train.RunState, origin: dict) -> None:
    """``out`` as a run directory: config.json and a checkpoint that ``runs.load_run`` reads.

    The checkpoint holds the learners (without the estimator's state, which a simulation run
    has not) and the nominal robot standing, the layout every run directory's physics has."""
    nominal = spec.simulation(engine)
    saved = train.RunState(physics=nominal.engine.init(nominal.qpos0, spec.batch),
                           learners=jax.tree.map(jnp.asarray, state.learners._replace(estimate=None)))
    runs.write_run(out, spec, engine, saved, online=origin)
