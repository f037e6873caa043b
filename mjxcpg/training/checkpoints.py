"""A run's orbax checkpoints: the full state after a chunk (``runs``: how often), with the
config's sha256 and a sha256 of the leaves; the newest intact one read back, damaged ones
set aside.

One process writes the whole batch in ``DIR/checkpoints/``.  Several processes each write
their own block of learners, in ``DIR/checkpoint_parts/learners-FIRST-LAST/``, with the
learners' indices beside the state; nothing passes through another process.  Learners are
independent and each one's random draws follow its own period count, so a learner's state
after a chunk is the same in any block: reading a run (``restore_learners``) takes each
learner from whichever checkpoint holds it furthest on, and so reads any mix of the two
layouts, from any process count.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjxcpg.training import config, train

CHECKPOINTS = "checkpoints"
CHECKPOINT_PARTS = "checkpoint_parts"
DAMAGED_CHECKPOINTS = "damaged_checkpoints"
# Checkpoints kept: the newest, and older ones to fall back on should it be damaged.
KEPT_CHECKPOINTS = 3
_READ_ATTEMPTS = 4


class RunError(ValueError):
    """A run directory that cannot be used as asked."""


def first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [type(error).__name__])[0][:500]


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


def checkpoint_leaves(state: Any, spec: train.RunSpec, learners: np.ndarray | None = None) -> dict:
    """The state's leaves by index, the config's fingerprint, the learners' indices in the
    run when ``state`` holds a block of them, and a sha256 of all.  Empty leaves (MJX's data
    holds some, e.g. ``act`` of a model without actuator dynamics) are left out: orbax cannot
    save them, and ``restore_learners`` takes them from its template."""
    leaves = {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state)) if np.size(x) > 0}
    leaves["config_sha256"] = _fingerprint(config.spec_to_dict(spec))
    if learners is not None:
        leaves["learners"] = np.asarray(learners, np.int64)
    return leaves | {"leaves_sha256": _leaves_sha256(leaves)}


def part_directory(out: Path, learners: np.ndarray) -> Path:
    """Where a process writes the checkpoints of its block ``learners`` (contiguous)."""
    return out / CHECKPOINT_PARTS / f"learners-{int(learners[0]):05d}-{int(learners[-1]):05d}"


def manager_of(out: Path, writer: bool = False) -> ocp.CheckpointManager:
    """Orbax's view of the whole-batch checkpoints of ``out`` (``manager_at``)."""
    return manager_at(out / CHECKPOINTS, writer)


def manager_at(directory: Path, writer: bool = False) -> ocp.CheckpointManager:
    """Orbax's view of the checkpoints in ``directory``; a ``writer`` also clears the
    temporary directories of writes that a kill or a failure left unfinished.  (Several
    processes of a run are each a JAX program of their own, ``mjxcpg.jaxutil.processes``:
    orbax writes for the one that asks.)"""
    if writer:
        _drop_closed_loop_callbacks()
        _remove_unfinished_writes(directory)
    return ocp.CheckpointManager(
        directory.resolve(), options=ocp.CheckpointManagerOptions(
            max_to_keep=KEPT_CHECKPOINTS, create=writer, cleanup_tmp_directories=writer, read_only=not writer))


def _remove_unfinished_writes(directory: Path) -> None:
    """Remove the temporary directories of writes that a killed process left in ``directory``.

    Only a writer calls this, and each writer owns its directory (the run's lock, or its own
    block's part), so no live write owns one.  Orbax's own clean-up is not enough: after a
    kill during the write of step n, a resume that writes step n again lost its new temporary
    directory of the same name ("No such file or directory: n.orbax-checkpoint-tmp")."""
    for path in directory.glob("*.orbax-checkpoint-tmp*"):
        shutil.rmtree(path, ignore_errors=True)


def written(directory: Path, action: Callable[[], Any]) -> Any:
    """``action``, a checkpoint write into ``directory`` (or the wait for one), its failure
    a one-line error."""
    try:
        return action()
    except Exception as error:  # orbax re-raises what its writer threads met, of many types
        raise RunError(f"cannot write a checkpoint in {directory}: {first_line(error)}; "
                       "the checkpoints written before it are kept") from None


def _is_closed_loop_callback(unraisable) -> bool:
    return (unraisable.object is None and unraisable.exc_type is RuntimeError
            and str(unraisable.exc_value) == "Event loop is closed")


def _drop_closed_loop_callbacks() -> None:
    """Drop the unraisable errors that a failed save's writes still pending raise: orbax ends
    the save's event loop at its first error, and each pending tensorstore write's callback
    then raises "Event loop is closed" into ``sys.unraisablehook``, a traceback apiece, from
    a thread of its own.  The failure reaches the user as ``written``'s one line; other
    unraisable errors show as before."""
    previous = sys.unraisablehook
    if getattr(previous, "drops_closed_loop_callbacks", False):
        return

    def hook(unraisable) -> None:
        if not _is_closed_loop_callback(unraisable):
            previous(unraisable)

    hook.drops_closed_loop_callbacks = True
    sys.unraisablehook = hook


def save_next(manager: ocp.CheckpointManager, state: Any, spec: train.RunSpec,
              learners: np.ndarray | None = None) -> None:
    """Start saving ``state`` (of the block ``learners``, or of the whole batch) as the step
    after the latest (orbax writes in the background)."""
    manager.save((manager.latest_step() or 0) + 1,
                 args=ocp.args.StandardSave(checkpoint_leaves(state, spec, learners)))


def write_checkpoint(out: Path, state: Any, spec: train.RunSpec) -> None:
    """Save ``state`` as the next checkpoint of the run directory ``out`` and wait for it."""
    with contextlib.closing(manager_of(out, writer=True)) as manager:
        written(out / CHECKPOINTS, lambda: save_next(manager, state, spec))
        written(out / CHECKPOINTS, manager.wait_until_finished)


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


def checkpoint_directories(out: Path) -> list[Path]:
    """The directories of ``out`` that hold checkpoints: the whole batch's, then each block's."""
    parts = sorted((out / CHECKPOINT_PARTS).glob("learners-*")) if (out / CHECKPOINT_PARTS).is_dir() else []
    return [d for d in [out / CHECKPOINTS, *parts] if d.is_dir()]


def restore_learners(out: Path, template: Any, spec: train.RunSpec,
                     writer: bool = False) -> tuple[Any, list[str]] | None:
    """Every learner's newest state among ``out``'s checkpoints (module docstring): each
    directory's newest intact checkpoint, and from those, learner by learner, the one whose
    period count is highest.  Returns the whole batch's state and notices for the user (the
    damaged checkpoints passed over, which a ``writer`` moves to DIR/damaged_checkpoints/),
    or None when there is no checkpoint."""
    template_leaves, treedef = jax.tree.flatten(template)
    # Which leaf holds the learners' period counts: the template's structure, numbered.
    period_leaf = jax.tree.unflatten(treedef, range(len(template_leaves))).learners.period
    expected = checkpoint_leaves(template, spec)
    for key in ("leaves_sha256", "config_sha256"):
        expected.pop(key)
    fingerprints = _accepted_fingerprints(spec)
    found, notices = [], []
    for directory in checkpoint_directories(out):
        with contextlib.closing(manager_at(directory, writer)) as manager:
            if not manager.all_steps():
                continue
            step, leaves, damaged = newest_intact(manager)
        if damaged:
            text = damage_text(step, damaged)
            if writer:
                text += f"; the damaged ones are moved to {set_aside(directory, [d for d, _ in damaged])}"
            notices.append(f"{out if directory.name == CHECKPOINTS else directory}: {text}")
        leaves.pop("leaves_sha256", None)
        fingerprint = leaves.pop("config_sha256", None)
        if not any(np.array_equal(fingerprint, f) for f in fingerprints):
            raise RunError(f"the checkpoint in {directory} was written by another config")
        learners = leaves.pop("learners", np.arange(spec.batch))
        if leaves.keys() != expected.keys() or np.any((learners < 0) | (learners >= spec.batch)) or any(
                leaves[k].shape != (len(learners), *v.shape[1:]) or leaves[k].dtype != v.dtype
                for k, v in expected.items()):
            raise RunError(f"the checkpoint in {directory} does not match the state this code builds "
                           "(another version of mjxcpg, or another engine's state, wrote it)")
        found.append((learners, leaves))
    if not found:
        return None
    periods = np.full((len(found), spec.batch), -1, np.int64)
    for s, (learners, leaves) in enumerate(found):
        periods[s, learners] = leaves[f"{period_leaf:04d}"]
    # A learner no checkpoint holds (its process was killed before its first save) keeps
    # the template's state: it starts again from its seed, as it first did.
    source = np.where(periods.max(axis=0) < 0, -1, np.argmax(periods, axis=0))
    restored = []
    for i, x in enumerate(template_leaves):
        whole = np.array(x)
        if f"{i:04d}" in expected:
            for s, (learners, leaves) in enumerate(found):
                chosen = source[learners] == s
                whole[learners[chosen]] = leaves[f"{i:04d}"][chosen]
        restored.append(jax.numpy.asarray(whole))
    return jax.tree.unflatten(treedef, restored), notices


def damage_text(step: int, damaged: list[tuple[int, str]]) -> str:
    return "; ".join(f"checkpoint {d} is damaged ({why})" for d, why in damaged) + f"; using checkpoint {step}"


def set_aside(directory: Path, steps: list[int]) -> Path:
    """Move the damaged checkpoints ``steps`` of ``directory`` (a run's checkpoints/, or one
    of its checkpoint_parts/) out of orbax's sight, into the run's damaged_checkpoints/
    (for a part, a folder of its name there)."""
    whole_batch = directory.name == CHECKPOINTS
    out = directory.parent if whole_batch else directory.parent.parent
    aside = out / DAMAGED_CHECKPOINTS / ("" if whole_batch else directory.name)
    aside.mkdir(parents=True, exist_ok=True)
    for step in steps:
        target = aside / str(step)
        copies = 0
        while target.exists():
            copies += 1
            target = aside / f"{step}-{copies}"
        os.replace(directory / str(step), target)
    return aside
