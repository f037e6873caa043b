"""Kill ``mjxcpg reproduce`` with SIGKILL once inside every stage, and check that the same
command, run again until it ends, leaves the same results as one uninterrupted run.

    .venv/bin/python bench/kill_resume.py --config quick --out /tmp/kill_resume

Two directories under --out: ``uninterrupted`` and ``killed``.  The uninterrupted run's
``reproduce.json`` gives each stage's wall time; then for each stage in turn the command is
started again in ``killed``, and once that stage has started it is killed a random
(seeded) fraction of the stage's uninterrupted time later.  A last start runs to the end.
Then every result file of both (JSON, Markdown, PNG, CSV; not the checkpoints, the
TensorBoard logs or wall times) is compared, byte for byte, the run directory's own path
taken out of them; in JSON the keys that hold wall times are left out.  Exit status 0 when
every stage was killed and all results are identical.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

RESULT_SUFFIXES = (".json", ".md", ".png", ".csv")
NOT_RESULTS = ("checkpoints", "tensorboard")
TIMINGS = ("reproduce.json", "wall_s.json")
TIMING_KEY = "wall_s"
POLL_SECONDS = 0.2


def command(config: str, out: Path, extra: list[str]) -> list[str]:
    mjxcpg = Path(sys.executable).with_name("mjxcpg")
    return [str(mjxcpg), "reproduce", "--config", config, "--out", str(out), "--quiet", *extra]


def without_timings(value):
    """A JSON value with every wall-time key left out, at any depth."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if k != TIMING_KEY}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def results(out: Path) -> dict[str, bytes]:
    found = {}
    for path in sorted(out.rglob("*")):
        rel = path.relative_to(out)
        if not path.is_file() or path.suffix not in RESULT_SUFFIXES or rel.name in TIMINGS:
            continue
        if any(part in NOT_RESULTS for part in rel.parts):
            continue
        data = path.read_bytes().replace(str(out).encode(), b"RUN")
        if path.suffix == ".json":
            data = json.dumps(without_timings(json.loads(data)), sort_keys=True).encode()
        found[str(rel)] = data
    return found


def stages(out: Path) -> dict:
    try:
        return json.loads((out / TIMINGS[0]).read_text())
    except (FileNotFoundError, json.JSONDecodeError):  # not yet written, or being written
        return {}


def has_started(stage: str, previous: str | None, out: Path) -> bool:
    """Whether ``reproduce`` is in ``stage``: marked started, or not marked while the stage
    before it has finished (``reproduce.json`` is first written once the sweep has made the
    run directory, and the report, rewritten by every call, is never marked started)."""
    marks = stages(out).get("stages", {})
    if marks.get(stage) == "started":
        return True
    return stage not in marks and (previous is None or marks.get(previous) == "finished")


def kill_in(stage: str, previous: str | None, after: float, cmd: list[str], out: Path) -> str:
    """Start ``cmd``, wait for ``stage`` to start, SIGKILL it ``after`` seconds later; what happened."""
    process = subprocess.Popen(cmd, start_new_session=True)
    while not has_started(stage, previous, out):
        if process.poll() is not None:
            return f"ended (status {process.returncode}) before {stage} started"
        time.sleep(POLL_SECONDS)
    try:
        process.wait(timeout=after)
        return f"ended (status {process.returncode}) within {after:.1f} s of {stage}'s start"
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        return "killed"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="quick")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("extra", nargs="*", help="further reproduce options, after --")
    args = parser.parse_args()
    reference, killed = args.out / "uninterrupted", args.out / "killed"
    for path in (reference, killed):
        if path.exists():
            print(f"kill_resume: {path} exists; give a new --out", file=sys.stderr)
            return 2

    begun = time.monotonic()
    subprocess.run(command(args.config, reference, args.extra), check=True)
    walls = stages(reference)["wall_s"]
    print(f"uninterrupted: {time.monotonic() - begun:.0f} s; stages {walls}", flush=True)

    rng = random.Random(args.seed)
    missed = []
    cmd = command(args.config, killed, args.extra)
    previous = None
    for stage, wall in walls.items():
        after = rng.uniform(0.1, 0.9) * wall
        outcome = kill_in(stage, previous, after, cmd, killed)
        previous = stage
        print(f"{stage}: {outcome} ({after:.1f} s into it)", flush=True)
        if outcome != "killed":
            missed.append(stage)
    last = subprocess.run(cmd)
    if last.returncode != 0:
        print(f"kill_resume: the last start ended with status {last.returncode}", file=sys.stderr)
        return 1

    want, got = results(reference), results(killed)
    differ = sorted(name for name in want.keys() | got.keys() if want.get(name) != got.get(name))
    print(f"{len(walls) - len(missed)} of {len(walls)} stages killed; {len(want)} result files; "
          f"{len(differ)} differ")
    for name in differ:
        print(f"  differs: {name}")
    return 1 if differ or missed else 0


if __name__ == "__main__":
    sys.exit(main())
