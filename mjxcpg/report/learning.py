"""What a finished run writes: summary.json, returns.json, its final policies' gaits, Table 1
(with any controls beside the learners), stats.json and the learning plots."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import jax
import numpy as np

from mjxcpg.control import walk
from mjxcpg.learning.learner import actor_feedback
from mjxcpg.report import plots
from mjxcpg.training import stats, train
from mjxcpg.training.files import write_text_atomic

# Table 1, simulation column: k_s -> (experiments, successes, mean trials to success)
PAPER_TABLE1 = {0.0: (4, 1, 2385), 1.0: (3, 3, 528), 2.0: (3, 3, 195), 3.0: (4, 4, 464),
                4.0: (3, 2, 192), 5.0: (5, 2, 1011), 10.0: (5, 5, 95)}


WALK_SECONDS = 20.0  # a final policy's walk, its hand-designed start included


def final_policy_gaits(sim, task, weights, seconds: float = WALK_SECONDS,
                       hand_seconds: float | None = None) -> list[dict]:
    """Every learner's final policy (mean, no noise; a control's own feedback) walks
    ``seconds``, all in one batch, the first ``hand_seconds`` of them with the hand-designed
    feedback: by default as a learning trial starts (``TrialParams.walk_hand_seconds``); 0
    walks it from standing.  ``weights``: one row per robot.  Its speed and height are
    measured after the hand-designed start, and never before ``walk.SETTLE_SECONDS``."""
    if hand_seconds is None:
        hand_seconds = task.trial.walk_hand_seconds
    # On one device: this walk, unlike the learning, is not bit-stable under sharding.
    trace = walk.walk_from_standing(sim, actor_feedback(task), jax.device_get(weights), seconds,
                                    hand_seconds=hand_seconds)
    settle = max(walk.SETTLE_SECONDS, hand_seconds)
    return [g.as_dict() for g in walk.summarise(trace, sim.control_dt, sim.layout.weight, settle_s=settle)]


def group_of(row: dict) -> tuple[float, float | None]:
    """A learner's cell: its k_s and, in a run with energy gains, its k_E."""
    return row["k_s"], row.get("k_e")


def group_label(group: tuple[float, float | None]) -> str:
    k_s, k_e = group
    return f"{k_s:g}" if k_e is None else f"{k_s:g}, k_E {k_e:g}"


def _sortable(group: tuple[float, float | None]) -> tuple[float, float]:
    return group[0], -1.0 if group[1] is None else group[1]


def table1(results: list[dict]) -> str:
    groups = defaultdict(list)
    for r in results:
        groups[group_of(r)].append(r)
    lines = ["| k_s | experiments | successes | mean trials to success | paper: experiments | "
             "paper: successes | paper: mean trials |", "|---|---|---|---|---|---|---|"]
    for group in sorted(groups, key=_sortable):
        rs = groups[group]
        done = [r["trials_to_success"] for r in rs if r["succeeded"]]
        mean = f"{np.mean(done):.0f}" if done else "-"
        paper = PAPER_TABLE1.get(group[0], ("-", "-", "-"))
        lines.append(f"| {group_label(group)} | {len(rs)} | {len(done)} | {mean} | {paper[0]} | {paper[1]} | "
                     f"{paper[2]} |")
    done = [r["trials_to_success"] for r in results if r["succeeded"]]
    lines.append(f"| all | {len(results)} | {len(done)} | {np.mean(done):.0f} | 27 | 20 | 696 |"
                 if done else f"| all | {len(results)} | 0 | - | 27 | 20 | 696 |")
    return "\n".join(lines) + "\n"


def write_report(out: Path, spec: train.RunSpec, sim, task, state: train.RunState, plots_too: bool = True) -> dict:
    """summary.json (per learner, with its final policy's gait), returns.json (per trial),
    table1.md, and unless ``plots_too`` is False the PNG plots."""
    results = train.learner_results(spec, state.learners)
    gaits = final_policy_gaits(sim, task, state.learners.weights)
    weights = jax.device_get(state.learners.weights)
    learners = []
    for i, (r, g) in enumerate(zip(results, gaits)):
        learners.append({
            "learner": i, "k_s": r["k_s"], **({"k_e": r["k_e"]} if "k_e" in r else {}), "seed": r["seed"],
            "succeeded": r["succeeded"],
            "trials_to_success": r["trials_to_success"], "trials": r["trials"],
            "mean_vx": g["mean_vx"], "final_policy_fell": g["fell"],
            "policy_input_gradient": plots.input_dominance(task.learner.propulsive_mean(weights.mean[i]), task.basis),
        })
        if plots_too:
            gradient = learners[-1]["policy_input_gradient"]
            plots.policy_map(task.learner.propulsive_mean(weights.mean[i]), task.basis, task.learner.a_max, out / f"policy_map_{i:02d}.png",
                             title=f"learner {i}: k_s={r['k_s']:g}, seed {r['seed']} (cf. Fig 5)\n"
                                   f"mean |dmu/d roll rate| {gradient['roll_rate']:.2f}, "
                                   f"|dmu/d pitch rate| {gradient['pitch_rate']:.2f}",
                             v_scale=task.learner.v_scale)
    if plots_too:
        for k_s in sorted({r["k_s"] for r in results}):
            plots.learning_curves([r for r in results if r["k_s"] == k_s],
                                  out / f"learning_curve_ks{k_s:g}.png", title=f"k_s = {k_s:g} (cf. Fig 4)")
        plots.diagnostics(results, out / "diagnostics.png")
    summary = {"engine": sim.engine.name, "success_streak": spec.trial.success_streak,
               "walk": {"seconds": WALK_SECONDS, "hand_seconds": task.trial.walk_hand_seconds}, "learners": learners}
    write_text_atomic(out / "returns.json", json.dumps(results))
    write_table1(out, summary)
    # Last: a run directory with summary.json is finished, and holds all of its results.
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1))
    return summary


# ---------------------------------------------------------------- learners against controls

CONTROL_LABELS = {
    "learning_off": "(a) learning off, sigma as initialised",
    "learning_off_min_sigma": "(b) learning off, sigma at its smallest",
    "zero_feedback": "(c) a_5 = 0",
    "hand_feedback": "(d) hand-designed feedback",
}


def learner_metrics(summary: dict, results: list[dict]) -> list[dict]:
    """Per learner of a finished run (its summary.json and returns.json): success, trials to
    success, fall rate and mean return per trial, the mean return of its last
    ``success_streak`` trials, and its final policy's 20 s velocity (policy mean, no noise)."""
    streak = summary.get("success_streak", 20)
    rows = []
    for learner, r in zip(summary["learners"], results, strict=True):
        returns, falls = np.asarray(r["returns"], float), np.asarray(r["falls"], float)
        rows.append({
            "k_s": learner["k_s"], **({"k_e": learner["k_e"]} if "k_e" in learner else {}),
            "succeeded": learner["succeeded"],
            "trials_to_success": learner["trials_to_success"], "trials": learner["trials"],
            "fall_rate": float(falls.mean()) if falls.size else float("nan"),
            "mean_return": float(returns.mean()) if returns.size else float("nan"),
            "final_return": float(returns[-streak:].mean()) if returns.size else float("nan"),
            "velocity_20s": learner["mean_vx"],
        })
    return rows


def arm_rows(label: str, rows: list[dict]) -> list[str]:
    """Table lines for one arm (the learners or a control): per k_s and all together, with
    95% bootstrap intervals over learners."""
    lines = []
    groups = sorted({group_of(r) for r in rows}, key=_sortable)
    for group in groups + ["all"]:
        rs = rows if group == "all" else [r for r in rows if group_of(r) == group]
        done = [r["trials_to_success"] for r in rs if r["succeeded"]]
        cells = [stats.mean_interval(done).format(".0f")] + [
            stats.mean_interval([r[key] for r in rs]).format(spec)
            for key, spec in (("fall_rate", ".2f"), ("mean_return", ".2f"), ("final_return", ".2f"),
                              ("velocity_20s", ".3f"))]
        name = "all" if group == "all" else group_label(group)
        lines.append(f"| {label} | {name} | {len(done)}/{len(rs)} | " + " | ".join(cells) + " |")
    return lines


def velocity_trend(rows: list[dict]) -> dict:
    """Fig 7 as numbers: each k_s's mean 20 s velocity with its interval, Spearman's rho
    between k_s and those means, and the least-squares slope of velocity on k_s over the
    learners with its interval; in a run with energy gains, over its k_E = 0 learners."""
    rows = [r for r in rows if not r.get("k_e")]
    ks = sorted({r["k_s"] for r in rows})
    per_ks = {k: stats.mean_interval([r["velocity_20s"] for r in rows if r["k_s"] == k]) for k in ks}
    return {
        "per_k_s": {f"{k:g}": e.as_dict() for k, e in per_ks.items()},
        "spearman_rho": stats.spearman(ks, [per_ks[k].value for k in ks]) if len(ks) > 1 else float("nan"),
        "slope": stats.slope_interval([r["k_s"] for r in rows], [r["velocity_20s"] for r in rows]).as_dict()
        if len(ks) > 1 else None,
    }


def walk_description(walk_record: dict | None) -> str:
    """How a summary.json's final policies walked, in words (``None``: a summary written
    before the walk was recorded, which walked 20 s from standing)."""
    if walk_record is None:
        return "a 20 s walk from standing (an earlier version's summary)"
    seconds, hand = walk_record["seconds"], walk_record["hand_seconds"]
    measured = f"measured from {max(walk.SETTLE_SECONDS, hand):g} s on"
    if not hand:
        return f"a {seconds:g} s walk from standing, {measured}"
    return (f"a {seconds:g} s walk whose first {hand:g} s are the hand-designed feedback, as a learning "
            f"trial starts, {measured}")


def write_table1(run_dir: Path, summary: dict | None = None) -> str:
    """table1.md of a finished run: Table 1 beside the paper's, the learners and whatever
    controls ``run_dir/controls/`` holds in one table, and velocity against k_s (Fig 7);
    the numbers also go to stats.json.  ``summary``: the run's summary.json, when it is
    not yet written."""
    results = json.loads((run_dir / "returns.json").read_text())
    if summary is None:
        summary = json.loads((run_dir / "summary.json").read_text())
    arms = {"learners": learner_metrics(summary, results)}
    walks = {"learners": summary.get("walk")}
    for name in CONTROL_LABELS:
        control = run_dir / "controls" / name
        if (control / "summary.json").is_file():
            control_summary = json.loads((control / "summary.json").read_text())
            arms[name] = learner_metrics(control_summary, json.loads((control / "returns.json").read_text()))
            walks[name] = control_summary.get("walk")
    lines = [table1(results), "",
             "Learners and controls, each with its 95% bootstrap interval over learners. Fall rate "
             "and mean return are per trial; the final return is the mean over the last success-streak trials; "
             f"velocity is the final policy's mean (policy mean, no noise) over {walk_description(walks['learners'])}.",
             "", "| arm | k_s | successes | trials to success | fall rate | mean return | final return | "
             "20 s velocity (m/s) |", "|---|---|---|---|---|---|---|---|"]
    for name, rows in arms.items():
        lines += arm_rows(CONTROL_LABELS.get(name, "learners"), rows)
    other = [name for name, w in walks.items() if w != walks["learners"]]
    if other:
        lines += ["", "Walked otherwise, so their velocities do not compare with the learners': "
                  + "; ".join(f"{CONTROL_LABELS[name]} over {walk_description(walks[name])}" for name in other)
                  + " (`mjxcpg controls --force` runs them again)."]
    learners = arms["learners"]
    trend = velocity_trend(learners)
    if trend["slope"] is not None:
        slope = stats.Estimate(**trend["slope"])
        lines += ["", f"Velocity against k_s (Fig 7): Spearman rho between k_s and the per-k_s mean "
                      f"velocity {trend['spearman_rho']:.2f}; least-squares slope "
                      f"{slope.format('.4f')} m/s per unit k_s over {slope.n} learners."]
    text = "\n".join(lines) + "\n"
    write_text_atomic(run_dir / "table1.md", text)
    write_text_atomic(run_dir / "stats.json", json.dumps(json_safe({"arms": arms, "velocity_trend": trend}), indent=1))
    return text


def json_safe(tree):
    """NaN and infinities become null: the evaluation JSON stays strict JSON."""
    if isinstance(tree, dict):
        return {k: json_safe(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return [json_safe(v) for v in tree]
    if isinstance(tree, float) and not np.isfinite(tree):
        return None
    return tree
