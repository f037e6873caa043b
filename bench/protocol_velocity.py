"""Each final policy's 20 s velocity, from standing and after the learning trials' start.

A learning trial starts with the hand-designed feedback (1-3 s) and hands over to the
policy; the run's summary walks each final policy (its mean, no noise) after 2 s of it.
This walks every learner's final policy both ways, 20 s on the run's engine:
``from standing`` and ``after 2 s of the hand-designed feedback`` (the middle of the
trials' hand-over window), and prints per k_s the mean velocity with its 95% bootstrap
interval, the walks that fell, Spearman's rho between k_s and the per-k_s means and the
least-squares slope of velocity on k_s with its interval (a fallen walk counts with its
mean velocity up to the fall, as in the run's summary), and the a_5 = 0 gait's velocity in
the same walk.

    NPROC=1 .venv/bin/python bench/protocol_velocity.py runs/stats [--learners 10 11 ...]
"""

import argparse
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mjxcpg.control import walk
from mjxcpg.report import learning as report
from mjxcpg.training import runs, stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--learners", type=int, nargs="+", default=None, help="default: all")
    args = parser.parse_args()
    spec, sim, task, state = runs.load_run(args.run)
    chosen = runs.check_learners(spec, args.learners)
    hand_seconds = spec.trial.walk_hand_seconds
    k_s = np.array([spec.k_s[i] for i in chosen])
    for label, start in (("from standing", 0.0), (f"after {hand_seconds:g} s of the hand-designed feedback",
                                                 hand_seconds)):
        # The whole batch walks, as for the run's summary, whose trial-start figures this repeats.
        walked = report.final_policy_gaits(sim, task, state.learners.weights, hand_seconds=start)
        gaits = [walked[i] for i in chosen]
        v = np.array([g["mean_vx"] for g in gaits])
        fell = np.array([g["fell"] for g in gaits])
        groups = sorted(set(k_s))
        means = {k: stats.mean_interval(v[k_s == k]) for k in groups}
        print(f"\n{label}\n\n| k_s | learners | fell | 20 s velocity (m/s) |\n|---|---|---|---|")
        for k in groups:
            print(f"| {k:g} | {int(np.sum(k_s == k))} | {int(np.sum(fell[k_s == k]))} | {means[k].format('.3f')} |")
        if len(groups) > 1:
            rho = stats.spearman(groups, [means[k].value for k in groups])
            print(f"\nSpearman rho {rho:.2f}; slope {stats.slope_interval(k_s, v).format('.4f')} m/s per unit k_s")
        zero = walk.summarise(walk.walk_from_standing(sim, lambda obs, k: 0.0 * k, jnp.zeros(1), 20.0,
                                                     hand_seconds=start), sim.control_dt, sim.layout.weight)[0]
        print(f"a_5 = 0 (control c), the same walk: {zero.mean_vx:.3f} m/s" + (", fell" if zero.fell else ""))


if __name__ == "__main__":
    try:
        main()
    except runs.RunError as error:
        raise SystemExit(f"protocol_velocity: {error}") from None
