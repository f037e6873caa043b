"""A finished run's wall time against what MuJoCo C alone needs for the same physics steps.

From the run's TensorBoard events (``tensorboard/run``: after every chunk, its wall time, the
learners finished and the robot-steps per second), each chunk's robot-steps are known: the
learners unfinished before it, times its control periods, times the physics steps per
period.  The lower bound steps that many robots with raw MuJoCo C (``mujoco.rollout``, one
call over many recorded states) on the threads the run's engine used for that chunk
(``Engine.threads_for`` of its rows: the native engine's threads from
``engines._ROBOTS_PER_THREAD`` robots per thread, else one; ``--cores``: fewer, for a run
pinned to fewer cores than its engine has threads).  On several threads the cost per
robot-step is measured on those threads, not divided by their number: the machine's own
scaling counts, as it does for the run.
Both sides count from the first chunk's end (its compilation apart) to the last chunk's end.

The C cost per robot-step is measured here, on states of the run's own spec: a chunk of
``--periods`` control periods of its first 8 learners is recorded (after a warm-up chunk from
standing), and every recorded (state, servo targets) pair is stepped once; the fastest of
``--repeats`` such passes counts, as befits a lower bound.  Runs of one spec and engine share
one measurement, so that they are compared on the same bound.  Run it on the machine that
made the run, and on a quiet one.

    NPROC=1 .venv/bin/python bench/sweep_lower_bound.py runs/printed [--periods 500]

It also prints each run by phase: the chunks that ran at each batch width, their wall time
and their bound.
"""

import argparse
import dataclasses
import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import mujoco
import numpy as np
from mujoco import rollout

from mjxcpg.jaxutil import xla
from mjxcpg.training import runs, train
from mjxcpg.training.events import EVENTS_DIR, RUN_NAME, read_events

SAMPLE_LEARNERS = 8


class CCost(NamedTuple):
    per_step: float           # seconds per robot-step of raw MuJoCo C on one thread
    per_step_threaded: float  # the same on the engine's threads (at most ``cores``)
    threads: int              # those threads
    substeps: int
    threads_for: Callable[[int], int]  # the engine's: how many threads stepped a batch of that size


@functools.cache
def c_seconds_per_robot_step(spec: train.RunSpec, engine_name: str, periods: int, cores: int | None,
                             repeats: int) -> CCost:
    """Raw MuJoCo C's cost per robot-step on the run's states (module docstring)."""
    sample = dataclasses.replace(spec, k_s=spec.k_s[:SAMPLE_LEARNERS], seeds=spec.seeds[:SAMPLE_LEARNERS])
    sim = sample.simulation(engine_name)
    task = train.make_task(sim, sample)
    record = train.make_chunk(sim, task, periods, record=True)
    initial = sim.engine.init(sim.qpos0, sample.batch)
    state, _ = jax.block_until_ready(record(train.init_run(sim, task, sample), initial))
    _, transitions = jax.block_until_ready(record(state, initial))
    physics = np.asarray(transitions.physics.physics, np.float64).reshape(-1, sim.engine.nstate)
    ctrl = np.asarray(transitions.ctrl, np.float64).reshape(len(physics), 1, -1)
    substeps = sim.engine.substeps
    control = np.ascontiguousarray(np.repeat(ctrl, substeps, axis=1))
    model = sim.model
    out_state = np.empty((len(physics), substeps, len(physics[0])))
    out_sensors = np.empty((len(physics), substeps, model.nsensordata))
    threads = min(getattr(sim.engine, "threads", 1), cores or getattr(sim.engine, "threads", 1))

    def per_step(nthread: int) -> float:
        runner = rollout.Rollout(nthread=nthread if nthread > 1 else 0)
        data = [mujoco.MjData(model) for _ in range(nthread)]
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            runner.rollout([model] * len(physics), data, physics, control,
                           control_spec=int(mujoco.mjtState.mjSTATE_CTRL), skip_checks=True, nstep=substeps,
                           initial_warmstart=np.zeros((len(physics), model.nv)), state=out_state,
                           sensordata=out_sensors)
            times.append(time.perf_counter() - start)
        return min(times) / (len(physics) * substeps)

    return CCost(per_step(1), per_step(threads), threads, substeps, sim.engine.threads_for)


def lower_bound(run_dir: Path, periods: int, cores: int | None, repeats: int) -> dict:
    spec, record = runs.read_config(run_dir)
    events = [(wall, values) for wall, _, values in read_events(run_dir / EVENTS_DIR / RUN_NAME)]
    c = c_seconds_per_robot_step(spec, record["engine"], periods, cores, repeats)
    chunk_periods = round(spec.chunk_seconds / spec.controller.control_dt)
    bound, robot_steps = 0.0, 0
    phases: dict[int, list[float]] = {}  # rows -> [chunks, wall s, bound s]
    for (start, before), (end, after) in zip(events, events[1:]):
        active = spec.batch - int(before["progress/learners_finished"])
        rows = train.compacted_size(active, spec.batch)
        steps = active * chunk_periods * c.substeps
        robot_steps += steps
        chunk_bound = steps * (c.per_step_threaded if c.threads_for(rows) > 1 else c.per_step)
        bound += chunk_bound
        phase = phases.setdefault(rows, [0, 0.0, 0.0])
        phase[0] += 1
        phase[1] += end - start
        phase[2] += chunk_bound
    wall = events[-1][0] - events[0][0]
    return {"run": str(run_dir), "engine": record["engine"], "wall_s": wall, "robot_steps": robot_steps,
            "c_us_per_robot_step": c.per_step * 1e6, "c_us_per_robot_step_threads": c.per_step_threaded * 1e6,
            "threads": c.threads, "lower_bound_s": bound, "phases": phases,
            "ratio": wall / bound if bound else None}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--periods", type=int, default=500, help="control periods recorded for the C cost")
    parser.add_argument("--repeats", type=int, default=7, help="passes over the recorded states; the fastest counts")
    parser.add_argument("--cores", type=int, default=None,
                        help="cores the run had (a run pinned with taskset had fewer than its engine's threads)")
    args = parser.parse_args(argv)
    print("| run | engine | wall, first chunk's end to last (s) | robot-steps | raw C (us per robot-step, 1 thread) "
          "| on the threads | lower bound (s) | wall / bound |")
    print("|---|---|---|---|---|---|---|---|")
    phases = []
    for run in args.runs:
        r = lower_bound(run, args.periods, args.cores, args.repeats)
        print(f"| {r['run']} | {r['engine']} | {r['wall_s']:.1f} | {r['robot_steps']:,} | {r['c_us_per_robot_step']:.2f} "
              f"| {r['c_us_per_robot_step_threads']:.2f} ({r['threads']}) | {r['lower_bound_s']:.1f} | {r['ratio']:.2f} |")
        phases.append(r)
    for r in phases:
        print(f"\n{r['run']}, by the rows its chunks ran (the batch as it shrinks)\n\n"
              "| rows | chunks | wall (s) | lower bound (s) | wall / bound |\n|---|---|---|---|---|")
        for rows, (chunks, wall, bound) in sorted(r["phases"].items(), reverse=True):
            print(f"| {rows} | {chunks} | {wall:.1f} | {bound:.1f} | {wall / bound:.2f} |")
    return 0


if __name__ == "__main__":
    xla.one_cpu_thread()
    sys.exit(main(sys.argv[1:]))
