"""A run's final policies walked on every engine: MJX against MuJoCo C at the gait level.

Each final policy (its mean, no noise; a control's own feedback) walks 20 s from standing
on the native C engine and on MJX, all learners of the run in one batch per engine; the
result is each policy's mean speed after 2 s of settling on both, their ratio, and whether
it fell.  A run learned on one engine is walked on the other too: that is the transfer.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mjxcpg import report, runs
from mjxcpg.sim import make_simulation

ENGINES = ("native", "mjx")


def walk_on_engines(run_dir: Path, seconds: float = 20.0) -> dict:
    """Walk the run's final policies on both engines; write and return ``transfer.json``."""
    spec, record = runs.read_config(run_dir)
    _, _, task, state = runs.load_run(run_dir)
    gaits = {}
    for engine in ENGINES:
        sim = make_simulation(engine, params=spec.controller, physics_dt=spec.physics_dt)
        gaits[engine] = report.final_policy_gaits(sim, task, state, seconds)
    summary = json.loads((run_dir / "summary.json").read_text())["learners"]
    rows = []
    for k, learner in enumerate(summary):
        c, x = gaits["native"][k], gaits["mjx"][k]
        rows.append({"learner": k, "k_s": learner["k_s"], "succeeded": learner["succeeded"],
                     "mean_vx_c": c["mean_vx"], "mean_vx_mjx": x["mean_vx"],
                     "mjx_over_c": x["mean_vx"] / c["mean_vx"] if c["mean_vx"] else float("nan"),
                     "fell_c": c["fell"], "fell_mjx": x["fell"]})
    # Speed ratios of the successful policies that walk on C (a fall or a standstill has none).
    off = np.array([abs(r["mjx_over_c"] - 1) for r in rows
                    if r["succeeded"] and not r["fell_c"] and np.isfinite(r["mjx_over_c"])])
    result = {"learned_on": record["engine"], "seconds": seconds, "learners": rows,
              "compared": int(off.size),
              "median_abs_difference": float(np.median(off)) if off.size else None,
              "max_abs_difference": float(off.max()) if off.size else None,
              "falls_c": sum(r["fell_c"] for r in rows), "falls_mjx": sum(r["fell_mjx"] for r in rows)}
    (run_dir / "transfer.json").write_text(json.dumps(report._json_safe(result), indent=1))
    return result
