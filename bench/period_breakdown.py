"""Where one control period's time goes at small batches, on the native engine.

For each batch, a learning chunk is recorded (``train.make_chunk(record=True)``: the states
the engine was handed and the servo targets), after a warm-up chunk, and the same periods are
then timed piece by piece, each the median of ``--repeats`` timed calls:

* ``mujoco``: MuJoCo C alone, ``mujoco.rollout`` over the whole recorded chunk in one
  call (the recorded targets, open loop, from the first recorded state): the stepping cost
  without any per-period call;
* ``host step``: the engine's host side, called once per period from Python on the recorded
  states (``_host_step``: the float32-float64 conversions, ``rollout``, the divergence test);
* ``step, host callback``: a jitted ``lax.scan`` of the engine's step through XLA's host
  callback on the recorded states and targets, nothing else;
* ``step, in XLA``: the same through the FFI handler (``mjxcpg.physics.native_step``), the
  native engine's path below 4 robots per thread;
* ``controller + learner``: ``train.make_chunk`` on an engine that never steps
  (``bench/learner_cost.py``);
* ``full, host callback`` and ``full, in XLA``: ``train.make_chunk`` with either step.

Rows are microseconds per control period (two physics steps per robot), with the derived
shares: the callback's own cost (its step - host step), what each ``full`` costs beyond its
step and the controller and learner together, and MuJoCo alone over each ``full``.

    NPROC=1 .venv/bin/python bench/period_breakdown.py [--batches 1 2 4] [--json]
"""

import argparse
import dataclasses
import json
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

from learner_cost import NoPhysics
from mjxcpg import bench
from mjxcpg.bench import workloads
from mjxcpg.control.sim import make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.physics import engines
from mjxcpg.training import train


class CallbackNative(engines.NativeEngine):
    """The native engine with its host callback at every batch size."""

    def step(self, state, ctrl, active=None, pelvis_force=None):
        return engines._CEngine.step(self, state, ctrl, active, pelvis_force)


def median_seconds(run, repeats: int) -> float:
    run()  # warm-up (and compilation)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def breakdown(batch: int, steps: int, repeats: int) -> dict:
    sim = make_simulation("native")
    engine, substeps = sim.engine, sim.engine.substeps
    spec, task = workloads.benchmark_learners(sim, batch)
    initial = engine.init(sim.qpos0, batch)
    record = train.make_chunk(sim, task, steps, record=True)
    state = train.init_run(sim, task, spec)
    state, _ = jax.block_until_ready(record(state, initial))          # past the standing start
    after, transitions = jax.block_until_ready(record(state, initial))
    physics = np.asarray(transitions.physics.physics, np.float32)     # (steps, batch, nstate)
    sensordata = np.asarray(transitions.physics.sensordata, np.float32)
    work = np.asarray(transitions.physics.positive_work, np.float32)
    ctrl = np.asarray(transitions.ctrl, np.float32)
    active = np.ones(batch, bool)

    # MuJoCo C alone: one rollout call over the whole chunk.
    runner = rollout.Rollout(nthread=0)
    datas = [mujoco.MjData(engine.model)]
    control = np.repeat(ctrl.astype(np.float64).transpose(1, 0, 2), substeps, axis=1)  # (batch, steps * substeps, nu)
    start_state = physics[0].astype(np.float64)

    def mujoco_alone():
        runner.rollout([engine.model] * batch, datas, start_state, control, control_spec=int(mujoco.mjtState.mjSTATE_CTRL),
                       skip_checks=True, nstep=steps * substeps, initial_warmstart=np.zeros((batch, engine.model.nv)))

    def host_steps():
        for t in range(steps):
            engine._host_step(physics[t].copy(), sensordata[t].copy(), work[t].copy(), ctrl[t], active)

    callback_sim = dataclasses.replace(sim, engine=CallbackNative(sim.model, substeps))
    first = jax.tree.map(lambda x: x[0], transitions.physics)
    ctrls = jnp.asarray(ctrl)

    def step_scan(stepper):
        # Each period steps its recorded state, and the stepped state is carried out of the
        # loop so that XLA drops nothing.
        scan = jax.jit(lambda first, recorded: jax.lax.scan(
            lambda _, t: (stepper.step(t[0], t[1]), None), first, recorded)[0])
        return lambda: jax.block_until_ready(scan(first, (transitions.physics, ctrls)))

    no_physics = dataclasses.replace(sim, engine=NoPhysics(sim.model, substeps))
    learner_chunk = train.make_chunk(no_physics, train.make_task(no_physics, spec), steps)
    learner_state = after

    def controller_and_learner():
        jax.block_until_ready(learner_chunk(learner_state, initial))

    def full_with(simulation):
        chunk = train.make_chunk(simulation, train.make_task(simulation, spec), steps)
        return lambda: jax.block_until_ready(chunk(after, initial))

    us = {name: median_seconds(run, repeats) / steps * 1e6 for name, run in (
        ("mujoco", mujoco_alone), ("host step", host_steps),
        ("step, host callback", step_scan(callback_sim.engine)), ("step, in XLA", step_scan(engine)),
        ("controller + learner", controller_and_learner),
        ("full, host callback", full_with(callback_sim)), ("full, in XLA", full_with(sim)))}
    us["callback's own"] = us["step, host callback"] - us["host step"]
    for path in ("host callback", "in XLA"):
        us[f"full beyond step, controller, learner ({path})"] = (
            us[f"full, {path}"] - us[f"step, {path}"] - us["controller + learner"])
    for path in ("host callback", "in XLA"):
        us[f"mujoco / full ({path})"] = us["mujoco"] / us[f"full, {path}"]
    return {"batch": batch, **us}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--steps", type=int, default=500, help="control periods per timed call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    rows = [breakdown(b, args.steps, args.repeats) for b in args.batches]
    names = [k for k in rows[0] if k != "batch"]
    print("| us per control period | " + " | ".join(f"batch {r['batch']}" for r in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{r[name]:.2f}" if name.startswith("mujoco /") else f"{r[name]:.1f}"
                                         for r in rows) + " |")
    if args.json:
        print(json.dumps({"machine": bench.machine(), "rows": rows}))
    return 0


if __name__ == "__main__":
    xla.one_cpu_thread()  # as the mjxcpg program does
    sys.exit(main(sys.argv[1:]))
