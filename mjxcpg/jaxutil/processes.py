"""Several cooperating processes through JAX's coordination service, the rendezvous of
``jax.distributed``.

``join`` connects them: the coordinator's address, the process count and this process's
index come from its arguments or, where left out, from the environment as JAX reads it
(``JAX_COORDINATOR_ADDRESS``, Slurm, Open MPI, ...).  The processes share no learner state:
each steps its own block of learners (``Group.block``) and writes its own checkpoints, and
the runtime's key-value store carries only small things: who is alive, who stopped and why,
and the barriers (``barrier``, ``broadcast`` of a few bytes) at a run's start and end.
``ALONE`` is the group of one process, where all of these are free.

Failures end every process within a bounded time, each with one line:

* a process that dies (or stops) is found by the others' watchdog threads: every process
  ticks a counter in the store each second (``_TICK_S``), and one whose counter stands still
  for ``LOST_AFTER_S`` is named, and the survivors exit (status 2).  The store is served by
  a process of its own that process 0 forks (``ServiceProcess``), so that it outlives a
  killed process 0: JAX's runtime aborts every client of a service that is gone, before
  any line of ours;
* a process that raises calls ``abort``; SIGTERM (what Slurm sends before a preemption or at
  its time limit) makes the process abort itself.  The others' watchdogs see the abort within
  a tick and ask their main thread to stop (``stop_reason``), which a run loop reads after
  each chunk: it writes a checkpoint and raises.  A main thread still computing
  ``STOP_GRACE_S`` later is ended from the watchdog; the checkpoints written are kept;
* a group that does not form within the join timeout (a process never joined) is an error
  of ``join``, naming the process missing where it can.

JAX's C++ runtime logs to stderr as the service's state changes (a peer gone, a shutdown);
``join`` first forks a small stderr guard that passes the output on and keeps those log
lines out of it (in a log file, ``StderrFilter``), so that a failure reads as one line.  It
filters what is shown only: no decision reads it.
"""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import socket
import sys
import tempfile
import threading
import time

import numpy as np

LOST_AFTER_S = 20.0   # a process whose watchdog has not ticked for this long is taken for dead
# A stop asked of a process (another's abort, SIGTERM) ends it this long after, if its run
# loop has not stopped by then at a chunk's end.  Slurm's KillWait, the time between its
# SIGTERM and its SIGKILL, is 30 s by default.
STOP_GRACE_S = 25.0
_TICK_S = 1.0
_POLL_MS = 1000       # a wait checks for an abort this often
_PREFIX = "mjxcpg/"
_JOINED: list["Group"] = []  # the group this process joined, if it did
# JAX's own heartbeat, which ends a group whose member is silent this long: far above the
# watchdog's LOST_AFTER_S, so that the watchdog names the lost process first.
_JAX_HEARTBEAT_S = 100
_SHUTDOWN_S = 30  # the graceful shutdown's barrier waits this long for every process
_GONE_AFTER_S = 3.0  # a peer whose ticks stopped this long ago has ended, for ``leave``


class ProcessError(ValueError):
    """Another process failed, or the group could not form: one line for the user."""


@dataclasses.dataclass
class Group:
    """This process (``index``) among ``count`` cooperating processes."""

    index: int = 0
    count: int = 1
    client: object = None  # the coordination service's client (its key-value store); None alone
    # Why this process was asked to stop (``stop_requested``); set by the watchdog thread.
    stop_reason: str | None = None
    _exchanges: int = 0
    _watchdog: threading.Thread | None = None
    _closing: bool = False
    _signals: socket.socket | None = None  # the read end of the signal wake-up socket
    _signal_writer: socket.socket | None = None  # its write end, kept open for the C handler
    _service: "ServiceProcess | None" = None  # the coordination service's process, on process 0

    @property
    def writer(self) -> bool:
        """Process 0 writes the run directory, the progress line and the reports."""
        return self.index == 0

    def block(self, batch: int) -> np.ndarray:
        """The learners (indices into the batch) this process steps: contiguous blocks whose
        sizes differ by one at most; a process beyond the batch gets none."""
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

    def stop_requested(self) -> str | None:
        """Why this process must stop (another process stopped, or this one was sent SIGTERM),
        or None: a run loop asks after each chunk (module docstring)."""
        return self.stop_reason

    def close(self) -> None:
        """The group's work is over, in every process (after a last ``barrier``): shut the
        client down with the others, so that no process loses its store while in use."""
        self._closing = True
        if self._watchdog is not None:
            # Out of the runtime before the interpreter ends: a thread that Python's shutdown
            # finds inside a runtime call aborts the process.
            self._watchdog.join(timeout=10 * _TICK_S)
        if self.count > 1:
            self.client.shutdown()
            if self._service is not None:
                self._service.stop(wait=True)

    def leave(self, status: int) -> None:
        """End this process now with ``status`` (it has said why).  Process 0 first waits,
        up to ``STOP_GRACE_S`` and a little, for the others to end, then stops the service:
        the store is theirs, and a process that lost it would end without its checkpoint and
        its own line."""
        try:
            self.client.key_value_set(f"{_PREFIX}exited/{self.index}", str(status), allow_overwrite=True)
            if self.writer:
                self._wait_for_peers(time.monotonic() + STOP_GRACE_S + 5)
        except Exception:  # the store is gone: nothing to wait for
            pass
        self._closing = True
        if self._service is not None:
            self._service.stop(wait=False)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)

    def _wait_for_peers(self, deadline: float) -> None:
        """Until every other process has exited or stopped ticking (``_GONE_AFTER_S``)."""
        seen: dict[str, tuple[str, float]] = {}
        while time.monotonic() < deadline:
            exited = {key for key, _ in self.client.key_value_dir_get(f"{_PREFIX}exited/")}
            now = time.monotonic()
            for key, value in self.client.key_value_dir_get(f"{_PREFIX}alive/"):
                if seen.get(key, (None,))[0] != value:
                    seen[key] = (value, now)
            waiting = [p for p in range(self.count) if p != self.index
                       and f"{_PREFIX}exited/{p}" not in exited
                       and now - seen.get(f"{_PREFIX}alive/{p}", ("", now))[1] < _GONE_AFTER_S]
            if not waiting:
                return
            time.sleep(0.2)

    def abort(self, message: str) -> None:
        """Tell the others that this process stopped, and why (``message`` follows "process
        N "; their watchdogs see it)."""
        if self.count > 1:
            try:
                self.client.key_value_set(f"{_PREFIX}abort/{self.index}", f"process {self.index} {message}",
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
            if self.stop_reason is not None:
                raise ProcessError(f"process {self.index} stops: {self.stop_reason}")

    def _peer_abort(self) -> str | None:
        """Another process's abort message, if one has aborted."""
        # A directory read lists the keys under ``abort/``, not a key named ``abort``.
        for key, message in self.client.key_value_dir_get(f"{_PREFIX}abort/"):
            if key != f"{_PREFIX}abort/{self.index}":
                return message
        return None

    def _signalled(self) -> bool:
        """Whether SIGTERM has come since the last look (the wake-up socket, ``join``)."""
        try:
            return bool(self._signals is not None and self._signals.recv(64))
        except BlockingIOError:
            return False

    # ------------------------------------------------------------ liveness

    def _start_watchdog(self) -> None:
        def end(text: str) -> None:
            # The main thread may be deep in a computation: end the process from here.
            print(f"mjxcpg: error: process {self.index} stops: {text}; the checkpoints written so far are "
                  "kept: rerun with --resume", file=sys.stderr, flush=True)
            self.leave(2)

        def watch() -> None:
            seen: dict[int, tuple[str, float]] = {}
            tick, deadline = 0, None
            while True:
                if self._signalled() and self.stop_reason is None:
                    self.stop_reason = "it was sent SIGTERM"
                    self.abort("was sent SIGTERM")
                    deadline = time.monotonic() + STOP_GRACE_S
                try:
                    self.client.key_value_set(f"{_PREFIX}alive/{self.index}", str(tick), allow_overwrite=True)
                    ticks = dict(self.client.key_value_dir_get(f"{_PREFIX}alive/"))
                    aborted = self._peer_abort() if self.stop_reason is None else None
                except Exception as error:
                    if self._closing:  # the runtime is shutting down
                        return
                    end(f"it lost the coordinator, process 0 ({_first_line(error)})")
                if self._closing:
                    return
                now = time.monotonic()
                if aborted is not None:
                    self.stop_reason, deadline = aborted, now + STOP_GRACE_S
                if deadline is not None and now > deadline:
                    end(f"{self.stop_reason}, and its chunk did not end within {STOP_GRACE_S:g} s")
                for p in range(self.count):
                    value = ticks.get(f"{_PREFIX}alive/{p}", "")
                    if seen.get(p, (None,))[0] != value:
                        seen[p] = (value, now)
                lost = [p for p, (_, since) in seen.items() if now - since > LOST_AFTER_S]
                if lost:
                    end(f"process {', '.join(map(str, lost))} stopped answering (no sign of life for "
                        f"{LOST_AFTER_S:g} s)")
                tick += 1
                time.sleep(_TICK_S)

        self._watchdog = threading.Thread(target=watch, name="mjxcpg-watchdog", daemon=True)
        self._watchdog.start()

    def _catch_sigterm(self) -> None:
        """SIGTERM stops this process at a chunk's end, through the watchdog: the C-level
        handler writes to a socket that the watchdog reads (``signal.set_wakeup_fd``), since
        Python runs its own handler only when the main thread next runs Python code."""
        if threading.current_thread() is not threading.main_thread():
            return
        read, write = socket.socketpair()
        read.setblocking(False)
        write.setblocking(False)
        self._signals, self._signal_writer = read, write
        signal.signal(signal.SIGTERM, lambda number, frame: None)
        signal.set_wakeup_fd(write.fileno(), warn_on_full_buffer=False)


ALONE = Group()


def _first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [type(error).__name__])[0][:500]


# ---------------------------------------------------------------- joining

def _settings(coordinator, count, index, timeout_s) -> tuple[str, int, int, list[int] | None]:
    """The coordinator's address, the process count, this process's index and its devices,
    from the arguments or, where left None, from the environment as ``jax.distributed`` reads
    it (``JAX_COORDINATOR_ADDRESS``, Slurm, Open MPI, ...)."""
    from jax._src import clusters

    coordinator = coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS")
    devices = None
    if None in (coordinator, count, index):
        coordinator, count, index, devices = clusters.ClusterEnv.auto_detect_unset_distributed_params(
            coordinator, count, index, None, None, timeout_s)
    for name, value in (("the coordinator's address", coordinator), ("the process count", count),
                        ("this process's index", index)):
        if value is None:
            raise ProcessError(f"cannot join the processes: {name} is not given and the environment does not say it")
    if not 0 <= index < count:
        raise ProcessError(f"cannot join the processes: process index {index} is not in 0..{count - 1}")
    return coordinator, count, index, devices


def join(coordinator: str | None = None, count: int | None = None, index: int | None = None,
         timeout_s: int = 120) -> Group:
    """Join the group of processes, before anything else uses JAX; the arguments left None
    come from the environment (``_settings``).

    Each process stays a JAX program of its own (``jax.process_count()`` is 1 in each, on
    its own devices): the processes share no arrays, so JAX's multi-controller runtime is
    not started, only its coordination service (in ``ServiceProcess``, forked by process 0)
    and a client of it in every process, for the key-value store and the rendezvous.  The
    client's error callback is a no-op: the runtime aborts a client whose service is gone
    whatever the callback, which is why the service is served apart."""
    import jax
    from jax._src.lib import _jax

    _guard_stderr()
    address, count, index, devices = _settings(coordinator, count, index, timeout_s)
    if devices:  # Slurm's GPU task: its own devices, as jax.distributed would choose them
        jax.config.update("jax_cuda_visible_devices", ",".join(map(str, devices)))
    service = ServiceProcess.start(address.rsplit(":", 1)[-1], count) if index == 0 and count > 1 else None
    client = _jax.get_distributed_runtime_client(address, index, init_timeout=timeout_s,
                                                 heartbeat_timeout=_JAX_HEARTBEAT_S, shutdown_timeout=_SHUTDOWN_S,
                                                 missed_heartbeat_callback=lambda *_: None,
                                                 shutdown_on_destruction=False)
    try:
        client.connect()
    except Exception:  # JAX's runtime raises odd types here (e.g. RuntimeError: std::bad_cast)
        if service is not None:
            service.stop(wait=True)
        if index == 0 and count == 2:
            missing = "process 1 never joined"
        elif count == 2:
            missing = f"process 0 (the coordinator, {address}) never answered"
        else:
            missing = f"process 0 (the coordinator, {address}) or another process never joined"
        raise ProcessError(f"process {index}: the {count} processes did not all join within {timeout_s} s: "
                           f"{missing}") from None
    group = Group(index=index, count=count, client=client, _service=service)
    if count > 1:
        group._catch_sigterm()
        group._start_watchdog()
        _JOINED.append(group)
    return group


class ServiceProcess:
    """The coordination service, served by a process forked from process 0 at ``join``, so
    that it outlives process 0: a killed process 0 takes the service with it otherwise, and
    JAX's runtime ends every other process at once on losing it (a C++ abort, before any
    line of ours).  With it served apart, the others' watchdogs find process 0 silent and
    end with their line.  Told to ``stop``, it shuts the service down; left (process 0 ended
    without a word), it serves ``ORPHAN_SERVICE_S`` longer, time for the others to end, and
    exits.  It ignores SIGTERM and SIGINT, which a scheduler sends to every process of a
    task: process 0 stops on them, and the others still need the store to stop."""

    # Time for the others to find process 0 silent (LOST_AFTER_S) and end, with a margin.
    ORPHAN_SERVICE_S = LOST_AFTER_S + STOP_GRACE_S + 5

    def __init__(self, pid: int, control: int):
        self.pid, self._control = pid, control

    @classmethod
    def start(cls, port: str, count: int) -> "ServiceProcess":
        control_read, control_write = os.pipe()
        ready_read, ready_write = os.pipe()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            os.close(control_write)
            os.close(ready_read)
            try:
                _ignore_stop_signals()
                # Its streams are process 0's no longer: a reader of them (a terminal, a
                # test) sees them close when process 0 ends.  The runtime's log goes to a file.
                os.dup2(os.open(os.devnull, os.O_RDWR), 0)
                os.dup2(os.open(os.devnull, os.O_RDWR), 1)
                os.dup2(os.open(_log_path(), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644), 2)
                cls._serve(port, count, control_read, ready_write)
            finally:
                os._exit(0)
        os.close(control_read)
        os.close(ready_write)
        ready = os.read(ready_read, 1)
        os.close(ready_read)
        if ready != b"1":
            os.waitpid(pid, 0)
            raise ProcessError(f"process 0 could not serve the coordination service on port {port} "
                               "(is the port in use?)")
        return cls(pid, control_write)

    @staticmethod
    def _serve(port: str, count: int, control: int, ready: int) -> None:
        from jax._src.lib import _jax

        try:
            service = _jax.get_distributed_runtime_service(f"[::]:{port}", count, heartbeat_timeout=_JAX_HEARTBEAT_S,
                                                           shutdown_timeout=_SHUTDOWN_S)
        except Exception:
            return  # process 0 reads no "ready" and says so
        os.write(ready, b"1")
        if not os.read(control, 1):  # b"": process 0 ended without stopping the service
            time.sleep(ServiceProcess.ORPHAN_SERVICE_S)
        service.shutdown()

    def stop(self, wait: bool) -> None:
        """Shut the service down (every process has shut its client down, or has ended), and
        with ``wait``, until its process has exited."""
        try:
            os.write(self._control, b"s")
            if wait:
                os.waitpid(self.pid, 0)
        except OSError:  # it has ended already
            pass


def _ignore_stop_signals() -> None:
    for number in (signal.SIGTERM, signal.SIGINT):
        signal.signal(number, signal.SIG_IGN)


def joined() -> Group | None:
    """The group of several processes this one joined, if it did."""
    return _JOINED[0] if _JOINED and _JOINED[0].count > 1 else None


def exit_now(status: int) -> None:
    """End a process of several at once with ``status``, once it has said why: a failed
    run's peers may never come to a graceful shutdown.  Process 0, which serves the others'
    store, first waits for them to end (``Group.leave``).  Alone, or not joined, it returns."""
    if _JOINED and _JOINED[0].count > 1:
        _JOINED[0].leave(status)


# ---------------------------------------------------------------- the stderr guard

# A line of Abseil's C++ log: severity, date, time, thread, file:line].
_CPP_LOG = re.compile(rb"^[IWEF]\d{4} \d\d:\d\d:\d\d\.\d+ +\d+ [^ \]]+:\d+\]")
# What the C++ runtime prints when one of its threads ends the process (after our line:
# the runtime's threads may outlive the exit that the watchdog or the error path starts).
_CPP_ENDS = (b"terminate called", b"FATAL: exception not rethrown")


class StderrFilter:
    """The stderr guard's filter (module docstring): ``feed`` it bytes as they come, and it
    returns what passes on to stderr and what goes to the log: C++ log blocks (a log line
    and the lines after it, up to one of ours or a Python traceback)."""

    def __init__(self):
        self._pending = b""
        self._in_log = False

    def feed(self, data: bytes) -> tuple[bytes, bytes]:
        """Pass ``data`` (b"" at the end of the stream: flush everything held)."""
        self._pending += data
        out, log = [], []
        while self._pending:
            newline = self._pending.find(b"\n")
            if newline < 0 and data and self._incomplete(self._pending):
                break  # a line still arriving: wait for the rest
            end = len(self._pending) if newline < 0 else newline + 1
            line, self._pending = self._pending[:end], self._pending[end:]
            self._line(line, out, log)
        return b"".join(out), b"".join(log)

    def _incomplete(self, pending: bytes) -> bool:
        # A log line's prefix (severity, time, thread, file:line) is well under 200 bytes.
        return bool(_CPP_LOG.match(pending) or (self._in_log and not pending.startswith(b"\r"))
                    or (pending[:1] in b"IWEF" and len(pending) < 200))

    def _line(self, line: bytes, out: list[bytes], log: list[bytes]) -> None:
        if _CPP_LOG.match(line) or line.startswith(_CPP_ENDS):
            self._in_log = True
        elif line.startswith((b"mjxcpg", b"\r", b"Traceback")):
            self._in_log = False
        (log if self._in_log else out).append(line)


def _log_path() -> str:
    """Where this process's share of the runtime's log goes."""
    return os.path.join(tempfile.gettempdir(), f"mjxcpg-process-{os.getpid()}.log")


def _guard_stderr() -> None:
    """Fork the stderr guard (module docstring) and send this process's stderr through it."""
    if os.environ.get("MJXCPG_RAW_STDERR"):
        return
    log_path = _log_path()
    sys.stderr.flush()
    read, write = os.pipe()
    if os.fork() > 0:
        os.close(read)
        os.dup2(write, 2)
        os.close(write)
        return
    os.close(write)
    sys.stdin.close()
    try:
        _ignore_stop_signals()  # it ends when the process it guards has ended: at end of stream
        _guard_loop(read, log_path)
    finally:
        os._exit(0)


def _guard_loop(read: int, log_path: str) -> None:
    """Pass ``read`` on to stderr through a ``StderrFilter``, its log to ``log_path``."""
    log, stream = None, StderrFilter()
    while True:
        data = os.read(read, 65536)
        out, logged = stream.feed(data)
        if out:
            os.write(2, out)
        if logged:
            if log is None:
                log = open(log_path, "ab")
            log.write(logged)
        if not data:
            break
    if log is not None:
        log.close()
