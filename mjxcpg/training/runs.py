"""Run directories: config, orbax checkpoints every chunk, resume, results, a lock.

``DIR/config.json`` (the run spec, the engine, and the code that made the run: see
``mjxcpg.training.provenance``), ``DIR/checkpoints/`` (orbax, the full state: physics, CPG, learner
weights, traces, RNG keys, bookkeeping, with the config's sha256 and a sha256 of it all),
``DIR/summary.json`` (written last: a run directory that holds it is finished), ``DIR/.lock``.
A run resumed from a checkpoint ends exactly as an uninterrupted one: chunk boundaries and
every random draw are functions of the config and seeds alone.

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
import fcntl
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjxcpg.control.sim import Simulation, make_simulation
from mjxcpg.training import config, events, provenance, train
from mjxcpg.training.files import write_text_atomic
from mjxcpg.training.progress import RunProgress

LOCK_NAME = ".lock"
CHECKPOINTS = "checkpoints"
DAMAGED_CHECKPOINTS = "damaged_checkpoints"
# Checkpoints kept: the newest, and older ones to fall back on should it be damaged.
KEPT_CHECKPOINTS = 3
_READ_ATTEMPTS = 4


class RunError(ValueError):
    """A run directory that cannot be used as asked."""


def notice(text: str) -> None:
    """One line to the user, beside the progress bar."""
    print(f"mjxcpg: {text}", file=sys.stderr, flush=True)


def _first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [type(error).__name__])[0][:200]


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


def remove_run_files(out: Path) -> None:
    """Empty ``out`` for a new run (``--force``), keeping the lock its caller holds."""
    for path in run_files(out):
        shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()


def is_finished(out: Path) -> bool:
    return (out / "summary.json").is_file()


# ---------------------------------------------------------------- checkpoints

def _fingerprint(spec: train.RunSpec) -> np.ndarray:
    """The config's identity, stored in every checkpoint beside the state."""
    text = json.dumps(config.spec_to_dict(spec), sort_keys=True).encode()
    return np.frombuffer(hashlib.sha256(text).digest(), np.uint8)


def _leaves_sha256(leaves: dict) -> np.ndarray:
    """One sha256 over the leaves' names, dtypes, shapes and bytes."""
    digest = hashlib.sha256()
    for key in sorted(leaves):
        x = np.ascontiguousarray(leaves[key])
        digest.update(f"{key}:{x.dtype.str}:{x.shape}".encode())
        digest.update(x.tobytes())
    return np.frombuffer(digest.digest(), np.uint8)


def _leaves(state: Any, spec: train.RunSpec) -> dict:
    """The state's leaves by index, the config's fingerprint, and a sha256 of both.  Empty
    leaves (MJX's data holds some, e.g. ``act`` of a model without actuator dynamics) are
    left out: orbax cannot save them, and ``restore_state`` takes them from its template."""
    leaves = {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state)) if np.size(x) > 0}
    leaves["config_sha256"] = _fingerprint(spec)
    return leaves | {"leaves_sha256": _leaves_sha256(leaves)}


def _manager(out: Path, writer: bool = False) -> ocp.CheckpointManager:
    """Orbax's view of ``out``'s checkpoints; a ``writer`` (holding the lock) also clears the
    temporary directories of writes that a kill or a failure left unfinished."""
    return ocp.CheckpointManager(
        out.resolve() / CHECKPOINTS,
        options=ocp.CheckpointManagerOptions(max_to_keep=KEPT_CHECKPOINTS, create=writer,
                                             cleanup_tmp_directories=writer, read_only=not writer))


def _written(out: Path, action: Callable[[], Any]) -> Any:
    """``action``, a checkpoint write (or the wait for one), its failure a one-line error."""
    try:
        return action()
    except Exception as error:  # orbax re-raises what its writer threads met, of many types
        raise RunError(f"cannot write a checkpoint in {out / CHECKPOINTS}: {_first_line(error)}; "
                       "the checkpoints written before it are kept") from None


def _save_next(manager: ocp.CheckpointManager, state: Any, spec: train.RunSpec) -> None:
    """Start saving ``state`` as the step after the latest (orbax writes in the background)."""
    manager.save((manager.latest_step() or 0) + 1, args=ocp.args.StandardSave(_leaves(state, spec)))


def write_checkpoint(out: Path, state: Any, spec: train.RunSpec) -> None:
    """Save ``state`` as the next checkpoint of the run directory ``out`` and wait for it."""
    manager = _manager(out, writer=True)
    _written(out, lambda: _save_next(manager, state, spec))
    _written(out, manager.wait_until_finished)


class DamagedCheckpoint(Exception):
    """A checkpoint that does not read back as it was written."""


def _read_checkpoint(manager: ocp.CheckpointManager, step: int) -> dict:
    """The leaves of checkpoint ``step``, checked against the sha256 saved with them
    (checkpoints written before there was one are taken as they read)."""
    try:
        # Restored as saved, not onto a template: a foreign tree is then ours to report.
        leaves = dict(manager.restore(step, args=ocp.args.StandardRestore()))
    except Exception as error:  # orbax raises many types for a damaged checkpoint
        raise DamagedCheckpoint(_first_line(error)) from None
    saved = leaves.pop("leaves_sha256", None)
    if saved is not None and not np.array_equal(saved, _leaves_sha256(leaves)):
        raise DamagedCheckpoint("its contents do not match their sha256")
    return leaves


def newest_intact(manager: ocp.CheckpointManager) -> tuple[int, dict, list[tuple[int, str]]]:
    """The newest checkpoint that reads back whole: its step, its leaves, and the newer,
    damaged ones as (step, why)."""
    for attempt in range(_READ_ATTEMPTS):
        damaged = []
        for step in sorted(manager.all_steps(), reverse=True):
            try:
                return step, _read_checkpoint(manager, step), damaged
            except DamagedCheckpoint as error:
                # A step that vanished while read was deleted by a run that is writing newer ones.
                if (manager.directory / str(step)).exists():
                    damaged.append((step, str(error)))
        if len(damaged) == len(manager.all_steps()) or attempt == _READ_ATTEMPTS - 1:
            break
        time.sleep(0.5)
        manager.reload()
    if not damaged:
        raise RunError(f"{manager.directory} holds no checkpoint")
    raise RunError(f"no intact checkpoint in {manager.directory}: "
                   + "; ".join(f"{step}: {why}" for step, why in damaged) + " (nothing was moved or deleted)")


def restore_state(manager: ocp.CheckpointManager, template: Any,
                  spec: train.RunSpec) -> tuple[Any, int, list[tuple[int, str]]]:
    """The newest intact checkpoint, checked against the config that asks for it: the state,
    its step, and the newer, damaged steps as (step, why)."""
    step, leaves, damaged = newest_intact(manager)
    expected = _leaves(template, spec)
    expected.pop("leaves_sha256")
    leaves.pop("leaves_sha256", None)
    if not np.array_equal(leaves.pop("config_sha256", None), expected.pop("config_sha256")):
        raise RunError("the checkpoint was written by another config")
    if leaves.keys() != expected.keys() or any(
            leaves[k].shape != v.shape or leaves[k].dtype != v.dtype for k, v in expected.items()):
        raise RunError("the checkpoint does not match this version's state; rerun without --resume")
    template_leaves, treedef = jax.tree.flatten(template)
    state = jax.tree.unflatten(treedef, [jax.numpy.asarray(leaves.get(f"{i:04d}", x))
                                         for i, x in enumerate(template_leaves)])
    return state, step, damaged


def _damage_text(step: int, damaged: list[tuple[int, str]]) -> str:
    return "; ".join(f"checkpoint {d} is damaged ({why})" for d, why in damaged) + f"; using checkpoint {step}"


def _set_aside(out: Path, steps: list[int]) -> Path:
    """Move the damaged checkpoints ``steps`` out of orbax's sight, into DIR/damaged_checkpoints/."""
    aside = out / DAMAGED_CHECKPOINTS
    aside.mkdir(exist_ok=True)
    for step in steps:
        target = aside / str(step)
        copies = 0
        while target.exists():
            copies += 1
            target = aside / f"{step}-{copies}"
        os.replace(out / CHECKPOINTS / str(step), target)
    return aside


# ---------------------------------------------------------------- running

def prepare(out: Path, spec: train.RunSpec, engine: str | None, resume: bool, force: bool,
            allow_other_code: bool = False) -> tuple:
    """Check the directory, build the simulation and the starting state (fresh or resumed).
    The caller holds ``locked(out)``."""
    config_path = out / "config.json"
    code = provenance.code_identity()
    record = {"spec": config.spec_to_dict(spec), "engine": engine, "code": code}
    fresh = True
    if run_files(out):
        if resume and config_path.is_file():
            record = json.loads(config_path.read_text())
            if record["spec"] != config.spec_to_dict(spec):
                raise RunError(f"{out} holds a run of another config; use a new --out")
            if is_finished(out):
                raise RunError(f"{out} holds a finished run (summary.json); its results stay as they are")
            differences = provenance.differences(record.get("code"), code)
            if differences and not allow_other_code:
                raise RunError(f"{out} was made by other code ({'; '.join(differences)}); "
                               "pass --allow-other-code to resume it with this code")
            if differences:
                record["resumed_with_other_code"] = record.get("resumed_with_other_code", []) + [
                    {"code": code, "differences": differences}]
                write_text_atomic(config_path, json.dumps(record, indent=1))
            engine = engine or record["engine"]
            fresh = False
        elif force:
            remove_run_files(out)
        elif resume:
            raise RunError(f"{out} is not a run directory (no config.json); nothing to resume")
        else:
            raise RunError(f"{out} exists; pass --resume to continue it or --force to replace it")
    sim = make_simulation(engine, params=spec.controller, physics_dt=spec.physics_dt)
    task = train.make_task(sim, spec)
    state = train.init_run(sim, task, spec)
    out.mkdir(parents=True, exist_ok=True)
    if fresh:
        # Before any checkpoint: a directory with checkpoints always says what made them.
        write_text_atomic(config_path, json.dumps(record | {"engine": sim.engine.name}, indent=1))
    manager = _manager(out, writer=True)
    if manager.all_steps():
        state, step, damaged = restore_state(manager, state, spec)
        if damaged:
            aside = _set_aside(out, [d for d, _ in damaged])
            notice(f"{out}: {_damage_text(step, damaged)}; the damaged ones are moved to {aside}")
            manager.reload()
    return sim, task, state, manager


def execute(out: Path, spec: train.RunSpec, engine: str | None = None, resume: bool = False,
            force: bool = False, progress: bool = True,
            tensorboard: bool = True, allow_other_code: bool = False,
            ) -> tuple[Simulation, train.Task, train.RunState, float]:
    """Run (or resume) to the end, checkpointing after every chunk, with a progress line
    (``progress``) and TensorBoard event files (``tensorboard``, ``mjxcpg.training.events``).
    The caller holds ``locked(out)``.

    Returns the simulation, task, final state and the wall time of this session."""
    sim, task, state, manager = prepare(out, spec, engine, resume, force, allow_other_code)
    start = time.perf_counter()
    try:
        state = learn_to_end(out, sim, task, spec, state, manager, progress, tensorboard)
    finally:
        _written(out, manager.wait_until_finished)
    return sim, task, state, time.perf_counter() - start


def learn_to_end(out: Path, sim: Simulation, task: train.Task, spec: train.RunSpec, state: train.RunState,
                 checkpoints: ocp.CheckpointManager | None, progress: bool, tensorboard: bool) -> train.RunState:
    """Chunks until every learner is done; after each, a checkpoint (unless ``checkpoints`` is
    None), the progress line and the event files of ``out``."""
    run_events = events.RunEvents(out, spec.k_s, spec.seeds) if tensorboard else None
    book = jax.device_get(state.learners.book)
    done = train.done_mask(task, state.learners)
    line = RunProgress(spec.trial, task.dt, sim.engine.substeps, spec.k_s, done, int(np.sum(book.trial)), progress)
    if run_events is not None:  # a resumed checkpoint may hold trials that a kill kept from the events
        run_events.write_trials(book, done)

    def on_chunk(new_state: train.RunState, counts: dict) -> None:
        if checkpoints is not None:
            _written(out, lambda: _save_next(checkpoints, new_state, spec))
        book = jax.device_get(new_state.learners.book)
        done = train.done_mask(task, new_state.learners)
        measures = line.update(book, np.asarray(jax.device_get(new_state.learners.period)), done,
                               counts["robot_steps_per_s"])
        if run_events is not None:
            run_events.write_trials(book, done)
            run_events.write_progress(measures["trials"], {k: v for k, v in measures.items()
                                                           if k != "trials" and v is not None})

    try:
        return train.run_until_done(sim, task, spec, state, on_chunk)
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
    physics is the hardware robot's, standing: a checkpoint holds nominal physics only.
    """
    out = Path(out)
    spec, record = read_config(out)
    manager = _manager(out)
    if not manager.all_steps():
        raise RunError(f"{out} has no checkpoint")
    sim = make_simulation(engine or record["engine"], slope_deg, params=spec.controller,
                          physics_dt=spec.physics_dt, robot=robot)
    task = train.make_task(sim, spec)
    # The checkpoint holds the physics in the recorded engine's layout.
    recorded = sim if sim.engine.name == record["engine"] and robot == "nominal" else make_simulation(
        record["engine"], params=spec.controller, physics_dt=spec.physics_dt)
    state, step, damaged = restore_state(manager, train.init_run(recorded, task, spec), spec)
    if damaged:
        notice(f"{out}: {_damage_text(step, damaged)}")
    if robot != "nominal":
        state = state._replace(physics=sim.engine.init(sim.qpos0, spec.batch))
    return LoadedRun(spec, sim, task, state)
