"""Run directories: config, orbax checkpoints every chunk, resume, results.

``DIR/config.json`` (the run spec and engine), ``DIR/checkpoints/`` (orbax, the full state:
physics, CPG, learner weights, traces, RNG keys, bookkeeping), ``DIR/summary.json``.
A run resumed from its last checkpoint ends exactly as an uninterrupted one: chunk
boundaries and every random draw are functions of the config and seeds alone.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjxcpg.control.sim import Simulation, make_simulation
from mjxcpg.training import config, events, train
from mjxcpg.training.progress import RunProgress


_READ_ATTEMPTS = 4


class RunError(ValueError):
    """A run directory that cannot be used as asked."""


def _fingerprint(spec: train.RunSpec) -> np.ndarray:
    """The config's identity, stored in every checkpoint beside the state."""
    text = json.dumps(config.spec_to_dict(spec), sort_keys=True).encode()
    return np.frombuffer(hashlib.sha256(text).digest(), np.uint8)


def _leaves(state: Any, spec: train.RunSpec) -> dict:
    """The state's leaves by index, and the config's fingerprint.  Empty leaves (MJX's data
    holds some, e.g. ``act`` of a model without actuator dynamics) are left out: orbax cannot
    save them, and ``restore_state`` takes them from its template."""
    leaves = {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state)) if np.size(x) > 0}
    return leaves | {"config_sha256": _fingerprint(spec)}


def _manager(out: Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(out.resolve() / "checkpoints",
                                 options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True))


def _save_next(manager: ocp.CheckpointManager, state: Any, spec: train.RunSpec) -> None:
    """Start saving ``state`` as the step after the latest (orbax writes in the background)."""
    manager.save((manager.latest_step() or 0) + 1, args=ocp.args.StandardSave(_leaves(state, spec)))


def write_checkpoint(out: Path, state: Any, spec: train.RunSpec) -> None:
    """Save ``state`` as the next checkpoint of the run directory ``out`` and wait for it."""
    manager = _manager(out)
    _save_next(manager, state, spec)
    manager.wait_until_finished()


def prepare(out: Path, spec: train.RunSpec, engine: str | None, resume: bool, force: bool) -> tuple:
    """Check the directory, build the simulation and the starting state (fresh or resumed)."""
    config_path = out / "config.json"
    record = {"spec": config.spec_to_dict(spec), "engine": engine}
    if out.exists() and any(out.iterdir()):
        if resume and config_path.is_file():
            saved = json.loads(config_path.read_text())
            if saved["spec"] != record["spec"]:
                raise RunError(f"{out} holds a run of another config; use a new --out")
            engine = engine or saved["engine"]
        elif force:
            shutil.rmtree(out)
        elif resume:
            raise RunError(f"{out} is not a run directory (no config.json); nothing to resume")
        else:
            raise RunError(f"{out} exists; pass --resume to continue it or --force to replace it")
    sim = make_simulation(engine, params=spec.controller, physics_dt=spec.physics_dt)
    record["engine"] = sim.engine.name
    task = train.make_task(sim, spec)
    state = train.init_run(sim, task, spec)
    out.mkdir(parents=True, exist_ok=True)
    manager = _manager(out)
    if manager.latest_step() is not None:
        state = restore_state(manager, state, spec)
    else:
        config_path.write_text(json.dumps(record, indent=1))
    return sim, task, state, manager


def restore_state(manager: ocp.CheckpointManager, template: Any, spec: train.RunSpec) -> Any:
    """The latest checkpoint, checked against the config that asks for it."""
    expected = _leaves(template, spec)
    # A running sweep writes a step and deletes an old one while we read: look again, a few times.
    for attempt in range(_READ_ATTEMPTS):
        try:
            # Restored as saved, not onto ``expected``: a foreign tree is then ours to report.
            leaves = dict(manager.restore(manager.latest_step(), args=ocp.args.StandardRestore()))
            break
        except Exception as error:  # orbax raises many types for a damaged or foreign checkpoint
            if attempt == _READ_ATTEMPTS - 1:
                raise RunError(f"cannot read the checkpoint: {str(error).splitlines()[0][:200]}") from None
            time.sleep(0.5)
            manager.reload()
    if not np.array_equal(leaves.pop("config_sha256", None), expected.pop("config_sha256")):
        raise RunError("the checkpoint was written by another config")
    if leaves.keys() != expected.keys() or any(
            leaves[k].shape != v.shape or leaves[k].dtype != v.dtype for k, v in expected.items()):
        raise RunError("the checkpoint does not match this version's state; rerun without --resume")
    template_leaves, treedef = jax.tree.flatten(template)
    return jax.tree.unflatten(treedef, [jax.numpy.asarray(leaves.get(f"{i:04d}", x))
                                        for i, x in enumerate(template_leaves)])


def execute(out: Path, spec: train.RunSpec, engine: str | None = None, resume: bool = False,
            force: bool = False, progress: bool = True,
            tensorboard: bool = True) -> tuple[Simulation, train.Task, train.RunState, float]:
    """Run (or resume) to the end, checkpointing after every chunk, with a progress line
    (``progress``) and TensorBoard event files (``tensorboard``, ``mjxcpg.training.events``).

    Returns the simulation, task, final state and the wall time of this session."""
    sim, task, state, manager = prepare(out, spec, engine, resume, force)
    start = time.perf_counter()
    try:
        state = learn_to_end(out, sim, task, spec, state, manager, progress, tensorboard)
    finally:
        manager.wait_until_finished()
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
            _save_next(checkpoints, new_state, spec)
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
    if manager.latest_step() is None:
        raise RunError(f"{out} has no checkpoint")
    sim = make_simulation(engine or record["engine"], slope_deg, params=spec.controller,
                          physics_dt=spec.physics_dt, robot=robot)
    task = train.make_task(sim, spec)
    # The checkpoint holds the physics in the recorded engine's layout.
    recorded = sim if sim.engine.name == record["engine"] and robot == "nominal" else make_simulation(
        record["engine"], params=spec.controller, physics_dt=spec.physics_dt)
    state = restore_state(manager, train.init_run(recorded, task, spec), spec)
    if robot != "nominal":
        state = state._replace(physics=sim.engine.init(sim.qpos0, spec.batch))
    return LoadedRun(spec, sim, task, state)
