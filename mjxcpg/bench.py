"""Step-throughput micro-benchmarks: robot-steps per second for every engine, batch size,
model and workload, side by side in one run.

A robot-step is one physics step of one robot.  The workloads:

* ``physics``: physics alone.  Our robot replays, open loop, the servo targets of its
  hand-designed gait (recorded on MuJoCo C), so it walks as in ``full``; the humanoid gets
  zero controls.  The C engines run their host side (``_simulate``: MuJoCo C on one
  thread, or ``mujoco.rollout`` over the batch on all cores) in a plain Python loop, one call
  per control period as in a run, with no JAX in the loop; MJX runs a jitted ``lax.scan`` of
  ``engine.step``.
* ``full``: physics, controller and learner, ``train.make_chunk`` on one learner per robot
  (our robot only).

``full`` over ``physics`` at the same batch is what the controller, the learner and, for
the C engines, the host callback cost.  Compile time is reported apart and never counted
in a rate.  Each rate is the median over timed calls after a warm-up call.

Two test models: our robot (``models/qrio.xml``) and MJX's own benchmark humanoid
(``test_data/humanoid/humanoid.xml`` in the ``mujoco-mjx`` package, loaded as shipped and
started from ``qpos0``), whose figures compare with published MJX numbers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import importlib.metadata
import importlib.resources
import io
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg import engines, train, walk, xla
from mjxcpg.controller import control_step, roll_rate_feedback
from mjxcpg.robot import observe
from mjxcpg.sim import Simulation, make_simulation

MODELS = ("qrio", "humanoid")
WORKLOADS = ("physics", "full")
BATCHES = (1, 27, 256, 1024)
RATIO_BATCH = 27                              # the paper's sweep: 27 learners
OVERHEAD_TARGETS = {"native": 0.25, "mjx": 0.10}  # issue 5: full costs at most this much over physics
FULL_K_S = 10.0                               # velocity reward gain of every benchmarked learner
FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


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
    """A benchmark ready to time: ``run`` advances the robots and waits for the result."""

    run: Callable[[], None]
    robot_steps: int           # physics steps x robots per call to ``run``
    compile_s: float | None    # None: nothing to compile (raw C)


def humanoid_path() -> str:
    """MJX's benchmark humanoid, shipped in the ``mujoco-mjx`` package."""
    with contextlib.redirect_stdout(io.StringIO()):  # mjx prints when the optional warp is absent
        path = importlib.resources.files("mujoco.mjx") / "test_data" / "humanoid" / "humanoid.xml"
    if not path.is_file():
        raise FileNotFoundError(f"MJX's humanoid test model is not at {path}")
    return str(path)


class _Robots(NamedTuple):
    """An engine for one model, with the pose and the servo targets a physics benchmark replays."""

    engine: engines.Engine
    qpos: np.ndarray
    ctrl: np.ndarray           # (control periods, nu), replayed open loop from ``qpos``


WALK_REPLAY_SECONDS = 20.0


def walking_controls(sim: Simulation, seconds: float = WALK_REPLAY_SECONDS) -> np.ndarray:
    """The servo targets of the hand-designed gait from the standing pose, one row per control
    period, recorded on MuJoCo C.  Replayed open loop from the same pose, the C engines walk
    exactly this gait again, so ``physics`` and ``full`` step robots in like contact states."""
    recorder = make_simulation("mujoco", params=sim.params, physics_dt=sim.model.opt.timestep)
    engine, layout, params = recorder.engine, recorder.layout, recorder.params

    def one_robot(cpg_state, sensors):
        obs = observe(layout, sensors)
        return control_step(params, layout, cpg_state, obs, roll_rate_feedback(obs, params.hand_gain))

    def period(carry, _):
        physics, cpg_state = carry
        cpg_state, ctrl = jax.vmap(one_robot)(cpg_state, engine.sensors(physics))
        return (engine.step(physics, ctrl), cpg_state), ctrl[0]

    steps = round(seconds / params.control_dt)
    _, ctrl = xla.jit(lambda c: jax.lax.scan(period, c, None, length=steps))(
        (engine.init(recorder.qpos0, 1), walk.initial_cpg(1)))
    return np.asarray(ctrl, np.float64)


def _robots(sim: Simulation, model: str) -> _Robots:
    """``model`` on ``sim``'s engine kind; our robot is ``sim``'s own, replaying its gait."""
    if model == "qrio":
        return _Robots(sim.engine, sim.qpos0, walking_controls(sim))
    humanoid = mujoco.MjModel.from_xml_path(humanoid_path())
    # The same physics steps per engine call as our robot's control period; zero controls.
    return _Robots(engines.make_engine(sim.engine.name, humanoid, sim.engine.substeps), humanoid.qpos0.copy(),
                   np.zeros((1, humanoid.nu)))


def _compiled(step, state, *args) -> tuple[Callable[[], None], float]:
    """Compile ``state = step(state, *args)`` (``step`` jitted) once; return a runner and the
    compile time."""
    start = time.perf_counter()
    compiled = step.lower(state, *args).compile()
    compile_s = time.perf_counter() - start

    def run() -> None:
        nonlocal state
        state = jax.block_until_ready(compiled(state, *args))

    return run, compile_s


def _raw_c_physics(robots: _Robots, batch: int, control_steps: int) -> Workload:
    """The C engine's host side in a Python loop: no JAX, no callback.  The recorded servo
    targets are replayed period by period; at their end every robot starts over from the pose."""
    engine, model = robots.engine, robots.engine.model
    data = mujoco.MjData(model)
    data.qpos[:] = robots.qpos
    mujoco.mj_forward(model, data)
    start = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
    mujoco.mj_getState(model, data, start, FULLPHYSICS)
    physics, period = np.tile(start, (batch, 1)), 0

    def run() -> None:
        nonlocal physics, period
        for _ in range(control_steps):
            if period == len(robots.ctrl):
                physics, period = np.tile(start, (batch, 1)), 0
            physics, _ = engine._simulate(physics, np.tile(robots.ctrl[period], (batch, 1)))
            period += 1

    return Workload(run, batch * control_steps * engine.substeps, None)


def _mjx_physics(robots: _Robots, batch: int, control_steps: int) -> Workload:
    """A jitted ``lax.scan`` of ``engine.step`` over the recorded servo targets: every call
    replays the first ``control_steps`` of them from the pose, so it stays a walk's start."""
    engine = robots.engine
    rows = np.arange(control_steps) % len(robots.ctrl)
    ctrl = jnp.tile(jnp.asarray(robots.ctrl[rows], jnp.float32)[:, None, :], (1, batch, 1))
    pose = engine.init(robots.qpos, batch)

    def steps(state, ctrl):
        return jax.lax.scan(lambda s, u: (engine.step(s, u), None), state, ctrl)[0]

    start = time.perf_counter()
    compiled = xla.jit(steps).lower(pose, ctrl).compile()
    compile_s = time.perf_counter() - start
    return Workload(lambda: jax.block_until_ready(compiled(pose, ctrl)) and None,
                    batch * control_steps * engine.substeps, compile_s)


def _full(sim: Simulation, batch: int, control_steps: int) -> Workload:
    """``train.make_chunk``: physics, controller and learner, one learner per robot."""
    spec = train.RunSpec(k_s=(FULL_K_S,) * batch, seeds=tuple(range(batch)))
    task = train.make_task(sim, spec)
    chunk = train.make_chunk(sim, task, control_steps)
    run, compile_s = _compiled(chunk, train.init_run(sim, task, spec), sim.engine.init(sim.qpos0, batch))
    return Workload(run, batch * control_steps * sim.engine.substeps, compile_s)


def build(case: Case, sim: Simulation, robots: _Robots, options: Options) -> Workload:
    """The workload of ``case`` (``sim``: our robot on the case's engine), compiled if it needs to be."""
    if case.workload == "full":
        return _full(sim, case.batch, options.control_steps)
    if case.engine == "mjx":
        return _mjx_physics(robots, case.batch, options.control_steps)
    return _raw_c_physics(robots, case.batch, options.control_steps)


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
        workload.run()
        call_s = time.perf_counter() - call_start
        rates.append(workload.robot_steps / call_s)
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
    robots: dict[tuple[str, str], _Robots] = {}
    last_rate: dict[tuple[str, str, str], tuple[int, float]] = {}  # (engine, model, workload) -> (batch, rate)
    for case in todo:
        key = (case.engine, case.model, case.workload)
        if key in last_rate:
            batch, rate = last_rate[key]
            robot_steps = case.batch * options.control_steps * robots[case.engine, case.model].engine.substeps
            projected = 2 * robot_steps / rate  # warm-up and one timed call, at the smaller batch's rate
            if projected > options.budget_seconds:
                reason = (f"about {projected:.0f} s of stepping at batch {batch}'s rate, "
                          f"over the {options.budget_seconds:g} s budget")
                skipped.append(case._asdict() | {"reason": reason})
                log(f"skip  {_label(case)}: {reason}")
                continue
        if case.engine not in sims:
            sims[case.engine] = make_simulation(case.engine)
        if (case.engine, case.model) not in robots:
            robots[case.engine, case.model] = _robots(sims[case.engine], case.model)
        workload = build(case, sims[case.engine], robots[case.engine, case.model], options)
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
    """Where the figures come from: CPU, cores, JAX backend and devices, versions, load."""
    cpu = platform.processor()
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as f:
        cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    versions = {name: importlib.metadata.version(name)
                for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy")}
    return {
        "cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
        "python": sys.version.split()[0], "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()], "versions": versions,
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
