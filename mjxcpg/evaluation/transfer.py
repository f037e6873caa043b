"""A run's final policies walked elsewhere: on every engine (MJX against MuJoCo C at the gait
level), and on the hardware robot of ``mjxcpg.physics.hardware``.

On the engines, each final policy (its mean, no noise) walks as in the run's report: 20 s,
the first 2 s with the hand-designed feedback as a learning trial starts, its speed measured
over the policy's 18 s (``report.final_policy_gaits``).  It walks ``walks`` times: once as
learned and ``walks - 1`` times with every weight of its mean scaled by (1 + 1e-6 n),
n ~ N(0, 1), the same n on both engines and for the same learner in any batch.  Some learned
gaits have no single 20 s speed: a change of their weights of that size (about 8 times
float32's unit roundoff) moves their speed by tens of percent on either engine alone
(docs/engines.md); the mean over the walks is the figure the engines are compared on.  A run
learned on one engine is walked on the other too: that is the transfer.

On the hardware robot (``walk_policies``, ``hardware_transfer``) each policy walks from
standing, unlike the run's report (docs/hardware.md).
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
from mjxcpg.learning.learner import actor_feedback
from mjxcpg.physics import hardware
from mjxcpg.report import learning as report
from mjxcpg.training import files, runs, train

ENGINES = ("native", "mjx")
RELATIVE_PERTURBATION = 1e-6  # of each mean weight


def perturbed_weights(weights, walks: int, learners: Sequence[int], seed: int = 0):
    """Each learner's weights ``walks`` times in a row, the first as they are, the others with
    every mean weight scaled by (1 + 1e-6 n), n ~ N(0, 1) drawn from ``seed`` and the learner's
    index in its run (``learners``, one per row of ``weights``)."""
    rows = jnp.repeat(jnp.arange(weights.mean.shape[0]), walks)
    repeated = jax.tree.map(lambda w: jnp.asarray(w)[rows], weights)
    key = jax.random.PRNGKey(seed)
    n = jnp.concatenate([jax.random.normal(jax.random.fold_in(key, k), (walks,) + weights.mean.shape[1:])
                         for k in learners]).at[::walks].set(0.0)
    return repeated._replace(mean=repeated.mean * (1.0 + RELATIVE_PERTURBATION * n))


def engine_speeds(spec: train.RunSpec, weights, learners: Sequence[int], engine: str, seconds: float,
                  walks: int) -> np.ndarray:
    """(learners, walks) mean speeds of the final policies on ``engine`` (NaN where the walk
    fell); ``weights`` has one row per learner of ``spec``, ``learners`` their indices in
    their run."""
    sim = spec.simulation(engine)
    gaits = report.final_policy_gaits(sim, train.make_task(sim, spec),
                                      perturbed_weights(weights, walks, learners), seconds)
    return np.array([np.nan if g["fell"] else g["mean_vx"] for g in gaits]).reshape(-1, walks)


def _mean_and_spread(speeds: np.ndarray) -> tuple[float, list[float] | None]:
    upright = speeds[np.isfinite(speeds)]
    if not upright.size:
        return float("nan"), None
    return float(upright.mean()), [float(upright.min()), float(upright.max())]


def compare_engines(spec: train.RunSpec, weights, succeeded: Sequence[bool], learned_on: str,
                    seconds: float = report.WALK_SECONDS, walks: int = 8,
                    learners: Sequence[int] | None = None) -> dict:
    """The final policies ``weights`` (one row per learner of ``spec``; ``learners``: their
    indices in their run, by default 0, 1, ...) walked on every engine: per learner its speeds
    as learned and over the walks, their ratio MJX / C, and its falls; over the successful
    policies that fall in no walk on either engine, the median and largest |MJX/C - 1|."""
    learners = list(range(len(spec.k_s))) if learners is None else list(learners)
    speeds = {engine: engine_speeds(spec, weights, learners, engine, seconds, walks) for engine in ENGINES}
    rows = []
    for k, (learner, ok) in enumerate(zip(learners, succeeded, strict=True)):
        c, x = speeds["native"][k], speeds["mjx"][k]
        (mean_c, spread_c), (mean_x, spread_x) = _mean_and_spread(c), _mean_and_spread(x)
        rows.append({"learner": learner, "k_s": spec.k_s[k], "succeeded": bool(ok),
                     "as_learned_c": float(c[0]), "as_learned_mjx": float(x[0]),
                     "mean_vx_c": mean_c, "mean_vx_mjx": mean_x, "spread_c": spread_c, "spread_mjx": spread_x,
                     "mjx_over_c": mean_x / mean_c if mean_c else float("nan"),
                     "falls_c": int(np.isnan(c).sum()), "falls_mjx": int(np.isnan(x).sum()),
                     "speeds_c": c.tolist(), "speeds_mjx": x.tolist()})
    successful = [r for r in rows if r["succeeded"]]
    fell = [r for r in successful if r["falls_c"] or r["falls_mjx"]]
    off = np.array([abs(r["mjx_over_c"] - 1) for r in successful
                    if r not in fell and np.isfinite(r["mjx_over_c"])])
    return {"learned_on": learned_on, "seconds": seconds, "walks": walks,
            "hand_seconds": spec.trial.walk_hand_seconds, "learners": rows, "compared": int(off.size),
            "successful_that_fell": [r["learner"] for r in fell],
            "median_abs_difference": float(np.median(off)) if off.size else None,
            "max_abs_difference": float(off.max()) if off.size else None,
            "within_3_percent": int((off <= 0.03).sum()), "within_10_percent": int((off <= 0.10).sum()),
            "falls_c": sum(r["falls_c"] for r in rows), "falls_mjx": sum(r["falls_mjx"] for r in rows)}


def row_line(row: dict, walks: int) -> str:
    """One learner of ``compare_engines`` in a line: its mean speeds, their ratio, its falls."""
    return (f"learner {row['learner']:3d}  k_s {row['k_s']:4g}  mean over {walks} walks: C {row['mean_vx_c']:.4f}"
            f"  MJX {row['mean_vx_mjx']:.4f}  MJX/C {row['mjx_over_c']:.3f}"
            + (f"  falls on C {row['falls_c']}" if row["falls_c"] else "")
            + (f"  falls on MJX {row['falls_mjx']}" if row["falls_mjx"] else ""))


def walk_on_engines(run_dir: Path, seconds: float = report.WALK_SECONDS, walks: int = 8,
                    force: bool = False) -> dict:
    """Walk the run's final policies on both engines (``compare_engines``); write and return
    ``transfer.json``, holding the run's lock; an earlier one is replaced only with ``force``."""
    spec, record = runs.read_config(run_dir)
    with runs.locked(run_dir):
        runs.refuse_earlier_output(run_dir, ("transfer.json",), force, "transfer")
        _, _, _, state = runs.load_run(run_dir)
        succeeded = np.asarray(state.learners.book.trials_to_success) >= 0
        result = compare_engines(spec, jax.device_get(state.learners.weights), succeeded, record["engine"],
                                 seconds, walks)
        files.write_text_atomic(run_dir / "transfer.json", json.dumps(report.json_safe(result), indent=1))
    return result


def walk_policies(run_dir: Path | str, robot: str = "hardware", seconds: float = 20.0,
                  engine: str | None = None, learners: Sequence[int] | None = None,
                  repeats: int = 1, noise_seed: int = hardware.HARDWARE.noise_seed,
                  hand_seconds: float = 0.0) -> list[dict]:
    """Each chosen learner's final policy (its mean, no exploration noise) walking from the
    standing pose for ``seconds`` on ``robot``, ``repeats`` times (each walk its own batch
    row, hence on the hardware robot its own sensor-noise stream, drawn from ``noise_seed``),
    all in one batch; with ``hand_seconds`` > 0 the hand-designed feedback starts the walk,
    as it starts every learning trial, and the speed is measured after it.

    Per learner: index, k_s, seed, whether learning succeeded in simulation, ``walks`` (how
    many of the repeats went ``seconds`` without a fall), ``walked`` (all of them did), the
    shortest time before a fall and the mean forward speed over the walks that did not fall
    (ground truth, as an observer measures it).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    spec, sim, task, state = runs.load_run(Path(run_dir), engine, robot=robot)
    if isinstance(sim.engine, hardware.HardwareEngine) and noise_seed != sim.engine.mismatch.noise_seed:
        sim = dataclasses.replace(sim, engine=sim.engine.with_noise_seed(noise_seed))
    chosen = runs.check_learners(spec, learners)
    rows = jnp.repeat(jnp.asarray(chosen), repeats)
    weights = jax.tree.map(lambda w: w[rows], state.learners.weights)
    trace = walk.walk_from_standing(sim, actor_feedback(task), weights, seconds, hand_seconds=hand_seconds)
    gaits = walk.summarise(trace, sim.control_dt, sim.layout.weight,
                           settle_s=max(walk.SETTLE_SECONDS, hand_seconds))
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
             learners: Sequence[int] | None = None, repeats: int = 1,
             noise_seed: int = hardware.HARDWARE.noise_seed, robot: str = "hardware",
             hand_seconds: float = 0.0) -> dict:
    """How many learned policies of a run walk ``seconds`` on the hardware robot (or on
    ``robot``, another of ``hardware.MISMATCHES``).

    Every chosen learner walks once on the nominal robot (deterministic) and ``repeats``
    times on the hardware robot, each time with other sensor noise, drawn from ``noise_seed``
    (``walk_policies``).
    ``learners`` in the result has one row per learner with both outcomes. The counts are
    over the learners whose learning succeeded in simulation (the paper: 14 of 20 walked on
    QRIO): ``walk_hardware`` counts policies that walked in every repeat, ``walk_hardware_any``
    those that walked in at least one.
    """
    nominal = walk_policies(run_dir, "nominal", seconds, engine, learners, hand_seconds=hand_seconds)
    on_hardware = walk_policies(run_dir, robot, seconds, engine, learners, repeats, noise_seed, hand_seconds)
    rows = [{"learner": n["learner"], "k_s": n["k_s"], "seed": n["seed"], "succeeded": n["succeeded"],
             "walked_nominal": n["walked"], "mean_vx_nominal": n["mean_vx"],
             "walked_hardware": h["walked"], "walks_hardware": h["walks"],
             "seconds_hardware": h["seconds"], "mean_vx_hardware": h["mean_vx"]}
            for n, h in zip(nominal, on_hardware)]
    learned = [r for r in rows if r["succeeded"]]
    mismatch = dataclasses.replace(hardware.MISMATCHES[robot], noise_seed=noise_seed)
    return {"robot": robot, "seconds": seconds, "hand_seconds": hand_seconds, "repeats": repeats, "mismatch": dataclasses.asdict(mismatch),
            "succeeded_in_simulation": len(learned),
            "walk_nominal": sum(r["walked_nominal"] for r in learned),
            "walk_hardware": sum(r["walked_hardware"] for r in learned),
            "walk_hardware_any": sum(r["walks_hardware"] > 0 for r in learned),
            "learners": rows}
