"""Run directories: config, orbax checkpoints, resume, results, a lock.

``DIR/config.json`` (the run spec, the engine, and the code that made the run: see
``mjxcpg.training.provenance``), ``DIR/checkpoints/`` (``mjxcpg.training.checkpoints``: orbax, the
full state: physics, CPG, learner weights, traces, RNG keys, bookkeeping, with the config's
sha256 and a sha256 of it all; with several processes each writes its block's in
``DIR/checkpoint_parts/``),
``DIR/summary.json`` (written last: a run directory that holds it is finished), ``DIR/.lock``.
A checkpoint is written after the first chunk that ends ``checkpoint_every_s`` wall seconds
(``CHECKPOINT_EVERY_S`` by default; 0: every chunk) or more after the last one began, and
after the last chunk.  A run resumed from a checkpoint ends exactly as an uninterrupted one:
chunk boundaries and every random draw are functions of the config and seeds alone, not of
which chunks were checkpointed.

What can go wrong, and what then happens:

* a kill at any moment: orbax writes a checkpoint under a temporary name and renames it
  when it is complete, so the checkpoints on disk are whole; ``--resume`` goes on from the
  newest;
* a checkpoint damaged on disk (torn, corrupted): orbax cannot read it or its leaves do not
  match their sha256; a resume goes on from the newest intact one, says so, and moves the
  damaged ones to ``DIR/damaged_checkpoints/``; with none intact, an error, nothing moved;
* a failed write (a full disk): an error; the checkpoints written before it stay;
* a second process on the same directory: refused by the lock;
* other code than the run's: refused, unless allowed, and then recorded in config.json.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import json
import os
import shutil
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjxcpg.control.sim import Simulation
from mjxcpg.jaxutil import processes
from mjxcpg.training import config, events, provenance, train
from mjxcpg.training.checkpoints import (RunError, manager_at, manager_of, part_directory, restore_learners,
                                         save_next, write_checkpoint, written)
from mjxcpg.training.files import write_text_atomic
from mjxcpg.training.progress import RunProgress

LOCK_NAME = ".lock"
# A checkpoint hashes and writes the whole state, on threads that the physics then lacks: a
# short chunk of a few learners costs much less.  Written at most this often, a kill loses
# at most this many wall seconds of learning, plus one chunk.
CHECKPOINT_EVERY_S = 10.0


def notice(text: str) -> None:
    """One line to the user, beside the progress bar."""
    print(f"mjxcpg: {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------- the lock

def _lock_owner(handle) -> dict:
    """Who the lock file names: {} when it names nobody."""
    handle.seek(0)
    text = handle.read()
    try:
        return json.loads(text) if text.strip() else {}
    except json.JSONDecodeError:
        return {"pid": "unknown", "host": "unknown"}


def _owner_text(owner: dict) -> str:
    return f"pid {owner.get('pid')} on {owner.get('host')}"


@contextlib.contextmanager
def locked(out: Path) -> Iterator[None]:
    """Hold the run directory ``out`` (made if missing) for the block, or refuse at once.

    The lock is an ``flock`` of ``out/.lock``, and the file names the holder (pid, host).
    The kernel releases an flock when its holder dies, however it dies: a lock that is free
    but still names a holder was left by a dead process, and is taken over with a notice.
    """
    out.mkdir(parents=True, exist_ok=True)
    with open(out / LOCK_NAME, "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunError(f"{out} is in use by {_owner_text(_lock_owner(handle))}; "
                           "wait for it to end or use another --out") from None
        previous = _lock_owner(handle)
        if previous:
            notice(f"{out}: took over the lock of {_owner_text(previous)}, which is no longer running")
        handle.seek(0)
        handle.truncate()
        handle.write(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))
        handle.flush()
        try:
            yield
        finally:
            handle.truncate(0)
            handle.flush()


# ---------------------------------------------------------------- the directory

def run_files(out: Path) -> list[Path]:
    """What ``out`` holds besides its lock."""
    return [p for p in out.iterdir() if p.name != LOCK_NAME] if out.is_dir() else []


def check_replaceable(out: Path, allowed: bool, options: str = "pass --force to replace it") -> bool:
    """Whether ``out`` holds anything; refused (``RunError``, naming ``options``) when it holds
    a run and replacing or continuing it is not ``allowed``, and always when it holds files
    but no run (no config.json): a mistyped ``--out`` (``runs``, ``.``) must not lose what is
    not a run."""
    if not run_files(out):
        return False
    if not (out / "config.json").is_file():
        raise RunError(f"{out} holds files but is not a run directory (no config.json); nothing there is replaced")
    if not allowed:
        raise RunError(f"{out} exists; {options}")
    return True


def clear_for_new_run(out: Path, force: bool, options: str = "pass --force to replace it") -> None:
    """Empty ``out`` for a new run when it holds a run and ``force`` is set (keeping the lock
    its caller holds); else refuse as ``check_replaceable`` does."""
    if check_replaceable(out, force, options):
        for path in run_files(out):
            shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()


def refuse_earlier_output(out: Path, names: tuple[str, ...], force: bool, what: str) -> None:
    """Refuse (``RunError``) to write over the files or folders ``names`` in ``out`` that an
    earlier ``what`` (an evaluation, a render) left there, unless ``force``."""
    earlier = [name for name in names if (out / name).exists()]
    if earlier and not force:
        raise RunError(f"{out} holds an earlier {what} ({', '.join(earlier)}); pass --force to replace it")


def is_finished(out: Path) -> bool:
    return (out / "summary.json").is_file()


# ---------------------------------------------------------------- running

def run_record(spec: train.RunSpec, engine: str | None, **extra) -> dict:
    """What a run directory's config.json holds: the spec, the engine and the code that made
    the run (``provenance.code_identity``), and ``extra``."""
    return {"spec": config.spec_to_dict(spec), "engine": engine, "code": provenance.code_identity(), **extra}


def write_record(out: Path, spec: train.RunSpec, engine: str, **extra) -> None:
    """``out/config.json`` (``run_record``): written before anything else of a run, so that
    a directory holding a run's files always says what made them (``clear_for_new_run``)."""
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "config.json", json.dumps(run_record(spec, engine, **extra), indent=1))


def write_run(out: Path, spec: train.RunSpec, engine: str, state: train.RunState, **extra) -> None:
    """``out`` (new, or empty) as a run directory that ``load_run`` reads: config.json
    (``write_record``) and ``state`` as its one checkpoint."""
    write_record(out, spec, engine, **extra)
    write_checkpoint(out, state, spec)


def prepare(out: Path, spec: train.RunSpec, engine: str | None, resume: bool, force: bool,
            allow_other_code: bool = False) -> tuple:
    """Check the directory, build the simulation and the starting state (fresh, or every
    learner's newest checkpointed state: ``restore_learners``).  The caller holds
    ``locked(out)``."""
    config_path = out / "config.json"
    record = run_record(spec, engine)
    code = record["code"]
    fresh, differences = True, []
    if run_files(out):
        if resume and config_path.is_file():
            saved, record = read_config(out)
            if saved != spec:
                raise RunError(f"{out} holds a run of another config; use a new --out")
            if is_finished(out):
                raise RunError(f"{out} holds a finished run (summary.json); its results stay as they are")
            differences = provenance.differences(record.get("code"), code)
            if differences and not allow_other_code:
                raise RunError(f"{out} was made by other code ({'; '.join(differences)}); "
                               "pass --allow-other-code to resume it with this code")
            if engine is not None and engine != record["engine"]:
                raise RunError(f"{out} was run on the {record['engine']} engine; resume it with "
                               f"--engine {record['engine']} or without --engine")
            engine = record["engine"]
            fresh = False
        elif resume:
            raise RunError(f"{out} is not a run directory (no config.json); nothing to resume")
        else:
            clear_for_new_run(out, force, "pass --resume to continue it or --force to replace it")
    sim = spec.simulation(engine)
    task = train.make_task(sim, spec)
    state = train.init_run(sim, task, spec)
    out.mkdir(parents=True, exist_ok=True)
    if fresh:
        # Before any checkpoint: a directory with checkpoints always says what made them.
        write_text_atomic(config_path, json.dumps(record | {"engine": sim.engine.name}, indent=1))
    restored = restore_learners(out, state, spec, writer=True)
    if restored is not None:
        state, notices = restored
        for text in notices:
            notice(text)
    if not fresh and differences:
        # Recorded once the state is restored: a resume that fails leaves no trace.
        record["resumed_with_other_code"] = record.get("resumed_with_other_code", []) + [
            {"code": code, "differences": differences}]
        write_text_atomic(config_path, json.dumps(record, indent=1))
    return sim, task, state


def execute(out: Path, spec: train.RunSpec, engine: str | None = None, resume: bool = False,
            force: bool = False, progress: bool = True,
            tensorboard: bool = True, allow_other_code: bool = False,
            group: processes.Group = processes.ALONE, checkpoint_every_s: float = CHECKPOINT_EVERY_S,
            ) -> tuple[Simulation, train.Task, train.RunState, float]:
    """Run (or resume) to the end, checkpointing every ``checkpoint_every_s`` wall seconds
    and at the end (module docstring), with a progress line
    (``progress``) and TensorBoard event files (``tensorboard``, ``mjxcpg.training.events``).
    The caller holds ``locked(out)``.  With several processes (``group``) this is process 0:
    it checks the directory and starts the run, then steps its own block of learners while the
    others run ``follow``, and once every block has its final checkpoint reads the whole
    batch's final state from them.

    Returns the simulation, task, final state and the wall time of this session."""
    sim, task, state = prepare(out, spec, engine, resume, force, allow_other_code)
    start = time.perf_counter()
    share_start(group, sim.engine.name)
    final = learn_block(out, sim, task, spec, state, progress, tensorboard, group, checkpoint_every_s)
    if group.count > 1:
        group.barrier()  # until every process has written its block's final checkpoint
        final, _ = restore_learners(out, state, spec)
    return sim, task, final, time.perf_counter() - start


def share_start(group: processes.Group, engine: str | None) -> str | None:
    """Process 0's engine for the run, to every process (None: the run is not to be run, it
    has finished); the others' states come from the run's checkpoints, not from process 0."""
    if group.count == 1:
        return engine
    return group.broadcast((engine or "").encode() if group.writer else None).decode() or None


def follow(out: Path, spec: train.RunSpec, group: processes.Group, tensorboard: bool = True,
           checkpoint_every_s: float = CHECKPOINT_EVERY_S) -> None:
    """A process other than 0: once process 0 has checked ``out`` and started the run, step
    this process's block of learners (``Group.block``) from their newest checkpointed state
    to the end; nothing when process 0 found the run finished."""
    engine = share_start(group, None)
    if engine is not None:
        sim = spec.simulation(engine)
        task = train.make_task(sim, spec)
        state = train.init_run(sim, task, spec)
        restored = restore_learners(out, state, spec)
        learn_block(out, sim, task, spec, state if restored is None else restored[0], False, tensorboard, group,
                    checkpoint_every_s)
    group.barrier()  # this block's final checkpoint is on disk


def block_spec(spec: train.RunSpec, rows: np.ndarray) -> train.RunSpec:
    """``spec``'s learners ``rows``, as a run of their own."""
    k_e = None if spec.k_e is None else tuple(spec.k_e[i] for i in rows)
    return dataclasses.replace(spec, k_s=tuple(spec.k_s[i] for i in rows), seeds=tuple(spec.seeds[i] for i in rows),
                               k_e=k_e)


def _first_rows(tree, count: int):
    return jax.tree.map(lambda x: x[:count], tree)


def learn_block(out: Path, sim: Simulation, task: train.Task, spec: train.RunSpec, state: train.RunState,
                progress: bool, tensorboard: bool, group: processes.Group = processes.ALONE,
                checkpoint_every_s: float = CHECKPOINT_EVERY_S, checkpointed: bool = True) -> train.RunState:
    """Chunks until every learner of this process's block (the whole batch, alone) is done;
    after each, the progress line and the event files of ``out``, and (if ``checkpointed``)
    a checkpoint and a flush of the events when ``checkpoint_every_s`` have passed since the
    last or the block has ended (``train.run_until_done``).  A stop that the group asks for
    (``Group.stop_requested``) writes a checkpoint and raises.  Returns the block's final
    state (alone: the run's)."""
    if group.count == 1:
        block, learners = np.arange(spec.batch), None
        checkpoints = manager_of(out, writer=True) if checkpointed else None
    else:
        block = learners = group.block(spec.batch)
        if len(block) == 0:
            return state
        checkpoints = manager_at(part_directory(out, block), writer=True)
        if group.writer and progress:
            notice(f"process 0 of {group.count} steps learners {block[0]}-{block[-1]} of {spec.batch}; "
                   "the progress line counts those")
    # A lone learner of a wider run runs beside a copy of itself, as it would in the run's
    # batch: XLA compiles a batch of one differently.
    rows = block if len(block) >= 2 or spec.batch < 2 else np.repeat(block, 2)
    real = len(block)
    mine = block_spec(spec, rows)
    if len(rows) != spec.batch:
        state = jax.tree.map(lambda x: np.asarray(x)[rows], state)
    try:
        final = _learn_rows(out, sim, task, spec, mine, state, real, learners, checkpoints, progress, tensorboard,
                            group, checkpoint_every_s)
    except BaseException:
        if checkpoints is not None:
            # Waited for, not closed: closing ends orbax's event loop under the writes of a
            # failed save still pending, whose callbacks then print tracebacks.
            written(Path(checkpoints.directory), checkpoints.wait_until_finished)
        raise
    if checkpoints is not None:
        directory = Path(checkpoints.directory)
        written(directory, checkpoints.wait_until_finished)
        written(directory, checkpoints.close)  # its writer threads, which a long-lived process would keep
    return final


def _learn_rows(out, sim, task, spec, mine: train.RunSpec, state: train.RunState, real: int, learners,
                checkpoints: ocp.CheckpointManager | None, progress: bool, tensorboard: bool,
                group: processes.Group, checkpoint_every_s: float) -> train.RunState:
    """``learn_block``'s loop over ``mine``, the block's spec; its first ``real`` rows are its
    learners (``learners`` in the run; None: the whole batch), the rest a copy."""
    k_s, seeds = mine.k_s[:real], mine.seeds[:real]
    run_events = events.RunEvents(out, k_s, seeds, learners, run_progress=group.writer) if tensorboard else None
    book = jax.device_get(_first_rows(state.learners.book, real))
    done = train.done_mask(task, state.learners)[:real]
    line = RunProgress(spec.trial, task.dt, sim.engine.substeps, k_s, done, int(np.sum(book.trial)), progress,
                       sim.engine.threads_for)
    if run_events is not None:  # a resumed checkpoint may hold trials that a kill kept from the events
        run_events.write_trials(book, done)

    last_saved = time.monotonic()

    def save(new_state: train.RunState) -> None:
        written(Path(checkpoints.directory), lambda: save_next(checkpoints, _first_rows(new_state, real), spec,
                                                                learners))

    def on_chunk(new_state: train.RunState, counts: dict) -> None:
        nonlocal last_saved
        book, done = jax.device_get(_first_rows(new_state.learners.book, real)), counts["done"][:real]
        stop = group.stop_requested()
        due = done.all() or stop is not None or time.monotonic() - last_saved >= checkpoint_every_s
        if due:
            last_saved = time.monotonic()
            if checkpoints is not None:
                save(new_state)
        periods = np.asarray(jax.device_get(new_state.learners.period))[:real]
        measures = line.update(book, periods, done, counts["robot_steps_per_s"], counts["compile_s"])
        if run_events is not None:
            run_events.write_trials(book, done)
            run_events.write_progress(measures["trials"], {k: v for k, v in measures.items()
                                                           if k != "trials" and v is not None})
            if due:
                run_events.flush()
        if stop is not None:
            if checkpoints is not None:
                written(Path(checkpoints.directory), checkpoints.wait_until_finished)
            raise processes.ProcessError(f"process {group.index} stops: {stop}; it wrote its checkpoint: "
                                         "rerun with --resume")

    try:
        return train.run_until_done(sim, task, mine, state, on_chunk)
    finally:
        line.close()
        if run_events is not None:
            run_events.close()


def check_learners(spec: train.RunSpec, learners) -> list[int]:
    """``learners`` as indices into ``spec``'s batch (all of them when None), each in range."""
    chosen = list(range(spec.batch)) if learners is None else [int(k) for k in learners]
    for k in chosen:
        if not 0 <= k < spec.batch:
            raise RunError(f"learner {k} is out of range: the run has {spec.batch} learner(s)")
    return chosen


def read_config(out: Path) -> tuple[train.RunSpec, dict]:
    """The spec of the run in ``out`` and its whole config.json record."""
    config_path = out / "config.json"
    if not out.is_dir():
        raise RunError(f"no run directory at {out}")
    if not config_path.is_file():
        raise RunError(f"{out} has no config.json; not a run directory")
    try:
        record = json.loads(config_path.read_text())
        return config.spec_from_dict(record["spec"]), record
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise RunError(f"{config_path} is damaged: {error}") from None


class LoadedRun(NamedTuple):
    spec: train.RunSpec
    sim: Simulation
    task: train.Task
    state: train.RunState  # the latest checkpoint's


def load_run(out: Path, engine: str | None = None, slope_deg: float = 0.0, robot: str = "nominal") -> LoadedRun:
    """The spec, simulation, task and final state of a finished or interrupted run.

    On ``robot="hardware"`` (see ``mjxcpg.physics.hardware``) the learners are the checkpoint's and the
    physics is the hardware robot's, standing: a checkpoint holds nominal physics only.  Likewise
    on an engine other than the recorded one, whose state has another layout.
    """
    out = Path(out)
    spec, record = read_config(out)
    sim = spec.simulation(engine or record["engine"], slope_deg=slope_deg, robot=robot)
    task = train.make_task(sim, spec)
    # The checkpoint holds the physics in the recorded engine's layout.
    recorded = sim if sim.engine.name == record["engine"] and robot == "nominal" else spec.simulation(
        record["engine"])
    restored = restore_learners(out, train.init_run(recorded, task, spec), spec)
    if restored is None:
        raise RunError(f"{out} has no checkpoint")
    state, notices = restored
    for text in notices:
        notice(text)
    if recorded is not sim:
        state = state._replace(physics=sim.engine.init(sim.qpos0, spec.batch))
    return LoadedRun(spec, sim, task, state)
