"""Every evaluation ``mjxcpg eval`` can run, in the order it runs and reports them.

An evaluation is one record: its name (a choice of ``--skip``), the ``EvalParams`` fields it
owns (each one a flag of ``eval``) and what it runs on a loaded run's chosen policies; its
summary figures and its section of report.md are registered under the same name in
``mjxcpg.report.evaluation.SECTIONS``.  Adding one is a module with those functions, its line
in ``EVALUATIONS`` and its line in ``SECTIONS``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp

from mjxcpg.control.sim import Simulation
from mjxcpg.evaluation import evaluate, transfer
from mjxcpg.report import evaluation as report
from mjxcpg.evaluation.protocol import EvalParams
from mjxcpg.learning.learner import Task
from mjxcpg.physics import hardware
from mjxcpg.physics.model import MAX_SLOPE_DEG
from mjxcpg.training import checks, runs
from mjxcpg.training.train import RunSpec


@dataclasses.dataclass(frozen=True)
class Option:
    """A flag of ``mjxcpg eval``: ``--field-name`` sets ``EvalParams.field_name``."""

    field: str
    rule: checks.Range
    help: str

    @property
    def flag(self) -> str:
        return "--" + self.field.replace("_", "-")


@dataclasses.dataclass(frozen=True)
class EvalContext:
    """What every evaluation is given: a loaded run, its chosen learners' policies and how to walk them."""

    run_dir: Path
    spec: RunSpec
    sim: Simulation
    task: Task
    state: Any                  # the run's checkpointed sweep state
    learners: list[int]
    weights: Any                # the chosen learners' policy weights, one row each
    robot: str
    engine: str | None          # as asked; None: the run's
    params: EvalParams
    transfer_repeats: int       # not in EvalParams: that is written whole into evaluation.json


def load_context(run_dir: Path, learners: Sequence[int] | None, engine: str | None, robot: str,
                 params: EvalParams, transfer_repeats: int) -> EvalContext:
    spec, sim, task, state = runs.load_run(run_dir, engine, robot=robot)
    chosen = runs.check_learners(spec, learners)
    weights = jax.tree.map(lambda w: w[jnp.asarray(chosen)], state.learners.weights)
    return EvalContext(run_dir, spec, sim, task, state, chosen, weights, robot, engine, params, transfer_repeats)


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """One evaluation: what it runs, with which options, on which robots."""

    name: str
    title: str                                          # its progress line
    run: Callable[[EvalContext], Any]                   # one result per learner, or one for the run
    options: tuple[Option, ...] = ()
    robots: tuple[str, ...] | None = None               # the robots it applies to; None: every one

    def applies_to(self, robot: str) -> bool:
        return self.robots is None or robot in self.robots

    @property
    def per_learner(self) -> bool:
        """Whether its result is a list, one per learner, kept in each learner's row."""
        return report.SECTIONS[self.name].per_learner


_COUNT = checks.NON_NEGATIVE_COUNT

# The hand-designed feedback and a_5 = 0 walk each protocol beside the policies, under keys
# of their own: far past any learner's index, so that no learner's draws are theirs.
REFERENCES = {"hand": ("hand-designed feedback", 1_000_000), "zero": ("a_5 = 0", 1_000_001)}


def evaluate_references(context: EvalContext) -> dict:
    """Velocity and return map, slopes and pushes of the hand-designed feedback and of
    a_5 = 0, in the same protocols as the policies (``REFERENCES``)."""
    out = {}
    for actor, (label, index) in REFERENCES.items():
        task = dataclasses.replace(context.task, trial=dataclasses.replace(context.task.trial, actor=actor))
        weights = jax.tree.map(lambda w: w[:1], context.weights)  # unused by these actors
        out[actor] = {
            "label": label,
            "return_map": evaluate.evaluate_return_map(context.sim, task, weights, [index], context.params)[0],
            "slopes": evaluate.evaluate_slopes(context.sim, task, weights, [index], context.params,
                                               robot=context.robot)[0],
            "pushes": evaluate.evaluate_pushes(context.sim, task, weights, [index], context.params)[0]}
    return out

EVALUATIONS: tuple[Evaluation, ...] = (
    Evaluation("return_map", "velocity and return map",
               lambda c: evaluate.evaluate_return_map(c.sim, c.task, c.weights, c.learners, c.params),
               options=(Option("fixed_point_steps", _COUNT, "unperturbed gait cycles for velocity and fixed point"),
                        Option("perturbations", _COUNT, "return-map perturbations"))),
    Evaluation("slopes", "slopes",
               lambda c: evaluate.evaluate_slopes(c.sim, c.task, c.weights, c.learners, c.params, robot=c.robot),
               options=(Option("slope_seconds", checks.POSITIVE, "walk on each slope this long"),
                        Option("max_slope_deg", dataclasses.replace(_COUNT, high=MAX_SLOPE_DEG),
                               "steepest inclination tried each way"))),
    Evaluation("pushes", "pushes",
               lambda c: evaluate.evaluate_pushes(c.sim, c.task, c.weights, c.learners, c.params),
               options=(Option("push_rounds", _COUNT, "bisection rounds per push direction"),)),
    Evaluation("references", "the hand-designed feedback and a_5 = 0 in the same protocols",
               evaluate_references),
    Evaluation("transfer", "transfer: walks per policy on the hardware robot",
               lambda c: transfer.hardware_transfer(c.run_dir, engine=c.engine, learners=c.learners,
                                                    repeats=c.transfer_repeats, noise_seed=c.params.seed,
                                                    robot=c.robot, hand_seconds=c.params.hand_seconds),
               robots=tuple(hardware.MISMATCHES)),
)

NAMES = tuple(e.name for e in EVALUATIONS)


def applies(name: str, robot: str) -> bool:
    """Whether evaluation ``name`` runs on ``robot``."""
    return next(e for e in EVALUATIONS if e.name == name).applies_to(robot)


def _trial_walk_speeds(run_dir: Path) -> dict[int, float]:
    """Per learner, its final policy's speed in the run's own 20 s walk (summary.json: started
    as its trials were); empty for a run without a summary."""
    path = run_dir / "summary.json"
    if not path.is_file():
        return {}
    return {row["learner"]: row["mean_vx"] for row in json.loads(path.read_text())["learners"]}


def evaluate_run(context: EvalContext, names: Sequence[str] = NAMES,
                 progress: Callable[[str], None] | None = None) -> dict:
    """The evaluations ``names`` (those that apply to the context's robot) of the context's learners."""
    spec, book = context.spec, jax.device_get(context.state.learners.book)
    trial_walks = _trial_walk_speeds(context.run_dir)
    result = {"engine": context.sim.engine.name, "robot": context.robot, "params": dataclasses.asdict(context.params),
              "learners": [{"learner": k, "k_s": spec.k_s[k], **({} if spec.k_e is None else {"k_e": spec.k_e[k]}),
                            "seed": spec.seeds[k],
                            "succeeded": bool(book.trials_to_success[k] >= 0),
                            "trials": int(book.trial[k]),
                            "trial_walk_vx": trial_walks.get(k)} for k in context.learners]}
    for evaluation in EVALUATIONS:
        if evaluation.name not in names or not evaluation.applies_to(context.robot):
            continue
        if progress:
            progress(evaluation.title)
        outcome = evaluation.run(context)
        if evaluation.per_learner:
            for row, r in zip(result["learners"], outcome):
                row[evaluation.name] = r
        else:
            result[evaluation.name] = outcome
    return result
