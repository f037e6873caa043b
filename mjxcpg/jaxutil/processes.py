"""Several cooperating processes through JAX's multi-controller runtime (``jax.distributed``).

``join`` starts the runtime: the coordinator's address, the process count and this
process's index come from its arguments or, where left out, from what JAX reads itself
(``JAX_COORDINATOR_ADDRESS``, Slurm, Open MPI, ...).  A ``Group`` then moves host data between
the processes through the runtime's key-value store: ``allgather`` (every process's bytes
to every process), ``broadcast`` (process 0's bytes), ``barrier``.  ``ALONE`` is the group of
one process, where all of these are free.

Failures end every process within a bounded time, each with one line:

* a process that dies (or stops) is found by the others' watchdogs: every process ticks a
  counter in the store each second, and one whose counter stands still for ``LOST_AFTER_S``
  is named, and the survivors exit (status 2);
* a process that raises calls ``abort``, which the others see at their next wait;
* JAX's own runtime ends a process by a fatal C++ error when the group never forms (a
  process never joined) or its coordinator (process 0) is gone.  No Python code runs then,
  so ``join`` first forks a small stderr guard: it passes the output on, keeps JAX's C++ log
  out of it (into a log file), and when JAX's fatal error comes turns it into one line.
"""

from __future__ import annotations

import dataclasses
import io
import os
import re
import sys
import tempfile
import threading
import time

import numpy as np

LOST_AFTER_S = 20.0   # a process whose watchdog has not ticked for this long is taken for dead
_TICK_S = 1.0
_POLL_MS = 1000       # a wait checks for an abort this often
_PREFIX = "mjxcpg/"


class ProcessError(ValueError):
    """Another process failed, or the group could not form: one line for the user."""


@dataclasses.dataclass
class Group:
    """This process (``index``) among ``count`` cooperating processes."""

    index: int = 0
    count: int = 1
    client: object = None  # jax.distributed's client (its key-value store); None alone
    _exchanges: int = 0
    _watchdog: threading.Thread | None = None

    @property
    def writer(self) -> bool:
        """Process 0 writes the run directory, the progress line and the reports."""
        return self.index == 0

    def block(self, batch: int) -> np.ndarray:
        """The learners (indices into the batch) this process steps: contiguous blocks, as
        even as can be; a process beyond the batch gets none."""
        return np.array_split(np.arange(batch), min(self.count, batch))[self.index] \
            if self.index < batch else np.arange(0)

    # ------------------------------------------------------------ exchanges

    def allgather(self, payload: bytes) -> list[bytes]:
        """Every process's ``payload``, in process order (the same call in every process)."""
        if self.count == 1:
            return [payload]
        tag = self._next_tag()
        self.client.key_value_set_bytes(f"{_PREFIX}x/{tag}/{self.index}", payload)
        parts = [payload if p == self.index else self._wait(f"{_PREFIX}x/{tag}/{p}", p)
                 for p in range(self.count)]
        # Every process has read this one's previous payload before it set its new one.
        if tag > 0:
            self.client.key_value_delete(f"{_PREFIX}x/{tag - 1}/{self.index}")
        return parts

    def broadcast(self, payload: bytes | None) -> bytes:
        """Process 0's ``payload`` (the others pass None)."""
        return self.allgather(payload if self.writer else b"")[0]

    def barrier(self) -> None:
        self.allgather(b"")

    def abort(self, message: str) -> None:
        """Tell the others that this process stopped, and why (their next wait raises)."""
        if self.count > 1:
            try:
                self.client.key_value_set(f"{_PREFIX}abort/{self.index}", f"process {self.index}: {message}",
                                          allow_overwrite=True)
            except Exception:  # the store may be gone with its process; the watchdogs see that
                pass

    def _next_tag(self) -> int:
        self._exchanges += 1
        return self._exchanges - 1

    def _wait(self, key: str, process: int) -> bytes:
        while True:
            try:
                return self.client.blocking_key_value_get_bytes(key, _POLL_MS)
            except Exception as error:
                if "DEADLINE_EXCEEDED" not in str(error):
                    raise ProcessError(f"process {self.index} lost the coordinator (process 0): "
                                       f"{_first_line(error)}") from None
            # A directory read lists the keys under ``abort/``, not a key named ``abort``.
            for _, aborted in self.client.key_value_dir_get(f"{_PREFIX}abort/"):
                raise ProcessError(f"the run stopped in {aborted}")

    # ------------------------------------------------------------ liveness

    def _start_watchdog(self) -> None:
        def watch() -> None:
            seen: dict[int, tuple[str, float]] = {}
            tick = 0
            while True:
                try:
                    self.client.key_value_set(f"{_PREFIX}alive/{self.index}", str(tick), allow_overwrite=True)
                    ticks = dict(self.client.key_value_dir_get(f"{_PREFIX}alive/"))
                except Exception:  # the runtime is shutting down, or its coordinator is gone
                    return
                now = time.monotonic()
                for p in range(self.count):
                    value = ticks.get(f"{_PREFIX}alive/{p}", "")
                    if seen.get(p, (None,))[0] != value:
                        seen[p] = (value, now)
                lost = [p for p, (_, since) in seen.items() if now - since > LOST_AFTER_S]
                if lost:
                    names = ", ".join(map(str, lost))
                    # The main thread may be deep in a computation: end the process from here.
                    print(f"mjxcpg: error: process {names} stopped answering (no sign of life for "
                          f"{LOST_AFTER_S:g} s); process {self.index} stops too; the checkpoints "
                          "written so far are kept: rerun with --resume", file=sys.stderr, flush=True)
                    os._exit(2)
                tick += 1
                time.sleep(_TICK_S)

        self._watchdog = threading.Thread(target=watch, name="mjxcpg-watchdog", daemon=True)
        self._watchdog.start()


ALONE = Group()


def _first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [type(error).__name__])[0][:200]


def pack(arrays: list[np.ndarray]) -> bytes:
    """Arrays as bytes (``np.save`` each: dtypes and shapes kept, no pickle)."""
    buffer = io.BytesIO()
    for x in arrays:
        np.save(buffer, np.ascontiguousarray(x), allow_pickle=False)
    return buffer.getvalue()


def unpack(payload: bytes) -> list[np.ndarray]:
    buffer, arrays = io.BytesIO(payload), []
    while buffer.tell() < len(payload):
        arrays.append(np.load(buffer, allow_pickle=False))
    return arrays


# ---------------------------------------------------------------- joining

def join(coordinator: str | None = None, count: int | None = None, index: int | None = None,
         timeout_s: int = 120) -> Group:
    """Join the group of processes (``jax.distributed.initialize``), before anything else
    uses JAX; the arguments left None come from the environment, as JAX reads it."""
    import jax
    from jax._src import distributed

    address = coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS")
    _guard_stderr(index, count, address, timeout_s)
    try:
        jax.distributed.initialize(coordinator, count, index, initialization_timeout=timeout_s)
    except (ValueError, TypeError, RuntimeError) as error:
        # Arguments that JAX refuses, before it contacts anyone (not a network failure).
        distributed.global_state.client = distributed.global_state.service = None
        raise ProcessError(f"cannot join the processes: {_first_line(error)}") from None
    jax.devices()  # every process's CPU client is made together: now, while all are here
    group = Group(index=jax.process_index(), count=jax.process_count(), client=distributed.global_state.client)
    if os.environ.get("MJXCPG_RAW_STDERR") is None:  # tell the guard who this is
        os.write(2, f"{_GROUP_MARK.decode()}{group.index} {group.count}\n".encode())
    if group.count > 1:
        group._start_watchdog()
    return group


# ---------------------------------------------------------------- the stderr guard

# A line of Abseil's C++ log: severity, date, time, thread, file:line].
_CPP_LOG = re.compile(rb"^[IWEF]\d{4} \d\d:\d\d:\d\d\.\d+ +\d+ [^ \]]+:\d+\]")
_FATAL = b"Terminating process because the JAX distributed service detected fatal errors"
_GUARD_CONTEXT: dict = {}
_GROUP_MARK = b"\x00mjxcpg-group "


def _fatal_line(log: bytes, index, count, address, timeout_s) -> str:
    """JAX's fatal error, as one line."""
    me = f"process {index}" if index is not None else "this process"
    if b"RegisterTask" in log:
        if index == 0 and count == 2:
            missing = "process 1 never joined"
        elif count == 2:
            missing = f"process 0 (the coordinator, {address}) never answered"
        else:
            missing = f"process 0 (the coordinator, {address}) or another process never joined"
        return f"{me}: the {count or ''} processes did not all join within {timeout_s} s: {missing}"
    unhealthy = re.search(rb"stopped sending heartbeats\):\s*\n([\d,\s]+)\n", log)
    if unhealthy:
        names = ", ".join(unhealthy.group(1).decode().split())
        return f"{me} stops: JAX found process {names} dead (no heartbeat)"
    if b"Socket closed" in log or b"UNAVAILABLE" in log:
        return f"{me} stops: process 0 (the coordinator, {address}) is gone"
    status = re.search(rb"absl::Status: ([^\n]*)", log)
    return f"{me} stops: JAX's distributed runtime failed ({(status.group(1) if status else b'').decode()})"


def _guard_stderr(index, count, address, timeout_s) -> None:
    """Fork the stderr guard (module docstring) and send this process's stderr through it."""
    if os.environ.get("MJXCPG_RAW_STDERR"):
        return
    log_path = os.path.join(tempfile.gettempdir(), f"mjxcpg-process-{os.getpid()}.log")
    sys.stderr.flush()
    read, write = os.pipe()
    if os.fork() > 0:
        os.close(read)
        os.dup2(write, 2)
        os.close(write)
        return
    os.close(write)
    _GUARD_CONTEXT.update(index=index, count=count)
    sys.stdin.close()
    try:
        _guard_loop(read, log_path, address, timeout_s)
    finally:
        os._exit(0)


def _guard_loop(read: int, log_path: str, address, timeout_s) -> None:
    """Pass ``read`` on to stderr, but C++ log blocks (a log line and the lines after it,
    up to one of ours) go to ``log_path``; at the end, JAX's fatal error as one line."""
    log, pending, in_log, fatal = None, b"", False, b""
    while True:
        data = os.read(read, 65536)
        pending += data
        out = b""
        while pending:
            newline = pending.find(b"\n")
            if newline < 0 and data and (_CPP_LOG.match(pending) or (in_log and not pending.startswith(b"\r"))
                                         or (pending[:1] in b"IWEF" and len(pending) < 40)):
                break  # maybe a log line still arriving: wait for the rest
            line, pending = (pending, b"") if newline < 0 else (pending[:newline + 1], pending[newline + 1:])
            if line.startswith(_GROUP_MARK):
                index, count = line[len(_GROUP_MARK):].split()
                _GUARD_CONTEXT.update(index=int(index), count=int(count))
                continue
            if _CPP_LOG.match(line):
                in_log = True
            elif line.startswith((b"mjxcpg", b"\r", b"Traceback")):
                in_log = False
            if in_log or fatal:
                if log is None:
                    log = open(log_path, "ab")
                log.write(line)
                if _FATAL in line or fatal:
                    fatal += line
            else:
                out += line
        if out:
            os.write(2, out)
        if not data:
            break
    if log is not None:
        log.close()
    if fatal:
        context = _GUARD_CONTEXT
        os.write(2, f"mjxcpg: error: {_fatal_line(fatal, context.get('index'), context.get('count'), address, timeout_s)}"
                    f" (JAX's log: {log_path})\n".encode())
