"""Choose the physics step and the control period by measurement.

For each (physics step, control period) on a ladder, and for the same pair halved, this
measures on the native engine:

* the gait: 20 s walks of the hand-designed controller a_5 = K d(theta_roll)/dt for several
  K (forward speed, gait period, pelvis height, falls);
* learning: ``--seeds`` learners at k_s = 10 with the paper's settings (successes, mean trials
  to success, the final policies' speed).

The CPG keeps a 1 ms integration step whatever the control period.  Run it on a quiet machine:

    python bench/timestep.py --json > bench/results/timestep.json
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mjxcpg.control import walk
from mjxcpg.control.controller import ControllerParams, roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.jaxutil import xla
from mjxcpg.learning.learner import TrialParams
from mjxcpg.report import learning as report
from mjxcpg.training import runs
from mjxcpg.training.train import RunSpec

LADDER = ((0.002, 0.004), (0.004, 0.008), (0.008, 0.008), (0.008, 0.016), (0.016, 0.016))
HAND_GAINS = (0.0, 0.5, 1.0, 2.0)
CPG_STEP = 0.001


def controller_for(control_dt: float) -> ControllerParams:
    return ControllerParams(control_dt=control_dt, cpg_substeps=round(control_dt / CPG_STEP))


def gait(physics_dt: float, control_dt: float, seconds: float = 20.0) -> list[dict]:
    """The hand-designed controller at each gain of ``HAND_GAINS``, one batch."""
    sim = make_simulation("native", params=controller_for(control_dt), physics_dt=physics_dt)
    trace = walk.walk_from_standing(sim, roll_rate_feedback, jnp.array(HAND_GAINS), seconds)
    return [{"gain": k, **g.as_dict()} for k, g in zip(HAND_GAINS, walk.summarise(trace, control_dt, sim.layout.weight))]


def learning(physics_dt: float, control_dt: float, seeds: int, max_trials: int) -> dict:
    """``seeds`` learners at k_s = 10: successes, trials to success, final-policy speed."""
    spec = RunSpec(k_s=(10.0,) * seeds, seeds=tuple(range(seeds)), physics_dt=physics_dt,
                   controller=controller_for(control_dt), trial=TrialParams(max_trials=max_trials))
    with tempfile.TemporaryDirectory() as out:
        sim, task, state, wall_s = runs.execute(Path(out), spec, "native", progress=False)
        rows = report.write_report(Path(out), spec, sim, task, state)["learners"]
    trials = [r["trials_to_success"] for r in rows if r["succeeded"]]
    speeds = [r["mean_vx"] for r in rows if r["succeeded"] and not r["final_policy_fell"]]
    return {"succeeded": len(trials), "learners": seeds,
            "trials_to_success": trials, "mean_trials": float(np.mean(trials)) if trials else None,
            "final_vx": float(np.mean(speeds)) if speeds else None, "wall_s": wall_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--max-trials", type=int, default=400)
    parser.add_argument("--skip-learning", action="store_true")
    parser.add_argument("--learning-up-to", type=float, default=0.004,
                        help="learn only at physics steps up to this (s): coarser ones already fail the gait test")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = []
    for physics_dt, control_dt in LADDER:
        start = time.perf_counter()
        row = {"physics_dt": physics_dt, "control_dt": control_dt,
               "gait": gait(physics_dt, control_dt)}
        if not args.skip_learning and physics_dt <= args.learning_up_to:
            row["learning"] = learning(physics_dt, control_dt, args.seeds, args.max_trials)
        row["wall_s"] = time.perf_counter() - start
        results.append(row)
        speeds = " ".join(f"{g['mean_vx']:.3f}{'F' if g['fell'] else ''}" for g in row["gait"])
        learned = row.get("learning", {})
        print(f"physics {physics_dt * 1e3:g} ms, control {control_dt * 1e3:g} ms: "
              f"vx(K={HAND_GAINS}) {speeds}; period(K=1) {row['gait'][2]['gait_period']}; "
              f"learning {learned.get('succeeded')}/{args.seeds}, mean trials "
              f"{learned.get('mean_trials')}, final vx {learned.get('final_vx')}", flush=True)
    if args.json:
        print(json.dumps({"ladder": results}))


if __name__ == "__main__":
    xla.one_cpu_thread()  # as the mjxcpg program does
    main()
