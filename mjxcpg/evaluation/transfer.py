"""A run's final policies walked elsewhere: on every engine (MJX against MuJoCo C at the gait
level), and on the hardware robot of ``mjxcpg.physics.hardware``.

On the engines, each final policy (its mean, no noise) walks 20 s as a learning trial starts
(after the hand-designed feedback, ``TrialParams.walk_hand_seconds``), ``walks`` times: once
as learned and ``walks - 1`` times with every weight of its mean scaled by (1 + 1e-6 n),
n ~ N(0, 1), the same n on both engines.  Some learned gaits have no single 20 s speed: a
change of their weights of that size, the size of float32 rounding, moves their speed by tens
of percent on either engine alone (docs/engines.md); the mean over the walks is the figure
the engines are compared on.  A run learned on one engine is walked on the other too: that
is the transfer.
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
from mjxcpg.learning.learner import actor_feedback, policy_mean_feedback
from mjxcpg.physics import hardware
from mjxcpg.training import report, runs, train

ENGINES = ("native", "mjx")
RELATIVE_PERTURBATION = 1e-6  # of each mean weight: the size of float32 rounding


def perturbed_weights(weights, walks: int, seed: int = 0):
    """Each learner's weights ``walks`` times in a row, the first as they are, the others with
    every mean weight scaled by (1 + 1e-6 n), n ~ N(0, 1) drawn from ``seed``."""
    rows = jnp.repeat(jnp.arange(weights.mean.shape[0]), walks)
    repeated = jax.tree.map(lambda w: jnp.asarray(w)[rows], weights)
    n = jax.random.normal(jax.random.PRNGKey(seed), repeated.mean.shape).at[::walks].set(0.0)
    return repeated._replace(mean=repeated.mean * (1.0 + RELATIVE_PERTURBATION * n))


def engine_speeds(spec: train.RunSpec, weights, engine: str, seconds: float, walks: int) -> np.ndarray:
    """(learners, walks) mean speeds after settling of the final policies on ``engine``, each
    walked as a trial starts; NaN where the walk fell."""
    sim = spec.simulation(engine)
    task = train.make_task(sim, spec)
    trace = walk.walk_from_standing(sim, actor_feedback(task), perturbed_weights(weights, walks), seconds,
                                    hand_seconds=task.trial.walk_hand_seconds)
    speeds = [np.nan if g.fell else g.mean_vx for g in walk.summarise(trace, sim.control_dt)]
    return np.array(speeds).reshape(-1, walks)


def compare_engines(spec: train.RunSpec, weights, succeeded: Sequence[bool], learned_on: str,
                    seconds: float = 20.0, walks: int = 8) -> dict:
    """The final policies ``weights`` (one row per learner of ``spec``) walked on every engine:
    per learner its speeds as learned and over the walks, their ratio MJX / C, and its falls;
    over the successful policies that walk on C, the median and largest |MJX/C - 1|."""
    speeds = {engine: engine_speeds(spec, weights, engine, seconds, walks) for engine in ENGINES}
    rows = []
    for k, ok in enumerate(succeeded):
        c, x = speeds["native"][k], speeds["mjx"][k]
        mean_c = float(np.nanmean(c)) if np.isfinite(c).any() else float("nan")
        mean_x = float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")
        rows.append({"learner": k, "k_s": spec.k_s[k], "succeeded": bool(ok),
                     "as_learned_c": float(c[0]), "as_learned_mjx": float(x[0]),
                     "mean_vx_c": mean_c, "mean_vx_mjx": mean_x,
                     "spread_c": [float(np.nanmin(c)), float(np.nanmax(c))] if np.isfinite(c).any() else None,
                     "mjx_over_c": mean_x / mean_c if mean_c else float("nan"),
                     "falls_c": int(np.isnan(c).sum()), "falls_mjx": int(np.isnan(x).sum()),
                     "speeds_c": c.tolist(), "speeds_mjx": x.tolist()})
    off = np.array([abs(r["mjx_over_c"] - 1) for r in rows
                    if r["succeeded"] and not r["falls_c"] and np.isfinite(r["mjx_over_c"])])
    return {"learned_on": learned_on, "seconds": seconds, "walks": walks,
            "hand_seconds": spec.trial.walk_hand_seconds, "learners": rows, "compared": int(off.size),
            "median_abs_difference": float(np.median(off)) if off.size else None,
            "max_abs_difference": float(off.max()) if off.size else None,
            "within_3_percent": int((off <= 0.03).sum()), "within_10_percent": int((off <= 0.10).sum()),
            "falls_c": sum(r["falls_c"] for r in rows), "falls_mjx": sum(r["falls_mjx"] for r in rows)}


def walk_on_engines(run_dir: Path, seconds: float = 20.0, walks: int = 8) -> dict:
    """Walk the run's final policies on both engines (``compare_engines``); write and return
    ``transfer.json``."""
    spec, record = runs.read_config(run_dir)
    _, _, _, state = runs.load_run(run_dir)
    succeeded = np.asarray(state.learners.book.trials_to_success) >= 0
    result = compare_engines(spec, jax.device_get(state.learners.weights), succeeded, record["engine"],
                             seconds, walks)
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
