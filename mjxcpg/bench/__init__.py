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
import importlib.metadata
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable

import jax

from mjxcpg.bench.workloads import MODELS, WORKLOADS, Case, Options, Workload, build
from mjxcpg.control.sim import Simulation, make_simulation
from mjxcpg.physics import engines

BATCHES = (1, 27, 256, 1024)
RATIO_BATCH = 27                              # the paper's sweep: 27 learners
OVERHEAD_TARGETS = {"native": 0.25, "mjx": 0.10}  # the most full may cost over physics alone


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
