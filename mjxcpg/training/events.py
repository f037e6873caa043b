"""TensorBoard event files of a run, under ``DIR/tensorboard`` (``tensorboard --logdir runs/``).

One TensorBoard run per learner (``learner_KK_ksK_S_seedS``), so that TensorBoard draws the
learners of a sweep on one chart per measure, with each trial's return, fall, mean forward
velocity and mean |a_5| after the hand-over, and the policy's sigma at its end, at step =
the trial's number (from 1); and one run, ``run``, with the throughput, the learners
finished and the estimated time left after every chunk, at step = the trials finished by all
learners.

The events are written from the bookkeeping after a chunk, on the host, so a run's results
are the same with and without them, and reach the disk at ``flush`` (a run flushes with each
checkpoint: a flush syncs every file written to, which a short chunk would feel).  A run
resumed after a kill may recompute trials whose events were written before its last
checkpoint; the files already there are read back and only steps beyond them are written, so
no trial appears twice, and trials whose events a kill lost are in the checkpoint's
bookkeeping, from which they are written again.
"""

from __future__ import annotations

import itertools
import os
import struct
import time
from pathlib import Path

import numpy as np
from tensorboardX.event_file_writer import EventsWriter
from tensorboardX.proto.event_pb2 import Event
from tensorboardX.proto.summary_pb2 import Summary

EVENTS_DIR = "tensorboard"
RUN_NAME = "run"
# The per-trial scalars: tag -> the bookkeeping's per-trial array (learner.Bookkeeping).
TRIAL_SCALARS = {"trial/return": "returns", "trial/fell": "falls", "trial/mean_vx": "velocities",
                 "trial/mean_abs_a5": "mean_abs_a5", "trial/sigma": "sigmas"}
_RECORD_HEADER = struct.Struct("<QI")  # TFRecord: length, masked CRC of the length
_RECORD_FOOTER = 4                     # masked CRC of the data
_writers_opened = itertools.count()    # two writers of one process never share a file name


def learner_run_name(index: int, k_s: float, seed: int) -> str:
    return f"learner_{index:02d}_ks{k_s:g}_seed{seed}"


def read_events(directory: Path) -> list[tuple[float, int, dict[str, float]]]:
    """The scalar events of the event files in ``directory``, in order of writing: (wall
    time, step, {tag: value}).  A record cut short (a process killed while writing) ends its
    file."""
    found = []
    for path in sorted(directory.glob("events.out.tfevents.*")):
        data, start = path.read_bytes(), 0
        while start + _RECORD_HEADER.size <= len(data):
            length, _ = _RECORD_HEADER.unpack_from(data, start)
            body = start + _RECORD_HEADER.size
            if body + length + _RECORD_FOOTER > len(data):
                break
            event = Event.FromString(data[body:body + length])
            if event.summary.value:
                found.append((event.wall_time, event.step, {v.tag: v.simple_value for v in event.summary.value}))
            start = body + length + _RECORD_FOOTER
    return found


def read_scalars(directory: Path) -> dict[str, dict[int, float]]:
    """Every scalar of the event files in ``directory``: tag -> {step: value}."""
    scalars: dict[str, dict[int, float]] = {}
    for _, step, values in read_events(directory):
        for tag, value in values.items():
            scalars.setdefault(tag, {})[step] = value
    return scalars


def _last_step(directory: Path) -> int:
    return max((step for steps in read_scalars(directory).values() for step in steps), default=0)


class _Writer:
    """One TensorBoard run's new event file, opened at its first event (no thread: the
    caller writes every event, after a chunk, and flushes)."""

    def __init__(self, directory: Path):
        self.directory = directory
        self._file: EventsWriter | None = None
        self._unflushed = False

    def write(self, step: int, values: dict[str, float], wall_time: float) -> None:
        if self._file is None:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._file = EventsWriter(str(self.directory / "events"),
                                      filename_suffix=f".{os.getpid()}.{next(_writers_opened)}")
        summary = Summary(value=[Summary.Value(tag=tag, simple_value=float(v)) for tag, v in values.items()])
        self._file.write_event(Event(wall_time=wall_time, step=step, summary=summary))
        self._unflushed = True

    def flush(self) -> None:
        if self._file is not None and self._unflushed:
            self._file.flush()
            self._unflushed = False

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class RunEvents:
    """The event files of the run in ``out``: per learner its trials, and the run's progress."""

    def __init__(self, out: Path, k_s, seeds, learners=None, run_progress: bool = True):
        """``learners``: the learners' indices in the run (default 0, 1, ...), when these
        are a block of it; ``run_progress``: whether to write the run's progress too."""
        root = out / EVENTS_DIR
        indices = range(len(k_s)) if learners is None else [int(i) for i in learners]
        self._learners = [_Writer(root / learner_run_name(i, k, s)) for i, k, s in zip(indices, k_s, seeds)]
        self._logged = [_last_step(w.directory) for w in self._learners]
        self._run = _Writer(root / RUN_NAME) if run_progress else None
        self._run_logged = _last_step(self._run.directory) if run_progress else 0

    def write_trials(self, book, done: np.ndarray) -> None:
        """The trials finished since the last call (``book``: the bookkeeping, on the host)."""
        now = time.time()
        for i, writer in enumerate(self._learners):
            trials = int(book.trial[i])
            for t in range(self._logged[i], trials):
                writer.write(t + 1, {tag: getattr(book, field)[i][t] for tag, field in TRIAL_SCALARS.items()}, now)
            self._logged[i] = max(self._logged[i], trials)
            if done[i]:
                writer.close()

    def write_progress(self, trials: int, values: dict[str, float]) -> None:
        """The run's ``values`` at ``trials`` trials finished in all, unless already logged."""
        if self._run is not None and trials > self._run_logged:
            self._run.write(trials, {f"progress/{k}": v for k, v in values.items()}, time.time())
            self._run_logged = trials

    def flush(self) -> None:
        """Every event written so far, to disk."""
        for writer in self._writers():
            writer.flush()

    def close(self) -> None:
        for writer in self._writers():
            writer.close()

    def _writers(self) -> list[_Writer]:
        return self._learners + ([self._run] if self._run is not None else [])
