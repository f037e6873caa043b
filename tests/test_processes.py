"""A sweep run by two cooperating processes (jax.distributed, on this host's CPU) ends as the
one-process run does, byte for byte, uninterrupted and after both are killed and resumed with
two processes or one; a process that dies or never joins ends the others with one line."""

import json
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mjxcpg.cli import main
from mjxcpg.training import checkpoints, config

from test_runs import assert_same_results, one_line_error

SWEEP = ["sweep", "--quiet", "--engine", "native", "--no-tensorboard", "--checkpoint-every", "0"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def start(args: list[str], out: Path, count: int = 2, only: tuple[int, ...] | None = None,
          port: int | None = None) -> list[subprocess.Popen]:
    """``mjxcpg`` as processes 0..count-1 of one group (or only those of ``only``)."""
    port = port or free_port()
    group = ["--coordinator", f"localhost:{port}", "--num-processes", str(count)]
    return [subprocess.Popen([sys.executable, "-m", "mjxcpg", *args, "--out", str(out), *group,
                              "--process-id", str(i)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for i in (range(count) if only is None else only)]


def finish(procs: list[subprocess.Popen], timeout: float = 600) -> list[tuple[int, str, str]]:
    """Each process's exit status, stdout and stderr, once it has ended."""
    outputs = [p.communicate(timeout=timeout) for p in procs]
    return [(p.returncode, *output) for p, output in zip(procs, outputs)]


def newest_leaves(run: Path) -> tuple[int, dict]:
    step, leaves, damaged = checkpoints.newest_intact(checkpoints.manager_of(run))
    assert damaged == []
    return step, leaves


def kill_at_checkpoint(procs: list[subprocess.Popen], run: Path, step: int, victims: list[int]) -> float:
    """SIGKILL the processes ``victims`` once checkpoint ``step`` is on disk; the time then."""
    while not (run / checkpoints.CHECKPOINTS / str(step)).is_dir():
        assert all(p.poll() is None for p in procs), "the run ended before it could be killed"
        time.sleep(0.05)
    for i in victims:
        procs[i].send_signal(signal.SIGKILL)
    return time.perf_counter()


def short_chunks(tmp_path: Path) -> Path:
    """The `quick` config with 0.5 s chunks: a checkpoint every few tenths of a second."""
    path = tmp_path / "short.json"
    path.write_text(json.dumps(config.spec_to_dict(config.load_spec("quick")) | {"chunk_seconds": 0.5}))
    return path


def test_two_processes_end_as_one(finished_quick, tmp_path):
    run = tmp_path / "two"
    results = finish(start(SWEEP + ["--config", "quick"], run))
    assert [rc for rc, _, _ in results] == [0, 0], [err for _, _, err in results]
    assert "| k_s |" in results[0][1] and results[1][1] == ""  # process 0 reports, process 1 writes nothing
    assert_same_results(run, finished_quick)
    step, leaves = newest_leaves(run)  # the whole state, learner by learner, as one process had it
    reference_step, reference = newest_leaves(finished_quick)
    assert step == reference_step and leaves.keys() == reference.keys()
    assert all(np.array_equal(leaves[k], reference[k]) for k in leaves)


@pytest.mark.slow
def test_two_killed_processes_resume_with_two_and_with_one(finished_quick, tmp_path):
    killed = tmp_path / "killed"
    procs = start(SWEEP + ["--config", "quick"], killed)
    kill_at_checkpoint(procs, killed, 2, [0, 1])
    finish(procs)
    assert not (killed / "summary.json").exists()
    one = tmp_path / "resumed_by_one"
    shutil.copytree(killed, one)
    results = finish(start(SWEEP + ["--config", "quick", "--resume"], killed))
    assert [rc for rc, _, _ in results] == [0, 0], [err for _, _, err in results]
    assert_same_results(killed, finished_quick)
    assert main(SWEEP + ["--config", "quick", "--resume", "--out", str(one)]) == 0
    assert_same_results(one, finished_quick)


@pytest.mark.slow
@pytest.mark.parametrize("victim", [1, 0])
def test_killed_process_ends_the_other_with_one_line(tmp_path, victim):
    """A process killed mid-run: the other ends within 60 s, with one line naming it; the
    newest checkpoint reads back and the run resumes (with one process) to its end."""
    run = tmp_path / "run"
    procs = start(SWEEP + ["--config", str(short_chunks(tmp_path))], run)
    killed_at = kill_at_checkpoint(procs, run, 3, [victim])
    survivor = procs[1 - victim]
    _, err = survivor.communicate(timeout=90)
    ended_in = time.perf_counter() - killed_at
    finish(procs)
    assert survivor.returncode != 0 and ended_in < 60, (survivor.returncode, ended_in)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"process {victim}" in one_line_error(err), err
    newest_leaves(run)
    assert main(SWEEP + ["--config", str(short_chunks(tmp_path)), "--resume", "--out", str(run)]) == 0
    print(f"killed process {victim}; process {1 - victim} ended {ended_in:.1f} s later: {lines[0]}")


@pytest.mark.parametrize("present", [0, 1])
def test_process_that_never_joins_is_named(tmp_path, present):
    start_time = time.perf_counter()
    (rc, out, err), = finish(start(SWEEP + ["--config", "quick", "--join-timeout", "3"], tmp_path / "run",
                                   only=(present,)), timeout=120)
    assert rc != 0 and time.perf_counter() - start_time < 60
    assert len(err.strip().splitlines()) == 1, err
    assert f"process {1 - present}" in one_line_error(err) and "never" in err
    assert not (tmp_path / "run").exists()


def test_error_in_one_process_ends_the_other_with_one_line(finished_quick, tmp_path):
    """Process 0 refuses to resume a finished run of another config (an error on it alone):
    both processes end within 60 s, each with one line, process 1's naming process 0 and
    the cause; the finished run is left as it was."""
    run = tmp_path / "run"
    shutil.copytree(finished_quick, run)
    start_time = time.perf_counter()
    results = finish(start(SWEEP + ["--config", str(short_chunks(tmp_path)), "--resume"], run), timeout=120)
    assert time.perf_counter() - start_time < 60
    assert all(rc != 0 and len(err.strip().splitlines()) == 1 for rc, _, err in results), results
    assert "another config" in results[0][2]
    assert "process 0" in results[1][2] and "another config" in results[1][2]
    assert_same_results(run, finished_quick)
