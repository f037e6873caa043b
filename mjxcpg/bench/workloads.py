"""The benchmarks' workloads: what one timed call steps, for each engine, model and workload
(``full``, ``physics``), built ready to time."""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.resources
import io
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control.sim import Simulation
from mjxcpg.jaxutil import xla
from mjxcpg.physics import engines
from mjxcpg.physics.model import with_power_sensors
from mjxcpg.training import train

MODELS = ("qrio", "humanoid")
WORKLOADS = ("physics", "full")
FULL_K_S = 10.0                               # velocity reward gain of every benchmarked learner


@dataclasses.dataclass(frozen=True)
class Options:
    """How long to measure.

    ``control_steps`` control periods make one timed call; calls repeat for ``seconds``
    (at least ``min_calls`` of them).  ``budget_seconds`` bounds a measurement's stepping
    (warm-up and timed calls, not compilation): a case whose warm-up and one timed call
    would not fit, as projected from the same case at a smaller batch, is skipped.
    """

    control_steps: int = 25
    seconds: float = 3.0
    min_calls: int = 3
    budget_seconds: float = 60.0


class Case(NamedTuple):
    engine: str
    model: str
    batch: int
    workload: str


class Workload(NamedTuple):
    """A benchmark ready to time: ``run`` advances the robots, waits for the result and
    returns the seconds of the measured part (all of it, but for ``_replayed_physics``)."""

    run: Callable[[], float]
    robot_steps: int           # physics steps x robots per call to ``run``
    compile_s: float | None    # None: nothing to compile (raw C)


def humanoid_path() -> str:
    """MJX's benchmark humanoid, shipped in the ``mujoco-mjx`` package."""
    with contextlib.redirect_stdout(io.StringIO()):  # mjx prints when the optional warp is absent
        path = importlib.resources.files("mujoco.mjx") / "test_data" / "humanoid" / "humanoid.xml"
    if not path.is_file():
        raise FileNotFoundError(f"MJX's humanoid test model is not at {path}")
    return str(path)


def _compiled(step, state, *args) -> tuple[Callable[[], float], float]:
    """Compile ``state = step(state, *args)`` (``step`` jitted) once; return a runner and the
    compile time."""
    compiled, compile_s = xla.compile_timed(step, state, *args)

    def run() -> float:
        nonlocal state
        start = time.perf_counter()
        state = jax.block_until_ready(compiled(state, *args))
        return time.perf_counter() - start

    return run, compile_s


def benchmark_learners(sim: Simulation, batch: int) -> tuple[train.RunSpec, Any]:
    """One k_s = 10 learner per robot, seeds 0, 1, ...: the spec and the task of ``full``."""
    spec = train.RunSpec(k_s=(FULL_K_S,) * batch, seeds=tuple(range(batch)))
    return spec, train.make_task(sim, spec)


def _full(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """``train.make_chunk``: physics, controller and learner, one learner per robot."""
    spec, task = benchmark_learners(sim, batch)
    chunk = train.make_chunk(sim, task, control_steps)
    run, compile_s = _compiled(chunk, train.init_run(sim, task, spec), sim.engine.init(sim.qpos0, batch))
    return Workload(run, batch * control_steps * sim.engine.substeps, compile_s)


def _replayed_physics(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """Our robot's physics alone, on exactly the states and servo targets that ``full`` steps.

    Each call advances its own copy of the ``full`` run by ``control_steps`` periods, untimed,
    recording what the engine was asked (``make_chunk(record=True)``); it then times the engine
    replaying those steps alone in a jitted scan of its ``step``, and for the C engines also
    their host side (``_simulate``) in a plain loop with no JAX, keeping the faster (at small
    batches the native engine steps inside XLA, ``physics.native_step``; at large ones its
    threads are reached from Python).  The n-th call replays the n-th call of ``full``.
    """
    engine = sim.engine
    spec, task = benchmark_learners(sim, batch)
    record = train.make_chunk(sim, task, control_steps, record=True)
    initial = engine.init(sim.qpos0, batch)
    run_state = train.init_run(sim, task, spec)
    in_xla, compile_s = _xla_replay(engine, jax.eval_shape(record, run_state, initial)[1])
    if isinstance(engine, engines.MjxEngine):
        replay = in_xla
    else:
        def replay(transitions: train.Transition) -> float:
            return min(_c_replay(engine, transitions), in_xla(transitions))

    def run() -> float:
        nonlocal run_state
        run_state, transitions = jax.block_until_ready(record(run_state, initial))
        return replay(transitions)

    return Workload(run, batch * control_steps * engine.substeps, compile_s)


def _c_replay(engine: engines.Engine, transitions: train.Transition) -> float:
    """Seconds the C engine's host side takes to step the recorded robots that were active."""
    physics = np.asarray(transitions.physics.physics, np.float64)
    ctrl = np.asarray(transitions.ctrl, np.float64)
    steps = [(physics[t, rows], ctrl[t, rows]) for t, active in enumerate(np.asarray(transitions.active))
             if (rows := np.flatnonzero(active)).size]
    start = time.perf_counter()
    for state, u in steps:
        engine._simulate(state, u)
    return time.perf_counter() - start


def _xla_replay(engine: engines.Engine, shapes: train.Transition) -> tuple[Callable, float]:
    """A compiled scan making the engine's recorded calls alone, active masks included (in
    lockstep MJX steps idle robots too and keeps their old state, as in ``full``); returns
    the timed replay and its compile time."""
    def steps(transitions):
        # Each call's whole new state is carried out of the loop, as ``full`` carries it: XLA
        # may then drop nothing (summing only qpos let it drop the sensors, for one).
        def one(_, t):
            return engine.step(t.physics, t.ctrl, t.active), None
        first = jax.tree.map(lambda x: x[0], transitions.physics)
        return jax.lax.scan(one, first, transitions)[0]

    compiled, compile_s = xla.compile_timed(xla.jit(steps), shapes)

    def replay(transitions: train.Transition) -> float:
        start = time.perf_counter()
        jax.block_until_ready(compiled(transitions))
        return time.perf_counter() - start

    return replay, compile_s


def _humanoid_physics(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """MJX's humanoid from ``qpos0`` under zero controls, carried from call to call, with as
    many physics steps per engine call as our robot's control period, and the power sensors
    the engines read on every model of ours."""
    model = with_power_sensors(mujoco.MjSpec.from_file(humanoid_path())).compile()
    engine = engines.make_engine(sim.engine.name, model, sim.engine.substeps)
    robot_steps = batch * control_steps * engine.substeps
    if not isinstance(engine, engines.MjxEngine):
        physics = np.asarray(engine.init(model.qpos0, batch).physics, np.float64)
        zeros = np.zeros((batch, model.nu))

        def run() -> float:
            nonlocal physics
            start = time.perf_counter()
            for _ in range(control_steps):
                physics = engine._simulate(physics, zeros)[0]
            return time.perf_counter() - start

        return Workload(run, robot_steps, None)
    zeros = jnp.zeros((batch, model.nu), jnp.float32)

    def steps(state):
        return jax.lax.scan(lambda s, _: (engine.step(s, zeros), None), state, None, length=control_steps)[0]

    run, compile_s = _compiled(xla.jit(steps), engine.init(model.qpos0, batch))
    return Workload(run, robot_steps, compile_s)


def build(case: Case, sim: Simulation, options: Options) -> Workload:
    """The workload of ``case`` (``sim``: our robot on the case's engine), compiled if it needs to be."""
    if case.model == "humanoid":
        return _humanoid_physics(sim, case.batch, options.control_steps)
    if case.workload == "full":
        return _full(sim, case.batch, options.control_steps)
    return _replayed_physics(sim, case.batch, options.control_steps)
