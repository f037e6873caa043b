"""Step-throughput micro-benchmarks: robot-steps per second for every engine, batch size,
model and workload, side by side in one run.

A robot-step is one physics step of one robot.  The workloads:

* ``full``: physics, controller and learner, ``train.make_chunk`` on one learner per robot
  (our robot only), k_s = 10, from the start of learning.
* ``physics``: physics alone.  For our robot, exactly the physics steps ``full`` takes: the
  same run is advanced untimed while recording every state and servo target the engine was
  given, then only the engine replays them, timed (``_replayed_physics``).  So the two
  workloads step robots in the same states (MJX's solver and the C solver iterate more in
  some than in others).  The humanoid starts from ``qpos0`` under zero controls.  The C
  engines run their host side (``_simulate``: MuJoCo C on one thread, or ``mujoco.rollout``
  over the batch on all cores) in a plain Python loop, one call per control period as in a
  run, with no JAX in the loop; MJX runs a jitted ``lax.scan`` of ``engine.step``.

``full`` over ``physics`` at the same batch is what the controller, the learner and, for
the C engines, the host callback cost.  Compile time is reported apart and never counted
in a rate.  Each rate is the median over timed calls after a warm-up call.

Two test models: our robot (``mjxcpg/robots/qrio/qrio.xml``) and MJX's own benchmark humanoid
(``test_data/humanoid/humanoid.xml`` in the ``mujoco-mjx`` package, loaded as shipped and
started from ``qpos0``), whose figures compare with published MJX numbers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import functools
import importlib.metadata
import importlib.resources
import io
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control.sim import Simulation, make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.physics import engines
from mjxcpg.training import train

MODELS = ("qrio", "humanoid")
WORKLOADS = ("physics", "full")
BATCHES = (1, 27, 256, 1024)
RATIO_BATCH = 27                              # the paper's sweep: 27 learners
OVERHEAD_TARGETS = {"native": 0.25, "mjx": 0.10}  # the most full may cost over physics alone
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


def _compile(jitted, *args) -> tuple[Callable, float]:
    """``jitted`` compiled for ``args``, and the seconds that took."""
    start = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - start


def _compiled(step, state, *args) -> tuple[Callable[[], float], float]:
    """Compile ``state = step(state, *args)`` (``step`` jitted) once; return a runner and the
    compile time."""
    compiled, compile_s = _compile(step, state, *args)

    def run() -> float:
        nonlocal state
        start = time.perf_counter()
        state = jax.block_until_ready(compiled(state, *args))
        return time.perf_counter() - start

    return run, compile_s


def _learners(sim: Simulation, batch: int) -> tuple[train.RunSpec, Any]:
    spec = train.RunSpec(k_s=(FULL_K_S,) * batch, seeds=tuple(range(batch)))
    return spec, train.make_task(sim, spec)


def _full(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """``train.make_chunk``: physics, controller and learner, one learner per robot."""
    spec, task = _learners(sim, batch)
    chunk = train.make_chunk(sim, task, control_steps)
    run, compile_s = _compiled(chunk, train.init_run(sim, task, spec), sim.engine.init(sim.qpos0, batch))
    return Workload(run, batch * control_steps * sim.engine.substeps, compile_s)


def _replayed_physics(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """Our robot's physics alone, on exactly the states and servo targets that ``full`` steps.

    Each call advances its own copy of the ``full`` run by ``control_steps`` periods, untimed,
    recording what the engine was asked (``make_chunk(record=True)``); it then times the engine
    replaying those steps alone: the C engines' host side (``_simulate``) in a plain loop with no
    JAX, or a jitted scan of MJX's ``step``.  The n-th call replays the n-th call of ``full``.
    """
    engine = sim.engine
    spec, task = _learners(sim, batch)
    record = train.make_chunk(sim, task, control_steps, record=True)
    initial = engine.init(sim.qpos0, batch)
    run_state = train.init_run(sim, task, spec)
    if isinstance(engine, engines.MjxEngine):
        replay, compile_s = _mjx_replay(engine, jax.eval_shape(record, run_state, initial)[1])
    else:
        replay, compile_s = functools.partial(_c_replay, engine), None

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


def _mjx_replay(engine: engines.Engine, shapes: train.Transition) -> tuple[Callable, float]:
    """A compiled scan making MJX's recorded calls alone, active masks included (in lockstep
    MJX steps idle robots too and keeps their old state, as in ``full``); returns the timed
    replay and its compile time."""
    def steps(transitions):
        # Each call's whole new state is carried out of the loop, as ``full`` carries it: XLA
        # may then drop nothing (summing only qpos let it drop the sensors, for one).
        def one(_, t):
            return engine.step(t.physics, t.ctrl, t.active), None
        first = jax.tree.map(lambda x: x[0], transitions.physics)
        return jax.lax.scan(one, first, transitions)[0]

    compiled, compile_s = _compile(xla.jit(steps), shapes)

    def replay(transitions: train.Transition) -> float:
        start = time.perf_counter()
        jax.block_until_ready(compiled(transitions))
        return time.perf_counter() - start

    return replay, compile_s


def _humanoid_physics(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """MJX's humanoid from ``qpos0`` under zero controls, carried from call to call, with as
    many physics steps per engine call as our robot's control period."""
    model = mujoco.MjModel.from_xml_path(humanoid_path())
    engine = engines.make_engine(sim.engine.name, model, sim.engine.substeps)
    robot_steps = batch * control_steps * engine.substeps
    if not isinstance(engine, engines.MjxEngine):
        physics = np.asarray(engine.init(model.qpos0, batch).physics, np.float64)
        zeros = np.zeros((batch, model.nu))

        def run() -> float:
            nonlocal physics
            start = time.perf_counter()
            for _ in range(control_steps):
                physics, _ = engine._simulate(physics, zeros)
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


def time_workload(workload: Workload, options: Options) -> float | None:
    """Median robot-steps per second over timed calls after one warm-up call;
    None if the warm-up call alone used the budget."""
    start = time.perf_counter()
    workload.run()
    if time.perf_counter() - start >= options.budget_seconds:
        return None
    rates: list[float] = []
    timed_start = time.perf_counter()
    while True:
        call_start = time.perf_counter()
        rates.append(workload.robot_steps / workload.run())
        call_s = time.perf_counter() - call_start
        now = time.perf_counter()
        enough = now - timed_start >= options.seconds and len(rates) >= options.min_calls
        if enough or now - start + call_s > options.budget_seconds:
            return statistics.median(rates)


def cases(engine_names, models, batches, workloads) -> list[Case]:
    """Every combination that exists: the humanoid has no learner, so no ``full`` workload."""
    return [Case(e, m, b, w) for m in dict.fromkeys(models) for w in dict.fromkeys(workloads)
            for b in sorted(set(batches)) for e in dict.fromkeys(engine_names)
            if not (m == "humanoid" and w == "full")]


def run_benchmarks(todo: list[Case], options: Options,
                   log: Callable[[str], None] = lambda line: None) -> tuple[list[dict], list[dict]]:
    """Measure every case; return (results, skipped), each a list of records."""
    results, skipped = [], []
    sims: dict[str, Simulation] = {}
    last_rate: dict[tuple[str, str, str], tuple[int, float]] = {}  # (engine, model, workload) -> (batch, rate)
    for case in todo:
        key = (case.engine, case.model, case.workload)
        if key in last_rate:
            batch, rate = last_rate[key]
            robot_steps = case.batch * options.control_steps * sims[case.engine].engine.substeps
            projected = 2 * robot_steps / rate  # warm-up and one timed call, at the smaller batch's rate
            if projected > options.budget_seconds:
                reason = (f"about {projected:.0f} s of stepping at batch {batch}'s rate, "
                          f"over the {options.budget_seconds:g} s budget")
                skipped.append(case._asdict() | {"reason": reason})
                log(f"skip  {_label(case)}: {reason}")
                continue
        if case.engine not in sims:
            sims[case.engine] = make_simulation(case.engine)
        workload = build(case, sims[case.engine], options)
        rate = time_workload(workload, options)
        if rate is None:
            reason = f"one call took longer than the {options.budget_seconds:g} s budget"
            skipped.append(case._asdict() | {"reason": reason})
            log(f"skip  {_label(case)}: {reason}")
            continue
        last_rate[key] = (case.batch, rate)
        results.append(case._asdict() | {"robot_steps_per_s": rate, "compile_s": workload.compile_s})
        compiled = "" if workload.compile_s is None else f", compile {workload.compile_s:.1f} s"
        log(f"done  {_label(case)}: {rate:,.0f} robot-steps/s{compiled}")
    return results, skipped


def _label(case: Case) -> str:
    return f"{case.engine} {case.model} batch {case.batch} {case.workload}"


def overheads(results: list[dict], batch: int = RATIO_BATCH) -> list[dict]:
    """Per engine, at ``batch`` on our robot: full over physics rates and the cost of the
    controller and learner over physics alone (physics rate / full rate - 1)."""
    rates = {(r["engine"], r["workload"]): r["robot_steps_per_s"]
             for r in results if r["model"] == "qrio" and r["batch"] == batch}
    out = []
    for engine in engines.ENGINES:
        if (engine, "full") in rates and (engine, "physics") in rates:
            ratio = rates[engine, "full"] / rates[engine, "physics"]
            target = OVERHEAD_TARGETS.get(engine)
            out.append({"engine": engine, "batch": batch, "full_over_physics": ratio,
                        "overhead": 1 / ratio - 1, "target_overhead": target,
                        "meets_target": None if target is None else 1 / ratio - 1 <= target})
    return out


def machine() -> dict:
    """Where the figures come from: CPU, cores, JAX backend and devices, XLA:CPU's threads
    (``NPROC``, see ``xla.one_cpu_thread``), versions, load."""
    cpu = platform.processor()
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as f:
        cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    versions = {name: importlib.metadata.version(name)
                for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy")}
    return {
        "cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
        "python": sys.version.split()[0], "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "xla_cpu_threads": os.environ.get("NPROC", "one per core"), "versions": versions,
        "load_average_1min": os.getloadavg()[0],
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def format_table(results: list[dict], skipped: list[dict], engine_names) -> str:
    """Engines side by side, one row per model, workload and batch: robot-steps/s and
    compile seconds ('-' when nothing compiles, 'skipped' past the budget)."""
    cells = {(r["model"], r["workload"], r["batch"], r["engine"]):
             (f"{r['robot_steps_per_s']:,.0f}", "-" if r["compile_s"] is None else f"{r['compile_s']:.1f}")
             for r in results}
    cells |= {(s["model"], s["workload"], s["batch"], s["engine"]): ("skipped", "") for s in skipped}
    engine_names = list(dict.fromkeys(engine_names))
    rows = sorted({key[:3] for key in cells}, key=lambda k: (MODELS.index(k[0]), WORKLOADS.index(k[1]), k[2]))
    header = ["model", "workload", "batch"] + [f"{e} {col}" for e in engine_names for col in ("steps/s", "compile s")]
    lines = [[m, w, str(b)] + [c for e in engine_names for c in cells.get((m, w, b, e), ("", ""))]
             for m, w, b in rows]
    widths = [max(len(row[i]) for row in [header] + lines) for i in range(len(header))]
    fmt = lambda row: "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
    return "\n".join([fmt(header), fmt(["-" * w for w in widths])] + [fmt(row) for row in lines])


def format_overheads(ratios: list[dict]) -> str:
    lines = []
    for r in ratios:
        verdict = "" if r["target_overhead"] is None else (
            f" (target <= {r['target_overhead']:.0%}: {'met' if r['meets_target'] else 'missed'})")
        lines.append(f"{r['engine']} at batch {r['batch']}: full/physics = {r['full_over_physics']:.2f}; "
                     f"controller + learner cost {r['overhead']:.0%} over physics alone{verdict}")
    return "\n".join(lines)


def benchmark(engine_names=engines.ENGINES, models=MODELS, batches=BATCHES, workloads=WORKLOADS,
              options: Options = Options(), log: Callable[[str], None] | None = None) -> dict:
    """Run the benchmarks; the report: machine, options, results, skipped cases, overheads.
    ``log`` receives a progress line per case."""
    about = machine()
    results, skipped = run_benchmarks(cases(engine_names, models, batches, workloads), options,
                                      log or (lambda line: None))
    return {"machine": about, "options": dataclasses.asdict(options), "results": results,
            "skipped": skipped, "overheads": overheads(results)}
