"""The Python API, what the ``sweep``, ``learn`` and ``eval`` commands run: for scripts and
notebooks (README, "Python API").  ``import mjxcpg`` then ``mjxcpg.sweep(...)``, etc."""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from pathlib import Path
from typing import Callable, Iterable

from mjxcpg.evaluation import controls, online, registry
from mjxcpg.evaluation.protocol import EvalParams
from mjxcpg.jaxutil import processes as jax_processes
from mjxcpg.physics import hardware
from mjxcpg.report import document
from mjxcpg.report import evaluation as evaluation_report
from mjxcpg.report import learning as run_report
from mjxcpg.training import checks, runs, train
from mjxcpg.training.checkpoints import first_line
from mjxcpg.training.config import load_spec, validate
from mjxcpg.training.files import write_text_atomic
from mjxcpg.training.runs import load_run
from mjxcpg.training.train import RunSpec

__all__ = ["RunSpec", "EvalParams", "load_spec", "sweep", "load_run", "evaluate_policies", "EVALUATIONS",
           "reproduce", "ReproductionBudget"]

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
    learners together, every one calling ``sweep`` alike, ``out`` on a file system they all
    see.  Each steps its own block of learners and writes its checkpoints; process 0 holds the
    lock, checks and starts the run and writes the report; the others return None.

    Returns what ``out/summary.json`` holds (per learner: k_s, seed, succeeded,
    trials_to_success, mean_vx, ...), with ``wall_s``, the wall time of this session."""
    try:
        spec = validate(config) if isinstance(config, RunSpec) else load_spec(str(config))
        checks.check("checkpoint_every_s", checkpoint_every_s, checks.NON_NEGATIVE)
        if not processes.writer:
            runs.follow(Path(out), spec, processes, tensorboard, checkpoint_every_s)
            processes.barrier()  # until process 0 has written the report
            processes.close()
            return None
        summary = _sweep_here(spec, Path(out), engine, resume, force, progress, tensorboard, allow_other_code,
                              processes, checkpoint_every_s)
        processes.barrier()
        processes.close()
        return summary
    except jax_processes.ProcessError:
        raise  # a stop the group already knows of
    except BaseException as error:
        processes.abort(f"failed: {first_line(error)}")
        raise


def _sweep_here(spec: RunSpec, out: Path, engine, resume, force, progress, tensorboard, allow_other_code,
                processes: jax_processes.Group, checkpoint_every_s: float) -> dict:
    with runs.locked(out):
        if resume and runs.is_finished(out):
            runs.share_start(processes, None)
            processes.barrier()  # where the others would wait for every block's end
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
        result["command"] = eval_command(run_dir, learners, engine, robot, params, parts, transfer_repeats, out)
        table1_text = run_report.table1(train.learner_results(context.spec, context.state.learners))
        if (out / "eval").is_dir():  # the earlier evaluation's plots, which this one may not redraw
            shutil.rmtree(out / "eval")
        summary = evaluation_report.write_evaluation(out, result)
        document.write_report(out, run_dir, table1_text)
    return {"report": str(out / "report.md"), "engine": result["engine"], "robot": robot, **summary}


def eval_command(run_dir: Path, learners, engine, robot: str, params: EvalParams, parts: list[str],
                 transfer_repeats: int, out: Path) -> str:
    """The ``mjxcpg eval`` command line that evaluates as these arguments do (the report's)."""
    words = ["mjxcpg eval --run", str(run_dir)]
    if learners is not None:
        words += ["--learner", *map(str, learners)]
    if engine is not None:
        words += ["--engine", engine]
    if robot != "nominal":
        words += ["--robot", robot]
    flags = ["seed", "hand_seconds"] + [o.field for e in registry.EVALUATIONS for o in e.options]
    changed = [name for name, value in dataclasses.asdict(params).items() if value != getattr(EvalParams(), name)]
    for name in changed:
        if name in flags:
            words += ["--" + name.replace("_", "-"), f"{getattr(params, name):g}"]
    skipped = [name for name in EVALUATIONS if name not in parts and registry.applies(name, robot)]
    if skipped:
        words += ["--skip", *skipped]
    if robot in hardware.MISMATCHES and transfer_repeats != 20:
        words += ["--transfer-repeats", str(transfer_repeats)]
    default_out = run_dir if robot == "nominal" else run_dir / robot
    if out.resolve() != default_out.resolve():
        words += ["--out", str(out)]
    unflagged = [name for name in changed if name not in flags]
    return " ".join(words) + (f" (and, from Python, EvalParams {', '.join(unflagged)})" if unflagged else "")


# ---------------------------------------------------------------- the whole reproduction

@dataclasses.dataclass(frozen=True)
class ReproductionBudget:
    """How much of each stage ``reproduce`` runs beyond the sweep (which runs its config whole).
    ``BUDGET_FLAGS`` are those ``mjxcpg reproduce`` takes as flags."""

    controls: tuple[str, ...] = ("learning_off", "learning_off_min_sigma", "zero_feedback")
    control_trials: int = 100           # each control learner's budget, as the 70-learner study's
    transfer_repeats: int = 10          # walks per policy on each hardware robot, each with other noise
    online_robot: str = "harsher"       # the hardware robot online learning repairs policies on
    online_start: str = "standing"      # its trials from standing, as the transfer walks (online.STARTS)
    # sigma restarts at 0.2 (online.parse_exploration): on the harsher robot, of the values
    # measured (as learned, 0.2, 0.3, the initial 0.5), the one that repairs the most policies
    # while its control with learning off repairs fewer (docs/hardware.md)
    online_exploration: str | float = 0.2
    online_learners: int = 27           # at most this many of the policies failing there learn on
    online_trials: int = 200            # the paper's: walking within 200 trials on QRIO
    eval_params: EvalParams = EvalParams()  # every evaluation's protocol (the Python API's to change)

    def note(self) -> str:
        return (f"controls {', '.join(self.controls)} with {self.control_trials} trials each; every evaluation "
                f"of `mjxcpg eval`{'' if self.eval_params == EvalParams() else ' with other protocol constants'} from "
                f"standing; {self.transfer_repeats} walks per policy on each hardware robot ({', '.join(HARDWARE_ROBOTS)}); "
                f"online learning ({self.online_trials} trials, {self.online_start} start, "
                f"{document.exploration_words(self.online_exploration)}) on the `{self.online_robot}` "
                f"robot for at most {self.online_learners} of the policies that do not walk there in every try, "
                "beside the same trials with learning off.")


BUDGET_FLAGS = ("control_trials", "transfer_repeats", "online_robot", "online_start", "online_exploration",
                "online_learners", "online_trials")
HARDWARE_ROBOTS = tuple(hardware.MISMATCHES)  # every robot the hardware stage walks the policies on


STAGES = ("sweep", "controls", "eval", "hardware", "online", "report")


def reproduce(config: str = "paper", out: str | Path = "runs/paper", engine: str | None = None,
              budget: ReproductionBudget = ReproductionBudget(), progress: bool = True) -> dict:
    """The paper's experiments from learning to its last figure, into ``out``: the sweep of
    ``config``, the controls beside it, every evaluation, the transfer to each hardware robot,
    online learning on ``budget.online_robot`` for the policies that fail there beside the
    same trials with learning off, and ``out/report.md`` with them all.

    Each stage is recorded in ``out/reproduce.json`` as it starts and ends, with its wall
    time.  Called again, a finished stage is kept as it is and an interrupted one goes on
    (the sweep and the controls from their checkpoints) or runs again: every stage is
    deterministic, so the results are byte-identical to an uninterrupted run's.  A stage's
    output that this pipeline did not start (an ``eval`` run by hand, say) is refused, not
    replaced."""
    out = Path(out)
    spec = load_spec(config)
    if budget.online_robot not in HARDWARE_ROBOTS:
        raise ValueError(f"unknown hardware robot {budget.online_robot!r}; choose one of {', '.join(HARDWARE_ROBOTS)}")
    if budget.online_start not in online.STARTS:
        raise ValueError(f"unknown online start {budget.online_start!r}; choose one of {', '.join(online.STARTS)}")
    # "0.2" and 0.2 alike: the record and the command hold the number
    budget = dataclasses.replace(budget, online_exploration=online.parse_exploration(budget.online_exploration))
    for name in budget.controls:
        controls.control_spec(spec, name, budget.control_trials)  # a bad control is refused before any run
    record_path = out / document.PIPELINE_RECORD
    command = f"mjxcpg reproduce --config {config} --out {out}" + "".join(
        f" --{name.replace('_', '-')} {getattr(budget, name)}" for name in BUDGET_FLAGS
        if getattr(budget, name) != getattr(ReproductionBudget(), name))
    if record_path.is_file():
        record = json.loads(record_path.read_text())
        if record["config"] != config or record["budget"] != _budget_record(budget):
            raise runs.RunError(f"{out} holds a reproduction of other settings ({record['command']}); use another --out")
    else:
        record = {"command": command, "config": config, "note": budget.note(),
                  "budget": _budget_record(budget),
                  "stages": {}, "commands": {}}
    start = stage_start = time.perf_counter()

    def mark(stage: str, state: str, **commands) -> None:
        record["stages"][stage] = state
        record["commands"].update(commands)
        if state == "finished":  # its wall time, summed over the calls that ran it
            walls = record.setdefault("wall_s", {})
            walls[stage] = round(walls.get(stage, 0.0) + time.perf_counter() - stage_start, 1)
        if not (out / "config.json").is_file():
            return  # before the sweep has made the run directory, which must hold nothing else
        with runs.locked(out):
            write_text_atomic(record_path, json.dumps(record, indent=1))

    def begin(stage: str) -> bool:
        """Whether ``stage`` is to run; False when it is finished.  Says which stage runs."""
        nonlocal stage_start
        if record["stages"].get(stage) == "finished":
            return False
        stage_start = time.perf_counter()
        if progress:
            runs.notice(f"reproduce: stage {STAGES.index(stage) + 1} of {len(STAGES)}, {stage} "
                        f"(this session {_minutes(time.perf_counter() - start)} so far)")
        return True

    if begin("sweep"):
        mark("sweep", "started", sweep=f"mjxcpg sweep --config {config} --out {out}")
        sweep(spec, out, engine, resume=(out / "config.json").is_file(), progress=progress)
        mark("sweep", "finished")
    if begin("controls"):
        mark("controls", "started", controls=f"mjxcpg controls --run {out} --trials {budget.control_trials} "
                                              f"--only {' '.join(budget.controls)}")
        controls.run_controls(out, budget.controls, trials=budget.control_trials, engine=engine, resume=True,
                              progress=progress)
        mark("controls", "finished")
    if begin("eval"):
        again = record["stages"].get("eval") == "started"
        mark("eval", "started")
        evaluate_policies(out, engine=engine, params=budget.eval_params,
                          parts=[p for p in EVALUATIONS if registry.applies(p, "nominal")], force=again,
                          progress=_stage_lines(progress))
        mark("eval", "finished")
    if begin("hardware"):
        again = record["stages"].get("hardware") == "started"
        mark("hardware", "started")
        for robot in HARDWARE_ROBOTS:
            evaluate_policies(out, engine=engine, robot=robot, params=budget.eval_params, parts=["transfer"],
                              transfer_repeats=budget.transfer_repeats, force=again,
                              progress=_stage_lines(progress))
        mark("hardware", "finished")
    if begin("online"):
        again = record["stages"].get("online") == "started"
        mark("online", "started")
        failing = failing_on_hardware(out, budget.online_robot)[:budget.online_learners]
        commands = {}
        for name, learning in (("online", True), ("online_control", False)):
            target = out / name
            words = (f"mjxcpg learn --from {out} --learner {' '.join(map(str, failing))} "
                     f"--robot {budget.online_robot} --start {budget.online_start} "
                     f"--exploration {budget.online_exploration} --trials {budget.online_trials} "
                     f"--out {target}"
                     + ("" if learning else " --no-learning"))
            commands[name] = words if failing else ""
            if not failing or ((target / "online.json").is_file() and again):
                continue  # nothing to learn on, or learned before the interruption
            online.learn_online(out, failing, target, trials=budget.online_trials, robot=budget.online_robot,
                                engine=engine, learning=learning, start=budget.online_start,
                                exploration=budget.online_exploration, force=again,
                                progress=progress)
        mark("online", "finished", **commands)
    begin("report")
    path = document.write_report(out, out)
    mark("report", "finished")
    if progress:
        walls = ", ".join(f"{stage} {_minutes(seconds)}" for stage, seconds in record["wall_s"].items())
        runs.notice(f"reproduce: {path} written; this session {_minutes(time.perf_counter() - start)}; "
                    f"each stage's wall time, over every session that ran it: {walls}")
    return {"report": str(path), "wall_s": time.perf_counter() - start, "stage_wall_s": record.get("wall_s", {})}


def _minutes(seconds: float) -> str:
    return f"{int(seconds) // 60} min {int(seconds) % 60} s"


def _budget_record(budget: ReproductionBudget) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(budget)))  # as reproduce.json holds it


def _stage_lines(progress: bool) -> Callable[[str], None] | None:
    return (lambda text: runs.notice(f"eval: {text}")) if progress else None


def failing_on_hardware(run_dir: Path, robot: str = "hardware") -> list[int]:
    """The learners of ``run_dir`` that succeeded in simulation and did not walk in every try on
    the hardware robot ``robot`` (its ``ROBOT/eval/evaluation.json``), by index."""
    transfer = json.loads((run_dir / robot / "eval" / "evaluation.json").read_text())["transfer"]
    return [r["learner"] for r in transfer["learners"]
            if r["succeeded"] and r["walks_hardware"] < transfer["repeats"]]
