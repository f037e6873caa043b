"""How much a learned policy's 20 s speed moves under perturbations the size of rounding.

Each chosen final policy (its mean, no noise) walks 20 s from standing ``--rows`` times on
each engine: once as learned, then with every weight of its mean scaled by (1 + 1e-6 n),
n ~ N(0, 1), a fresh n per walk (the same n on every engine). A policy whose speed spreads
widely here has no single 20 s speed to compare across engines; the mean over the walks is
the comparable figure.

    NPROC=1 .venv/bin/python bench/speed_sensitivity.py runs/paper --learners 5 19 --rows 8
"""

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control import walk
from mjxcpg.learning.learner import policy_mean_feedback
from mjxcpg.training import runs

RELATIVE_PERTURBATION = 1e-6


def speeds(run_dir: Path, engine: str, learners: list[int], rows: int) -> np.ndarray:
    """(len(learners), rows) 20 s mean speeds; NaN where the walk fell."""
    spec, sim, task, state = runs.load_run(run_dir, engine)
    chosen = jnp.repeat(jnp.asarray(learners), rows)
    weights = jax.tree.map(lambda w: w[chosen], state.learners.weights)
    n = jax.random.normal(jax.random.PRNGKey(0), weights.mean.shape).at[::rows].set(0.0)
    weights = weights._replace(mean=weights.mean * (1.0 + RELATIVE_PERTURBATION * n))
    gaits = walk.summarise(walk.walk_from_standing(sim, policy_mean_feedback(task), weights, 20.0),
                           sim.control_dt)
    return np.array([np.nan if g.fell else g.mean_vx for g in gaits]).reshape(len(learners), rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--learners", type=int, nargs="+", required=True)
    parser.add_argument("--rows", type=int, default=8)
    parser.add_argument("--engines", nargs="+", default=["native", "mjx"])
    args = parser.parse_args()
    table = {e: speeds(args.run, e, args.learners, args.rows) for e in args.engines}
    print("| learner | engine | as learned | perturbed: min | max | mean over the walks | falls |")
    print("|---|---|---|---|---|---|---|")
    for i, learner in enumerate(args.learners):
        for engine, v in table.items():
            row = v[i]
            print(f"| {learner} | {engine} | {row[0]:.4f} | {np.nanmin(row):.4f} | {np.nanmax(row):.4f} | "
                  f"{np.nanmean(row):.4f} | {int(np.isnan(row).sum())}/{len(row)} |")


if __name__ == "__main__":
    main()
