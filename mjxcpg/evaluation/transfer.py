"""A run's final policies walked elsewhere: on every engine (MJX against MuJoCo C at the gait
level), and on the hardware robot of ``mjxcpg.physics.hardware``.

Each final policy (its mean, no noise; a control's own feedback) walks 20 s from standing
on the native C engine and on MJX, all learners of the run in one batch per engine; the
result is each policy's mean speed after 2 s of settling on both, their ratio, and whether
it fell.  A run learned on one engine is walked on the other too: that is the transfer.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control import walk
from mjxcpg.learning.learner import policy_mean_feedback
from mjxcpg.physics import hardware
from mjxcpg.training import report, runs

ENGINES = ("native", "mjx")


def walk_on_engines(run_dir: Path, seconds: float = 20.0) -> dict:
    """Walk the run's final policies on both engines; write and return ``transfer.json``."""
    spec, record = runs.read_config(run_dir)
    _, _, task, state = runs.load_run(run_dir)
    gaits = {}
    for engine in ENGINES:
        sim = spec.simulation(engine)
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
    (run_dir / "transfer.json").write_text(json.dumps(report.json_safe(result), indent=1))
    return result


def walk_policies(run_dir: Path | str, robot: str = "hardware", seconds: float = 20.0,
                  engine: str | None = None, learners: Sequence[int] | None = None,
                  repeats: int = 1) -> list[dict]:
    """Each chosen learner's final policy (its mean, no exploration noise) walking from the
    standing pose for ``seconds`` on ``robot``, ``repeats`` times (each walk its own batch
    row, hence on the hardware robot its own sensor-noise stream), all in one batch.

    Per learner: index, k_s, seed, whether learning succeeded in simulation, ``walks`` (how
    many of the repeats went ``seconds`` without a fall), ``walked`` (all of them did), the
    shortest time before a fall and the mean forward speed over the walks that did not fall
    (ground truth, as an observer measures it).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    spec, sim, task, state = runs.load_run(Path(run_dir), engine, robot=robot)
    chosen = runs.check_learners(spec, learners)
    rows = jnp.repeat(jnp.asarray(chosen), repeats)
    weights = jax.tree.map(lambda w: w[rows], state.learners.weights)
    trace = walk.walk_from_standing(sim, policy_mean_feedback(task), weights, seconds)
    gaits = walk.summarise(trace, sim.control_dt)
    succeeded = np.asarray(state.learners.book.trials_to_success)[chosen] >= 0
    results = []
    for i, (k, ok) in enumerate(zip(chosen, succeeded)):
        mine = gaits[i * repeats:(i + 1) * repeats]
        upright = [g.mean_vx for g in mine if not g.fell]
        results.append({"learner": k, "k_s": spec.k_s[k], "seed": spec.seeds[k], "succeeded": bool(ok),
                        "walks": len(upright), "walked": len(upright) == repeats,
                        "seconds": min(g.seconds for g in mine),
                        "mean_vx": float(np.mean(upright)) if upright else None})
    return results


def hardware_transfer(run_dir: Path | str, seconds: float = 20.0, engine: str | None = None,
             learners: Sequence[int] | None = None, repeats: int = 1) -> dict:
    """How many learned policies of a run walk ``seconds`` on the hardware robot.

    Every chosen learner walks once on the nominal robot (deterministic) and ``repeats``
    times on the hardware robot, each time with other sensor noise (``walk_policies``).
    ``learners`` in the result has one row per learner with both outcomes. The counts are
    over the learners whose learning succeeded in simulation (the paper: 14 of 20 walked on
    QRIO): ``walk_hardware`` counts policies that walked in every repeat, ``walk_hardware_any``
    those that walked in at least one.
    """
    nominal = walk_policies(run_dir, "nominal", seconds, engine, learners)
    on_hardware = walk_policies(run_dir, "hardware", seconds, engine, learners, repeats)
    rows = [{"learner": n["learner"], "k_s": n["k_s"], "seed": n["seed"], "succeeded": n["succeeded"],
             "walked_nominal": n["walked"], "mean_vx_nominal": n["mean_vx"],
             "walked_hardware": h["walked"], "walks_hardware": h["walks"],
             "seconds_hardware": h["seconds"], "mean_vx_hardware": h["mean_vx"]}
            for n, h in zip(nominal, on_hardware)]
    learned = [r for r in rows if r["succeeded"]]
    return {"seconds": seconds, "repeats": repeats, "mismatch": dataclasses.asdict(hardware.HARDWARE),
            "succeeded_in_simulation": len(learned),
            "walk_nominal": sum(r["walked_nominal"] for r in learned),
            "walk_hardware": sum(r["walked_hardware"] for r in learned),
            "walk_hardware_any": sum(r["walks_hardware"] > 0 for r in learned),
            "learners": rows}
