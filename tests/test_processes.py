"""A sweep run by two or three cooperating processes (jax.distributed, on this host's CPU)
ends as the one-process run does, byte for byte, uninterrupted and after being stopped and
resumed with another process count; a process that raises, is killed, is sent SIGTERM or
never joins ends the others within 60 s, each with one line naming it."""

import json
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from mjxcpg.cli import main
from mjxcpg.training import checkpoints, config, runs, train

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


def final_state(run: Path):
    """Every learner's newest state in ``run``'s checkpoints, whichever layout holds it."""
    spec, _ = runs.read_config(run)
    sim = spec.simulation("native")
    state, notices = checkpoints.restore_learners(run, train.init_run(sim, train.make_task(sim, spec), spec), spec)
    assert notices == []
    return state


def any_part_at(run: Path, step: int) -> bool:
    return any((d / str(step)).is_dir() for d in checkpoints.checkpoint_directories(run))


def signal_at_checkpoint(procs: list[subprocess.Popen], run: Path, step: int, victims: list[int],
                         number: int = signal.SIGKILL) -> float:
    """Send ``number`` to the processes ``victims`` once some process's checkpoint ``step``
    is on disk; the time then."""
    while not any_part_at(run, step):
        assert all(p.poll() is None for p in procs), "the run ended before it could be stopped"
        time.sleep(0.05)
    for i in victims:
        procs[i].send_signal(number)
    return time.perf_counter()


def short_chunks(tmp_path: Path) -> Path:
    """The `quick` config with 0.5 s chunks: a checkpoint every few tenths of a second."""
    path = tmp_path / "short.json"
    path.write_text(json.dumps(config.spec_to_dict(config.load_spec("quick")) | {"chunk_seconds": 0.5}))
    return path


@pytest.mark.parametrize("count", [2, 3])
def test_processes_end_as_one(finished_quick, tmp_path, count):
    """Each process steps its own block (three processes: a learner each, beside a copy of
    itself) and writes its own checkpoints; the results and every learner's learning state
    are the one-process run's."""
    run = tmp_path / "several"
    results = finish(start(SWEEP + ["--config", "quick"], run, count=count))
    assert [rc for rc, _, _ in results] == [0] * count, [err for _, _, err in results]
    assert "| k_s |" in results[0][1] and all(out == "" for _, out, _ in results[1:])  # process 0 reports
    assert_same_results(run, finished_quick)
    assert not (run / checkpoints.CHECKPOINTS).exists()
    assert len(list((run / checkpoints.CHECKPOINT_PARTS).iterdir())) == count
    # What learning leaves: the weights and the trials' records.  (A finished learner's
    # counters go on while it pads a batch, so they depend on how long its batch ran.)
    mine, reference = final_state(run).learners, final_state(finished_quick).learners
    assert all(jax.tree.leaves(jax.tree.map(np.array_equal, mine.weights, reference.weights)))
    for field in ("trial", "trials_to_success", "returns", "falls", "velocities", "mean_abs_a5", "sigmas"):
        assert np.array_equal(getattr(mine.book, field), getattr(reference.book, field)), field


@pytest.mark.slow
def test_two_killed_processes_resume_with_three_and_with_one(finished_quick, tmp_path):
    killed = tmp_path / "killed"
    procs = start(SWEEP + ["--config", "quick"], killed)
    signal_at_checkpoint(procs, killed, 2, [0, 1])
    finish(procs)
    assert not (killed / "summary.json").exists()
    one = tmp_path / "resumed_by_one"
    shutil.copytree(killed, one)
    results = finish(start(SWEEP + ["--config", "quick", "--resume"], killed, count=3))
    assert [rc for rc, _, _ in results] == [0, 0, 0], [err for _, _, err in results]
    assert_same_results(killed, finished_quick)
    assert main(SWEEP + ["--config", "quick", "--resume", "--out", str(one)]) == 0
    assert_same_results(one, finished_quick)


def stopped_then_resumed(tmp_path: Path, count: int, victim: int, number: int, reference: Path) -> list[str]:
    """``count`` processes of the short-chunk config, ``number`` sent to ``victim`` once a
    checkpoint 3 is on disk: every process ends within 60 s with one line; the run then
    resumes (with another process count) to the one-process run's results.  Their lines."""
    run = tmp_path / "run"
    procs = start(SWEEP + ["--config", str(short_chunks(tmp_path))], run, count=count)
    stopped_at = signal_at_checkpoint(procs, run, 3, [victim], number)
    results = finish(procs, timeout=90)
    ended_in = time.perf_counter() - stopped_at
    assert ended_in < 60 and all(rc != 0 for rc, _, _ in results), (ended_in, results)
    lines = [err for i, (_, _, err) in enumerate(results) if not (i == victim and number == signal.SIGKILL)]
    assert all(len(err.strip().splitlines()) == 1 and f"process {victim}" in one_line_error(err)
               for err in lines), lines
    resumed = finish(start(SWEEP + ["--config", str(short_chunks(tmp_path)), "--resume"], run,
                           count=5 - count))
    assert [rc for rc, _, _ in resumed] == [0] * (5 - count), [err for _, _, err in resumed]
    assert_same_results(run, reference)
    return [err.strip() for err in lines]


@pytest.fixture(scope="module")
def finished_short(tmp_path_factory):
    """The short-chunk config, run by one process."""
    folder = tmp_path_factory.mktemp("short")
    run = folder / "run"
    assert main(SWEEP + ["--config", str(short_chunks(folder)), "--out", str(run)]) == 0
    return run


def test_sigterm_checkpoints_every_process(tmp_path, finished_short):
    """SIGTERM (Slurm's notice before a preemption) to one of three processes: each writes a
    checkpoint at its chunk's end and stops, naming it; the run resumes with two."""
    lines = stopped_then_resumed(tmp_path, 3, 1, signal.SIGTERM, finished_short)
    assert "process 1 stops: it was sent SIGTERM" in lines[1], lines
    assert all("wrote its checkpoint" in line for line in lines), lines


@pytest.mark.slow
@pytest.mark.parametrize("count, victim, number", [(2, 1, signal.SIGKILL), (2, 0, signal.SIGKILL),
                                                   (3, 2, signal.SIGKILL), (2, 0, signal.SIGTERM)])
def test_stopped_process_ends_the_others(tmp_path, finished_short, count, victim, number):
    print(stopped_then_resumed(tmp_path, count, victim, number, finished_short))


@pytest.mark.parametrize("count", [2, 3])
def test_error_mid_run_ends_every_process(tmp_path, finished_short, count):
    """The last process's checkpoint folder is taken by a file mid-run, so that its next
    write fails while the others are learning: every process ends within 60 s with one line
    naming it and the cause, the others having written a checkpoint; once the folder is back
    the run resumes to the one-process run's results."""
    run = tmp_path / "run"
    spec = config.load_spec(str(short_chunks(tmp_path)))
    folder = checkpoints.part_directory(run, np.array_split(np.arange(spec.batch), count)[-1])
    procs = start(SWEEP + ["--config", str(short_chunks(tmp_path))], run, count=count)
    while not (folder / "2").is_dir():
        assert all(p.poll() is None for p in procs), "the run ended before its folder could be taken"
        time.sleep(0.02)
    aside = folder.with_name(folder.name + ".aside")
    folder.rename(aside)
    folder.write_text("in the way")
    taken_at = time.perf_counter()
    results = finish(procs, timeout=120)
    assert time.perf_counter() - taken_at < 60
    assert all(rc != 0 and len(err.strip().splitlines()) == 1 for rc, _, err in results), results
    assert all(f"process {count - 1}" in one_line_error(err) for _, _, err in results), results
    assert all("cannot write a checkpoint" in err for _, _, err in results), results
    folder.unlink()
    aside.rename(folder)
    resumed = finish(start(SWEEP + ["--config", str(short_chunks(tmp_path)), "--resume"], run, count=count))
    assert [rc for rc, _, _ in resumed] == [0] * count, [err for _, _, err in resumed]
    assert_same_results(run, finished_short)


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


def test_compiled_shapes_per_process_are_the_blocks_ladder():
    """1,024 learners over 8 processes, finishing one per chunk: each process compiles its
    block's sizes only, 128 and 64, 32, 16, 8, 4, 2 (counted by hand: the block, then the
    powers of two from half of it down to 2), where one compaction over the whole batch
    gave each process dozens."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    import compiled_shapes

    counts = compiled_shapes.shapes_per_process(1024, 8, seed=0)
    assert counts["own_block"] == [len([128, 64, 32, 16, 8, 4, 2])] * 8
    assert min(counts["global_compaction"]) > 7


def test_stderr_filter_keeps_our_lines_and_logs_the_runtimes():
    """A stream as a failing process of several writes it, fed in pieces that split lines:
    our lines and a traceback pass on in order; the C++ runtime's log block goes to the log."""
    from mjxcpg.jaxutil.processes import StderrFilter

    cpp = [b"E1206 22:31:04.123456   4242 coordination_service.cc:123] heartbeat lost\n",
           b"  more of the same log entry\n", b"terminate called after throwing an instance of 'x'\n"]
    traceback = [b"Traceback (most recent call last):\n", b'  File "x.py", line 1, in <module>\n',
                 b"ValueError: a real failure\n"]
    ours = [b"\rlearning 10%", b"\rlearning 20%\n", b"mjxcpg: error: process 1: cannot write a checkpoint\n"]
    stream = b"".join([ours[0], ours[1], *cpp, ours[2], *cpp[:1], *traceback])
    stderr_filter, shown, logged = StderrFilter(), b"", b""
    for at in [*range(0, len(stream), 7), len(stream)]:
        out, log = stderr_filter.feed(stream[at:at + 7])
        shown, logged = shown + out, logged + log
    assert shown == b"".join([*ours, *traceback])
    assert logged == b"".join([*cpp, *cpp[:1]])


@pytest.mark.slow
def test_paper_config_on_three_processes_learns_as_its_blocks_alone(tmp_path):
    """The `paper` sweep on three processes: each process's nine learners learn exactly as
    the same nine do in a one-process run of their own, the same batch width (their weights,
    trial records and Table 1 entries).  (The final 20 s walks run in process 0 at the whole
    batch's width, another width than the blocks' runs walk at: their speeds are not
    compared.)"""
    run = tmp_path / "several"
    results = finish(start(SWEEP + ["--config", "paper"], run, count=3), timeout=3600)
    assert [rc for rc, _, _ in results] == [0, 0, 0], [err for _, _, err in results]
    spec = config.load_spec("paper")
    whole = final_state(run).learners
    rows = json.loads((run / "summary.json").read_text())["learners"]
    for block in np.array_split(np.arange(spec.batch), 3):
        alone = tmp_path / f"block-{block[0]}"
        path = tmp_path / f"block-{block[0]}.json"
        path.write_text(json.dumps(config.spec_to_dict(spec) | {"k_s": [spec.k_s[i] for i in block],
                                                                "seeds": [spec.seeds[i] for i in block]}))
        assert main(SWEEP + ["--config", str(path), "--out", str(alone)]) == 0
        mine = jax.tree.map(lambda x: np.asarray(x)[block], whole)
        reference = final_state(alone).learners
        assert all(jax.tree.leaves(jax.tree.map(np.array_equal, mine.weights, reference.weights))), block
        for field in ("trial", "trials_to_success", "returns", "falls", "velocities", "mean_abs_a5", "sigmas"):
            assert np.array_equal(getattr(mine.book, field), getattr(reference.book, field)), (block, field)
        for row, single in zip([rows[i] for i in block], json.loads((alone / "summary.json").read_text())["learners"]):
            for key in ("k_s", "seed", "succeeded", "trials_to_success", "trials"):
                assert row[key] == single[key], (block, key)
