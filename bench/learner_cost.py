"""The controller and learner alone: microseconds per control period, without physics.

    python bench/learner_cost.py [--batches 1 27 256 1024] [--json]

``train.make_chunk`` runs over an engine whose step hands the state back unchanged (plus a
data dependency on the servo targets, so that XLA cannot hoist the learner out of the loop
as loop-invariant).  This is what ``mjxcpg bench``'s ``full`` workload adds to ``physics``,
measured directly; on MJX, where one program holds both and the solver's cost varies with
the robots' states, it is the only clean way to tell the learner's share.
"""

import argparse
import dataclasses
import json
import statistics
import sys
import time

import jax

from mjxcpg import bench
from mjxcpg.bench import workloads
from mjxcpg.control.sim import make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.physics import engines
from mjxcpg.training import train


class NoPhysics(engines.NativeEngine):
    """The native engine's state and sensors, never stepped."""

    def step(self, state, ctrl, active=None, pelvis_force=None):
        return state._replace(physics=state.physics + 0 * ctrl.sum())


def learner_us_per_period(batch: int, steps: int, calls: int) -> float:
    sim = make_simulation("native")
    sim = dataclasses.replace(sim, engine=NoPhysics(sim.model, sim.engine.substeps))
    spec, task = workloads.benchmark_learners(sim, batch)
    chunk = train.make_chunk(sim, task, steps)
    state, initial = train.init_run(sim, task, spec), sim.engine.init(sim.qpos0, batch)
    state = jax.block_until_ready(chunk(state, initial))
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        state = jax.block_until_ready(chunk(state, initial))
        times.append(time.perf_counter() - start)
    return statistics.median(times) / steps * 1e6


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 27, 256, 1024])
    parser.add_argument("--steps", type=int, default=500, help="control periods per timed call")
    parser.add_argument("--calls", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    results = [{"batch": b, "us_per_period": learner_us_per_period(b, args.steps, args.calls)}
               for b in args.batches]
    for r in results:
        print(f"batch {r['batch']:5d}: {r['us_per_period']:8.1f} us per control period, "
              f"{r['us_per_period'] / r['batch']:6.2f} us per learner", file=sys.stderr)
    if args.json:
        print(json.dumps({"machine": bench.machine(), "results": results}))
    return 0


if __name__ == "__main__":
    xla.one_cpu_thread()  # as the mjxcpg program does
    sys.exit(main(sys.argv[1:]))
