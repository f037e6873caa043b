"""A run's orbax checkpoints: the full state after a chunk (``runs``: how often), with the
config's sha256 and a sha256 of the leaves; the newest intact one read back, damaged ones
set aside."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjxcpg.training import config, train

CHECKPOINTS = "checkpoints"
DAMAGED_CHECKPOINTS = "damaged_checkpoints"
# Checkpoints kept: the newest, and older ones to fall back on should it be damaged.
KEPT_CHECKPOINTS = 3
_READ_ATTEMPTS = 4


class RunError(ValueError):
    """A run directory that cannot be used as asked."""


def first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [type(error).__name__])[0][:200]


def _fingerprint(spec_dict: dict) -> np.ndarray:
    """The config's identity, stored in every checkpoint beside the state."""
    text = json.dumps(spec_dict, sort_keys=True).encode()
    return np.frombuffer(hashlib.sha256(text).digest(), np.uint8)


def _accepted_fingerprints(spec: train.RunSpec) -> list[np.ndarray]:
    """The fingerprints a checkpoint of ``spec`` may hold: this code's, and earlier code's
    (``config.earlier_spec_dicts``)."""
    return [_fingerprint(d) for d in [config.spec_to_dict(spec), *config.earlier_spec_dicts(spec)]]


def _leaves_sha256(leaves: dict) -> np.ndarray:
    """One sha256 over the leaves' names, dtypes, shapes and bytes."""
    digest = hashlib.sha256()
    for key in sorted(leaves):
        x = np.ascontiguousarray(leaves[key])
        digest.update(f"{key}:{x.dtype.str}:{x.shape}".encode())
        digest.update(x.tobytes())
    return np.frombuffer(digest.digest(), np.uint8)


def checkpoint_leaves(state: Any, spec: train.RunSpec) -> dict:
    """The state's leaves by index, the config's fingerprint, and a sha256 of both.  Empty
    leaves (MJX's data holds some, e.g. ``act`` of a model without actuator dynamics) are
    left out: orbax cannot save them, and ``restore_state`` takes them from its template."""
    leaves = {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state)) if np.size(x) > 0}
    leaves["config_sha256"] = _fingerprint(config.spec_to_dict(spec))
    return leaves | {"leaves_sha256": _leaves_sha256(leaves)}


def manager_of(out: Path, writer: bool = False) -> ocp.CheckpointManager:
    """Orbax's view of ``out``'s checkpoints; a ``writer`` (holding the lock) also clears the
    temporary directories of writes that a kill or a failure left unfinished.

    Among several processes (``jax.process_count() > 1``) the one that asks (process 0 of a
    run) reads and writes the checkpoints alone: orbax's multi-process options name it as
    the only active process, so that orbax waits for no other at its barriers."""
    directory = out.resolve() / CHECKPOINTS
    extra = {}
    if jax.process_count() > 1:
        me = jax.process_index()
        extra["multiprocessing_options"] = ocp.options.MultiprocessingOptions(primary_host=me,
                                                                              active_processes={me})
        if writer:  # orbax does not make the directory for a subset of the processes
            directory.mkdir(parents=True, exist_ok=True)
    return ocp.CheckpointManager(
        directory, options=ocp.CheckpointManagerOptions(
            max_to_keep=KEPT_CHECKPOINTS, create=writer and not extra, cleanup_tmp_directories=writer,
            read_only=not writer, **extra))


def written(out: Path, action: Callable[[], Any]) -> Any:
    """``action``, a checkpoint write (or the wait for one), its failure a one-line error."""
    try:
        return action()
    except Exception as error:  # orbax re-raises what its writer threads met, of many types
        raise RunError(f"cannot write a checkpoint in {out / CHECKPOINTS}: {first_line(error)}; "
                       "the checkpoints written before it are kept") from None


def save_next(manager: ocp.CheckpointManager, state: Any, spec: train.RunSpec) -> None:
    """Start saving ``state`` as the step after the latest (orbax writes in the background)."""
    manager.save((manager.latest_step() or 0) + 1, args=ocp.args.StandardSave(checkpoint_leaves(state, spec)))


def write_checkpoint(out: Path, state: Any, spec: train.RunSpec) -> None:
    """Save ``state`` as the next checkpoint of the run directory ``out`` and wait for it."""
    with contextlib.closing(manager_of(out, writer=True)) as manager:
        written(out, lambda: save_next(manager, state, spec))
        written(out, manager.wait_until_finished)


class DamagedCheckpoint(Exception):
    """A checkpoint that does not read back as it was written."""


def _read_checkpoint(manager: ocp.CheckpointManager, step: int) -> dict:
    """The leaves of checkpoint ``step``, checked against the sha256 saved with them
    (checkpoints written before there was one are taken as they read)."""
    try:
        # Restored as saved, not onto a template: a foreign tree is then ours to report.
        leaves = dict(manager.restore(step, args=ocp.args.StandardRestore()))
    except Exception as error:  # orbax raises many types for a damaged checkpoint
        raise DamagedCheckpoint(first_line(error)) from None
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
    expected = checkpoint_leaves(template, spec)
    expected.pop("leaves_sha256")
    leaves.pop("leaves_sha256", None)
    expected.pop("config_sha256")
    stored = leaves.pop("config_sha256", None)
    if not any(np.array_equal(stored, f) for f in _accepted_fingerprints(spec)):
        raise RunError("the checkpoint was written by another config")
    if leaves.keys() != expected.keys() or any(
            leaves[k].shape != v.shape or leaves[k].dtype != v.dtype for k, v in expected.items()):
        raise RunError("the checkpoint does not match the state this code builds (another version "
                       "of mjxcpg, or another engine's state, wrote it)")
    template_leaves, treedef = jax.tree.flatten(template)
    state = jax.tree.unflatten(treedef, [jax.numpy.asarray(leaves.get(f"{i:04d}", x))
                                         for i, x in enumerate(template_leaves)])
    return state, step, damaged


def damage_text(step: int, damaged: list[tuple[int, str]]) -> str:
    return "; ".join(f"checkpoint {d} is damaged ({why})" for d, why in damaged) + f"; using checkpoint {step}"


def set_aside(out: Path, steps: list[int]) -> Path:
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
