"""Walking where it is told: learn with a commanded heading, then measure the heading walked.

For each command c (degrees, positive to the left) it learns the `heading` config with
``controller.heading_command`` = c (the heading reflex steers toward c; the reward's k_S
term reads the velocity along c) in OUT/heading_<c>, a run directory like any sweep's (an
existing one is resumed, a finished one reused), then walks every final policy (its mean,
no noise) for ``--seconds`` twice: started as its trials started (the hand-designed
feedback for the middle of the hand-over range) and from standing.  Per walk, after the
first ``--after`` seconds: whether it fell, its mean heading and its largest distance from
the command (degrees), and its speed along the command (m/s, the displacement over the
time).  The 0 degree policies are also walked with the heading reflex off (h_heading = 0),
and any ``--reference`` run's policies as they were learned: how much each drifts.

    .venv/bin/python bench/heading_study.py --out runs/heading
    .venv/bin/python bench/heading_study.py --out runs/heading --reference runs/paper \
        --reference-learners 22 23 24 25 26

Writes OUT/heading_study.json and OUT/heading_study.md (also printed; ``--report`` names
them).  ``--hand-seconds S ...`` walks each policy after each of those hand-designed starts
instead, e.g. ``--commands 30 -30 --hand-seconds 0.5 1 1.5 2 3 --report hand_over``.
"""

import argparse
import dataclasses
import json
import math
from pathlib import Path

import jax
import numpy as np

import mjxcpg
from mjxcpg.control import walk
from mjxcpg.jaxutil import xla
from mjxcpg.learning.learner import actor_feedback
from mjxcpg.training import runs, stats

WITHIN_DEG = 5.0  # the mean heading's allowed distance from the command


def yaw_degrees(qpos: np.ndarray) -> np.ndarray:
    """The pelvis' yaw (degrees, unwrapped) from the free joint's quaternion, per period."""
    w, x, y, z = (qpos[..., 3 + k].astype(np.float64) for k in range(4))
    return np.degrees(np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))))


def heading_walk(trace: walk.Trace, k: int, dt: float, command_deg: float, after_s: float) -> dict:
    """One robot's walk after ``after_s``: fell, mean heading, largest |heading - command|,
    speed along the command."""
    fallen = np.asarray(trace.fallen[k])
    if fallen.any():
        return {"fell": True, "fell_at_s": float(np.argmax(fallen) * dt)}
    qpos = np.asarray(trace.qpos[k], np.float64)
    start = round(after_s / dt)
    yaw = yaw_degrees(qpos)[start:]
    c = math.radians(command_deg)
    shift = qpos[-1, :2] - qpos[start, :2]
    return {"fell": False, "mean_heading_deg": float(np.mean(yaw)),
            "largest_error_deg": float(np.max(np.abs(yaw - command_deg))),
            "speed_along_command": float((shift[0] * math.cos(c) + shift[1] * math.sin(c)) / ((len(yaw) - 1) * dt))}


def walk_run(run_dir: Path, learners, seconds: float, after_s: float, command_deg: float,
             controller_changes: dict | None = None, hand_seconds: list[float] | None = None) -> dict:
    """Every chosen policy of ``run_dir`` walked twice (as its trials started, from standing),
    or once after each of ``hand_seconds`` of the hand-designed feedback."""
    spec, sim, task, state = runs.load_run(run_dir)
    if controller_changes:
        sim = sim.rebuild(params=dataclasses.replace(sim.params, **controller_changes))
    chosen = runs.check_learners(spec, learners)
    weights = jax.tree.map(lambda w: w[np.asarray(chosen)], state.learners.weights)
    starts = ([("as_trials", spec.trial.walk_hand_seconds), ("standing", 0.0)] if hand_seconds is None
              else [(f"hand_{s:g}_s", s) for s in hand_seconds])
    out = {}
    for start, hand in starts:
        trace = jax.device_get(walk.walk_from_standing(sim, actor_feedback(task), weights, seconds,
                                                       record_qpos=True, hand_seconds=hand))
        out[start] = [{"learner": k, **heading_walk(trace, j, sim.control_dt, command_deg, after_s)}
                      for j, k in enumerate(chosen)]
    return out


def cell(rows: list[dict], command_deg: float) -> dict:
    """Counts and the mean heading's 95% interval over the walks without a fall."""
    walked = [r for r in rows if not r["fell"]]
    within = [r for r in walked if abs(r["mean_heading_deg"] - command_deg) <= WITHIN_DEG]
    summary = {"walks": len(rows), "no_fall": len(walked), "within": len(within)}
    if walked:
        summary["mean_heading"] = stats.mean_interval([r["mean_heading_deg"] for r in walked]).as_dict()
        summary["largest_error_deg"] = max(r["largest_error_deg"] for r in walked)
        summary["speed"] = stats.mean_interval([r["speed_along_command"] for r in walked]).as_dict()
    return summary


def table(results: dict) -> list[str]:
    lines = [f"| policies | command (deg) | succeeded | start | no fall | mean heading within {WITHIN_DEG:g} deg | "
             "mean heading (deg) | largest \\|heading - command\\| (deg) | speed along the command (m/s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        for start, c in r["cells"].items():
            heading = stats.Estimate(**c["mean_heading"]).format("+.1f") if "mean_heading" in c else "-"
            speed = stats.Estimate(**c["speed"]).format(".4f") if "speed" in c else "-"
            largest = f"{c['largest_error_deg']:.1f}" if "largest_error_deg" in c else "-"
            lines.append(f"| {name} | {r['command_deg']:+g} | {r['succeeded']} | {start.replace('_', ' ')} | "
                         f"{c['no_fall']}/{c['walks']} | {c['within']}/{c['walks']} | {heading} | {largest} | "
                         f"{speed} |")
    return lines


def measured(run_dir: Path, learners, command_deg: float, args, controller_changes: dict | None = None) -> dict:
    """The chosen learners of ``run_dir`` (all when None): how many met the success criterion
    (summary.json), their walks (``walk_run``) and each start's ``cell``."""
    summary = json.loads((run_dir / "summary.json").read_text())["learners"]
    walks = walk_run(run_dir, learners, args.seconds, args.after, command_deg, controller_changes, args.hand_seconds)
    chosen = [w["learner"] for w in next(iter(walks.values()))]
    return {"run": str(run_dir), "command_deg": command_deg, "learners": chosen,
            "succeeded": f"{sum(summary[k]['succeeded'] for k in chosen)}/{len(chosen)}", "walks": walks,
            "cells": {start: cell(rows, command_deg) for start, rows in walks.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--config", default="heading")
    parser.add_argument("--commands", type=float, nargs="+", default=[0.0, 15.0, -15.0, 30.0, -30.0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--after", type=float, default=5.0, help="seconds left out of each walk's start")
    parser.add_argument("--reference", type=Path, nargs="*", default=[],
                        help="runs whose policies are walked as learned")
    parser.add_argument("--reference-learners", type=int, nargs="+", default=None)
    parser.add_argument("--hand-seconds", type=float, nargs="+", default=None,
                        help="walk after each of these hand-designed starts instead (default: as the "
                             "trials started, and from standing)")
    parser.add_argument("--report", default="heading_study", help="OUT/REPORT.json and .md")
    args = parser.parse_args()
    xla.one_cpu_thread()
    base = mjxcpg.load_spec(args.config)
    results = {}
    for command in args.commands:
        run_dir = args.out / f"heading_{command:+g}"
        spec = dataclasses.replace(base, controller=dataclasses.replace(
            base.controller, heading_command=math.radians(command)))
        if not (run_dir / "summary.json").is_file():
            mjxcpg.sweep(spec, out=run_dir, resume=(run_dir / "config.json").is_file())
        variants = {f"learned at {command:+g}": None}
        if command == 0:
            variants["the same, heading reflex off"] = {"h_heading": 0.0}
        for name, changes in variants.items():
            results[name] = measured(run_dir, None, command, args, changes)
    for reference in args.reference:
        entry = measured(reference, args.reference_learners, 0.0, args)
        results[f"{reference}, learners {entry['learners'][0]}-{entry['learners'][-1]}"] = entry
    lines = [f"Walks of {args.seconds:g} s, measured after the first {args.after:g} s "
             f"(`bench/heading_study.py --out {args.out} ...`):", ""] + table(results)
    print("\n".join(lines))
    (args.out / f"{args.report}.json").write_text(json.dumps(results, indent=1))
    (args.out / f"{args.report}.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    try:
        main()
    except (runs.RunError, ValueError) as error:
        raise SystemExit(f"heading_study: {error}") from None
