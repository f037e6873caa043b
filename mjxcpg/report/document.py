"""report.md: one report of a run directory, a section for every result the directory holds,
each beside the paper's figure and with the command that makes it alone.

The sections, in order: Table 1 with the controls and Fig 7's numbers (``table1.md``), the
learning curves (Fig 4) and policy maps (Fig 5) of the sweep, every evaluation of
``eval/evaluation.json`` (``mjxcpg.report.evaluation.SECTIONS``), the transfer to each hardware
robot (``ROBOT/eval/evaluation.json``) and online learning on one, beside its control with
learning off (``online/online.json``, ``online_control/online.json``).
Whatever a directory lacks is left out, so ``mjxcpg eval`` and ``mjxcpg reproduce`` write
the same report of what has been run.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from mjxcpg.physics import hardware
from mjxcpg.report import evaluation
from mjxcpg.training.files import write_text_atomic

PIPELINE_RECORD = "reproduce.json"  # the stages ``mjxcpg reproduce`` ran, and their commands
PAPER_ONLINE_TRIALS = 200           # the paper: the failing policies walk within 200 trials on QRIO


def _read_json(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def _link(target: Path, out_dir: Path) -> str:
    return os.path.relpath(target, out_dir)


def _command(text: str | None) -> list[str]:
    return [f"Alone: `{text}`", ""] if text else []


def learning_sections(run_dir: Path, out_dir: Path, commands: dict, table1_text: str | None) -> list[str]:
    """Table 1 with the controls beside the learners (and Fig 7's trend), Fig 4 and Fig 5."""
    lines = []
    table = run_dir / "table1.md"
    if table.is_file():
        lines += ["## Table 1: learning", "", table.read_text().strip(), ""]
    elif table1_text:
        lines += ["## Table 1: learning (from the checkpoint; the run has no table1.md yet)", "",
                  table1_text.strip(), ""]
    else:
        return lines
    lines += _command(commands.get("sweep"))
    if (run_dir / "controls").is_dir():
        lines += _command(commands.get("controls", f"mjxcpg controls --run {run_dir}"))
    curves = sorted(run_dir.glob("learning_curve_ks*.png"), key=lambda p: float(p.stem.removeprefix("learning_curve_ks")))
    if curves:
        lines += ["## Learning curves (Fig 4)", "",
                  "Accumulated reward per trial of every learner, one plot per k_s, with a 20-trial running "
                  "mean. The paper's Fig 4: a typical learning curve of the same accumulated reward; its "
                  "successful learners took 696 trials on average (Table 1).", ""]
        lines += [f"![{p.stem}]({_link(p, out_dir)})" for p in curves] + [""]
    summary = _read_json(run_dir / "summary.json")
    maps = {int(p.stem.removeprefix("policy_map_")): p for p in run_dir.glob("policy_map_*.png")}
    if summary and maps:
        first = {}
        for row in summary["learners"]:
            first.setdefault(row["k_s"], row["learner"])
        shown = [first[k] for k in sorted(first) if first[k] in maps]
        lines += ["## Policy maps (Fig 5)", "",
                  "The final policy's mean a_5 over the roll and pitch rates of the pelvis, the first learner "
                  "of each k_s; every learner's is `policy_map_NN.png` in the run directory. The paper's Fig 5: "
                  "the roll rate dominates the policy's output, the pitch rate has little influence.", ""]
        for k in shown:
            row = summary["learners"][k]
            gradient = row["policy_input_gradient"]
            lines.append(f"![learner {k}, k_s = {row['k_s']:g}]({_link(maps[k], out_dir)})")
            lines.append(f"Learner {k} (k_s = {row['k_s']:g}): mean |dmu/d roll rate| {gradient['roll_rate']:.2f}, "
                         f"|dmu/d pitch rate| {gradient['pitch_rate']:.2f}.")
            lines.append("")
    return lines


def evaluation_sections(eval_dir: Path, names: tuple[str, ...] | None = None) -> list[str]:
    """The sections of ``eval_dir/evaluation.json`` (only ``names``, if given), their plots redrawn there."""
    saved = _read_json(eval_dir / "evaluation.json")
    if saved is None:
        return []
    summary = saved.pop("summary")
    command = saved.get("command")
    if names is not None:
        saved = {k: v for k, v in saved.items() if k not in evaluation.SECTIONS or k in names}
        saved["learners"] = [{k: v for k, v in row.items() if k not in evaluation.SECTIONS or k in names}
                             for row in saved["learners"]]
    return evaluation.render_sections(saved, summary, eval_dir) + _command(command)


def exploration_words(exploration: str | float) -> str:
    """How online learning's sigma starts (``online.parse_exploration``'s values), in words."""
    if exploration == "initial":
        return "sigma restarted at its initial value"
    return "sigma as learned" if exploration == "learned" else f"sigma restarted at {exploration:g}"


def _exploration_words(online_record: dict | None) -> str:
    """How the online learners' sigma started, as ``online.json`` records it."""
    if online_record is None:
        return ""
    return f" ({exploration_words(online_record.get('exploration', 'learned'))})"


def online_section(run_dir: Path, commands: dict, robot: str = "harsh") -> list[str]:
    """Online additional learning on a hardware robot of the learners that failed there,
    beside the same trials with learning off."""
    learned, control = (_read_json(run_dir / name / "online.json") for name in ("online", "online_control"))
    if learned is None and "online" not in commands:
        return []
    robot = (learned or {}).get("robot", robot)
    lines = [f"## Online learning on the `{robot}` hardware robot", "",
             f"Each policy that did not walk in every try on the `{robot}` robot learns on there from its final "
             f"weights{_exploration_words(learned)}, with a reward from the robot's sensors alone "
             "(`docs/hardware.md`), until 20 successive "
             "trials without a fall; the control runs the same trials with learning off. The paper: the "
             f"failing policies walked within {PAPER_ONLINE_TRIALS} trials on QRIO.", ""]
    if learned is None:
        return lines + [f"Every policy walked in every try on the `{robot}` robot: none to learn on.", ""]
    others = {r["learner"]: r for r in (control or {"learners": []})["learners"]}
    lines += [f"Met the criterion within {learned['trials']} trials: **{learned['succeeded']} of "
              f"{len(learned['learners'])}** learning, "
              + (f"{control['succeeded']} of {len(control['learners'])} with learning off." if control else
                 "the control with learning off not run."), "",
              "| learner | k_s | trials to success | falls in its first 20 trials | final policy walks 20 s | "
              "its velocity (m/s) | learning off: trials to success |", "|---|---|---|---|---|---|---|"]

    def done(r: dict) -> str:
        return str(r["trials_to_success"]) if r["succeeded"] else f"not in {r['trials']}"

    for r in learned["learners"]:
        off = others.get(r["learner"])
        velocity = "-" if r["final_policy_mean_vx"] is None else f"{r['final_policy_mean_vx']:.3f}"
        lines.append(f"| {r['learner']} | {r['k_s']:g} | {done(r)} | {r['falls_in_first_20']} | "
                     f"{'yes' if r['final_policy_walks_20s'] else 'no'} | {velocity} | "
                     f"{done(off) if off else '-'} |")
    return lines + [""] + _command(commands.get("online")) + _command(commands.get("online_control"))


def write_report(out_dir: Path, run_dir: Path, table1_text: str | None = None) -> Path:
    """``out_dir/report.md`` of the run in ``run_dir``: every section its results allow.

    ``out_dir`` is where the evaluation went (``eval/``): the run directory itself, its
    ``hardware/`` subdirectory or a directory of the user's.  The run directory's own report
    also has the hardware transfer and online learning.  ``table1_text``: Table 1 made from
    the checkpoint, for a run without table1.md yet."""
    record = _read_json(run_dir / PIPELINE_RECORD) or {}
    commands = record.get("commands", {})
    title = (f"# `{run_dir}`: the paper's figures, reproduced" if record else f"# Evaluation of `{run_dir}`")
    lines = [title, ""]
    if record:
        lines += [f"Made by `{record['command']}` (config `{record['config']}`): {record['note']}", ""]
    lines += learning_sections(run_dir, out_dir, commands, table1_text)
    evaluated = evaluation_sections(out_dir / "eval")
    if evaluated:
        lines += ["# The final policies, evaluated", ""] + evaluated
    if out_dir.resolve() == run_dir.resolve():
        for robot in hardware.MISMATCHES:
            transfer = run_dir / robot / "eval"
            if transfer.is_dir():
                lines += [f"# On the `{robot}` hardware robot", ""] + evaluation_sections(transfer, names=("transfer",))
        lines += online_section(run_dir, commands, record.get("budget", {}).get("online_robot", "harsh"))
    path = out_dir / "report.md"
    write_text_atomic(path, "\n".join(lines))
    return path
