"""What a finished run writes: final-policy gaits, Table 1, plots."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import jax
import numpy as np

from mjxcpg import plots, train, walk
from mjxcpg.learner import policy_mean_feedback

# Table 1, simulation column: k_s -> (experiments, successes, mean trials to success)
PAPER_TABLE1 = {0.0: (4, 1, 2385), 1.0: (3, 3, 528), 2.0: (3, 3, 195), 3.0: (4, 4, 464),
                4.0: (3, 2, 192), 5.0: (5, 2, 1011), 10.0: (5, 5, 95)}


def final_policy_gaits(sim, task, state: train.RunState, seconds: float = 20.0) -> list[dict]:
    """Every learner's final policy (mean, no noise) walks ``seconds``, all in one batch."""
    weights = state.learners.weights
    batch = weights.mean.shape[0]
    run = walk.make_walk(sim.engine, sim.layout, sim.params, round(seconds / sim.control_dt),
                         policy_mean_feedback(task))
    trace = run(sim.engine.init(sim.qpos0, batch), walk.initial_cpg(batch), weights)
    return [g.as_dict() for g in walk.summarise(trace, sim.control_dt)]


def table1(results: list[dict]) -> str:
    groups = defaultdict(list)
    for r in results:
        groups[r["k_s"]].append(r)
    lines = ["| k_s | experiments | successes | mean trials to success | paper: experiments | "
             "paper: successes | paper: mean trials |", "|---|---|---|---|---|---|---|"]
    for k_s in sorted(groups):
        rs = groups[k_s]
        done = [r["trials_to_success"] for r in rs if r["succeeded"]]
        mean = f"{np.mean(done):.0f}" if done else "-"
        paper = PAPER_TABLE1.get(k_s, ("-", "-", "-"))
        lines.append(f"| {k_s:g} | {len(rs)} | {len(done)} | {mean} | {paper[0]} | {paper[1]} | {paper[2]} |")
    done = [r["trials_to_success"] for r in results if r["succeeded"]]
    lines.append(f"| all | {len(results)} | {len(done)} | {np.mean(done):.0f} | 27 | 20 | 696 |"
                 if done else f"| all | {len(results)} | 0 | - | 27 | 20 | 696 |")
    return "\n".join(lines) + "\n"


def write_report(out: Path, spec: train.RunSpec, sim, task, state: train.RunState) -> dict:
    """summary.json (per learner, with its final policy's gait), table1.md, PNG plots."""
    results = train.learner_results(spec, state.learners)
    gaits = final_policy_gaits(sim, task, state)
    weights = jax.device_get(state.learners.weights)
    learners = []
    for i, (r, g) in enumerate(zip(results, gaits)):
        learners.append({
            "learner": i, "k_s": r["k_s"], "seed": r["seed"], "succeeded": r["succeeded"],
            "trials_to_success": r["trials_to_success"], "trials": r["trials"],
            "mean_vx": g["mean_vx"], "final_policy_fell": g["fell"],
            "policy_input_gradient": plots.input_dominance(weights.mean[i], task.basis),
        })
        plots.policy_map(weights.mean[i], task.basis, task.learner.a_max, out / f"policy_map_{i:02d}.png",
                         title=f"learner {i}: k_s={r['k_s']:g}, seed {r['seed']} (cf. Fig 5)")
    for k_s in sorted({r["k_s"] for r in results}):
        plots.learning_curves([r for r in results if r["k_s"] == k_s],
                              out / f"learning_curve_ks{k_s:g}.png", title=f"k_s = {k_s:g} (cf. Fig 4)")
    summary = {"engine": sim.engine.name, "learners": learners}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "returns.json").write_text(json.dumps(results))
    (out / "table1.md").write_text(table1(results))
    return summary
