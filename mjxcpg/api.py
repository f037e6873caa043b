"""The Python API, what the ``sweep``, ``learn`` and ``eval`` commands run: for scripts and
notebooks (README, "Python API").  ``import mjxcpg`` then ``mjxcpg.sweep(...)``, etc."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Iterable

from mjxcpg.evaluation import registry
from mjxcpg.evaluation import report as evaluation_report
from mjxcpg.evaluation.protocol import EvalParams
from mjxcpg.jaxutil import processes as jax_processes
from mjxcpg.training import report as run_report
from mjxcpg.training import checks, runs, train
from mjxcpg.training.checkpoints import first_line
from mjxcpg.training.config import load_spec, validate
from mjxcpg.training.runs import load_run
from mjxcpg.training.train import RunSpec

__all__ = ["RunSpec", "EvalParams", "load_spec", "sweep", "load_run", "evaluate_policies", "EVALUATIONS"]

EVALUATIONS = registry.NAMES  # in run order; transfer: on the hardware robot only


def sweep(config: str | Path | RunSpec, out: str | Path, engine: str | None = None, resume: bool = False,
          force: bool = False, progress: bool = True, tensorboard: bool = True,
          allow_other_code: bool = False, processes: jax_processes.Group = jax_processes.ALONE,
          checkpoint_every_s: float = runs.CHECKPOINT_EVERY_S) -> dict | None:
    """Run the learners of ``config`` (a config's name, a .toml/.json path or a ``RunSpec``)
    in lockstep until each has met the success criterion or used its budget, into the run
    directory ``out`` (checkpoints, TensorBoard events, reports: docs/usage.md).

    ``out`` is locked for the run (``runs.locked``); ``allow_other_code`` lets ``resume``
    continue a run that other code made, and records that it did.  A checkpoint is written
    after the first chunk ``checkpoint_every_s`` wall seconds after the last (0: after every
    chunk) and after the last chunk; the results do not depend on it.

    ``processes``: the group of processes (``mjxcpg.jaxutil.processes.join``) that runs the
    learners together, every one calling ``sweep`` alike.  Process 0 alone reads and writes
    ``out``; the others step their share of the learners and return None.

    Returns what ``out/summary.json`` holds (per learner: k_s, seed, succeeded,
    trials_to_success, mean_vx, ...), with ``wall_s``, the wall time of this session."""
    try:
        spec = validate(config) if isinstance(config, RunSpec) else load_spec(str(config))
        checks.check("checkpoint_every_s", checkpoint_every_s, checks.NON_NEGATIVE)
        if not processes.writer:
            runs.follow(spec, processes)
            processes.barrier()  # until process 0 has written the report
            return None
        summary = _sweep_here(spec, Path(out), engine, resume, force, progress, tensorboard, allow_other_code,
                              processes, checkpoint_every_s)
        processes.barrier()
        return summary
    except BaseException as error:
        processes.abort(first_line(error))
        raise


def _sweep_here(spec: RunSpec, out: Path, engine, resume, force, progress, tensorboard, allow_other_code,
                processes: jax_processes.Group, checkpoint_every_s: float) -> dict:
    with runs.locked(out):
        if resume and runs.is_finished(out):
            runs.share_start(processes, None, None)
            return finished_summary(out, spec)
        sim, task, state, wall_s = runs.execute(out, spec, engine, resume=resume, force=force, progress=progress,
                                                tensorboard=tensorboard, allow_other_code=allow_other_code,
                                                group=processes, checkpoint_every_s=checkpoint_every_s)
        summary = run_report.write_report(out, spec, sim, task, state)
    summary["wall_s"] = wall_s
    return summary


def finished_summary(out: Path, spec: RunSpec) -> dict:
    """A resumed run that had already finished: its results as they are, ``wall_s`` 0
    (``make run`` a second time reprints Table 1 and exits 0)."""
    saved, _ = runs.read_config(out)
    if saved != spec:
        raise runs.RunError(f"{out} holds a finished run of another config; use a new --out")
    runs.notice(f"{out} holds a finished run; its results are kept as they are")
    return json.loads((out / "summary.json").read_text()) | {"wall_s": 0.0}


def evaluate_policies(run_dir: str | Path, learners: Iterable[int] | None = None, engine: str | None = None,
             robot: str = "nominal", params: EvalParams = EvalParams(),
             parts: Iterable[str] = EVALUATIONS, transfer_repeats: int = 20, out: str | Path | None = None,
             progress: Callable[[str], None] | None = None, force: bool = False) -> dict:
    """Evaluate the final policies of the run in ``run_dir`` as the paper did: velocity
    against k_s, the return map of step length, slopes, pushes (``parts``; ``transfer``, on
    the hardware robot only, walks each policy ``transfer_repeats`` times with other sensor
    noise).  Writes ``eval/*.json``, plots and ``report.md`` in ``out`` (default: the run
    directory; on the hardware robot its ``hardware/`` subdirectory), holding ``out``'s lock
    while it runs; an earlier evaluation there is replaced only with ``force``.

    Returns the report's summary and where the report is."""
    run_dir, parts = Path(run_dir), list(parts)
    unknown = set(parts) - set(EVALUATIONS)
    if unknown:
        raise ValueError(f"unknown evaluation(s) {', '.join(sorted(unknown))}; choose from {', '.join(EVALUATIONS)}")
    runs.read_config(run_dir)  # a missing or damaged run is refused before ``out`` is made
    # Each robot's evaluation has its own place, so that one never overwrites the other's.
    out = Path(out) if out else run_dir if robot == "nominal" else run_dir / robot
    if out.exists() and not out.is_dir():
        raise runs.RunError(f"--out {out} is a file, not a directory")
    with runs.locked(out):
        runs.refuse_earlier_output(out, ("eval", "report.md"), force, "evaluation")
        context = registry.load_context(run_dir, learners, engine, robot, params, transfer_repeats)
        result = registry.evaluate_run(context, parts, progress)
        table1_text = run_report.table1(train.learner_results(context.spec, context.state.learners))
        if (out / "eval").is_dir():  # the earlier evaluation's plots, which this one may not redraw
            shutil.rmtree(out / "eval")
        summary = evaluation_report.write_eval_report(run_dir, result, registry.EVALUATIONS, out, table1_text)
    return {"report": str(out / "report.md"), "engine": result["engine"], "robot": robot, **summary}
