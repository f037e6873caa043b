"""The Python API, what the ``sweep``, ``learn`` and ``eval`` commands run: for scripts and
notebooks (README, "Python API").  ``import mjxcpg`` then ``mjxcpg.sweep(...)``, etc."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

from mjxcpg.evaluation import evaluate, report as evaluation_report, transfer
from mjxcpg.evaluation.protocol import EvalParams
from mjxcpg.training import report as run_report
from mjxcpg.training import runs, train
from mjxcpg.training.config import load_spec, validate
from mjxcpg.training.runs import load_run
from mjxcpg.training.train import RunSpec

__all__ = ["RunSpec", "EvalParams", "load_spec", "sweep", "load_run", "evaluate_policies", "EVALUATIONS"]

EVALUATIONS = ("return_map", "slopes", "pushes", "transfer")  # transfer: on the hardware robot only


def sweep(config: str | Path | RunSpec, out: str | Path, engine: str | None = None, resume: bool = False,
          force: bool = False, progress: bool = True, tensorboard: bool = True) -> dict:
    """Run the learners of ``config`` (a config's name, a .toml/.json path or a ``RunSpec``)
    in lockstep until each has met the success criterion or used its budget, into the run
    directory ``out`` (checkpoints, TensorBoard events, reports: README, "Learning").

    Returns what ``out/summary.json`` holds (per learner: k_s, seed, succeeded,
    trials_to_success, mean_vx, ...), with ``wall_s``, the wall time of this session."""
    spec = validate(config) if isinstance(config, RunSpec) else load_spec(str(config))
    out = Path(out)
    sim, task, state, wall_s = runs.execute(out, spec, engine, resume=resume, force=force, progress=progress,
                                            tensorboard=tensorboard)
    summary = run_report.write_report(out, spec, sim, task, state)
    summary["wall_s"] = wall_s
    return summary


def evaluate_policies(run_dir: str | Path, learners: Iterable[int] | None = None, engine: str | None = None,
             robot: str = "nominal", params: EvalParams = EvalParams(),
             parts: Iterable[str] = EVALUATIONS, transfer_repeats: int = 20, out: str | Path | None = None,
             progress: Callable[[str], None] | None = None) -> dict:
    """Evaluate the final policies of the run in ``run_dir`` as the paper did: velocity
    against k_s, the return map of step length, slopes, pushes (``parts``; ``transfer``, on
    the hardware robot only, walks each policy ``transfer_repeats`` times with other sensor
    noise).  Writes ``eval/*.json``, plots and ``report.md`` in ``out`` (default: the run
    directory; on the hardware robot its ``hardware/`` subdirectory).

    Returns the report's summary and where the report is."""
    run_dir = Path(run_dir)
    unknown = set(parts) - set(EVALUATIONS)
    if unknown:
        raise ValueError(f"unknown evaluation(s) {', '.join(sorted(unknown))}; choose from {', '.join(EVALUATIONS)}")
    spec, sim, task, state = load_run(run_dir, engine, robot=robot)
    chosen = runs.check_learners(spec, learners)
    parts = [p for p in EVALUATIONS if p in set(parts)]
    result = evaluate.evaluate_run(spec, sim, task, state, chosen, params, robot=robot, parts=parts,
                                     progress=progress)
    if robot == "hardware" and "transfer" in parts:
        if progress:
            progress(f"transfer: {transfer_repeats} walks per policy on the hardware robot")
        result["transfer"] = transfer.hardware_transfer(run_dir, engine=engine, learners=chosen,
                                                        repeats=transfer_repeats)
    # Each robot's evaluation has its own place, so that one never overwrites the other's.
    out = Path(out) if out else run_dir if robot == "nominal" else run_dir / robot
    table1_text = run_report.table1(train.learner_results(spec, state.learners))
    summary = evaluation_report.write_eval_report(run_dir, result, out, table1_text)
    return {"report": str(out / "report.md"), "engine": result["engine"], "robot": robot, **summary}
