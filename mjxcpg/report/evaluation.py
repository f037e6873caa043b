"""The evaluations' part of a report: each evaluation's summary figures (``summarise_*``) and
its section of report.md with its plots (``*_section``), every figure beside the paper's, all
registered in ``SECTIONS`` under the evaluation's name (``mjxcpg.evaluation.registry`` pairs
each with what it runs); ``write_evaluation`` writes eval/evaluation.json."""

from __future__ import annotations

import dataclasses
import json
from collections import defaultdict
from pathlib import Path
from typing import Callable

import numpy as np

from mjxcpg.report import plots
from mjxcpg.report.learning import json_safe
from mjxcpg.training import stats

PAPER_EIGENVALUE = -0.0101          # Fig 8, 50 perturbed steps
PAPER_SLOPES_DEG = (3.0, -4.0)      # steady walking from +3 to -4 degrees
PAPER_VELOCITY = 0.077              # Fig 6 gait, m/s
PAPER_HARDWARE = (14, 20)           # learned policies that walked on the real QRIO


def _finite(value: float | None) -> bool:
    return value is not None and bool(np.isfinite(value))


def _fmt(value: float | None, spec: str = ".3f", scale: float = 1.0) -> str:
    return format(value * scale, spec) if _finite(value) else "-"


def _succeeded(result: dict) -> list[dict]:
    return [r for r in result["learners"] if r["succeeded"]]


def base_summary(result: dict) -> dict:
    """The summary's figures that every evaluation has: learners and how many learned."""
    rows = result["learners"]
    return {"learners": len(rows), "succeeded": sum(r["succeeded"] for r in rows)}


def evaluation_header(result: dict, summary: dict) -> list[str]:
    """What was evaluated and how: the lines that open a report's evaluations."""
    return [f"Engine `{result['engine']}`, robot `{result['robot']}`, {len(result['learners'])} learner(s), "
             f"{summary['succeeded']} of which succeeded in learning. Every policy is the final "
             "policy's mean (no exploration noise), walking from the standing pose"
             + (f" after {result['params']['hand_seconds']:g} s of the hand-designed feedback"
                if result['params'].get('hand_seconds') else "")
             + "; all learners in one batch; deterministic by `--seed` "
             f"({result['params']['seed']}). Protocol and choices: `docs/evaluation.md`.", ""]


# ---------------------------------------------------------------- velocity and return map

LASTING_SPEED_FRACTION = 0.8        # a lasting walk keeps this much of its trial walk's speed


def walk_lasts(row: dict) -> bool | None:
    """Whether a learner's walk lasts: no fall over the unperturbed cycles, and their second
    half at least ``LASTING_SPEED_FRACTION`` of the speed of the run's own 20 s walk (None
    without that walk's speed, from a run with no summary)."""
    rm, reference = row["return_map"], row.get("trial_walk_vx")
    if reference is None:
        return None
    return bool(rm.get("walked_unperturbed_cycles")) and _finite(rm.get("mean_vx_last_half")) \
        and rm["mean_vx_last_half"] >= LASTING_SPEED_FRACTION * reference


def summarise_return_map(result: dict) -> dict:
    good = _succeeded(result)
    fitted = [r for r in good if r["return_map"]["eigenvalue"] is not None]
    stable = [r for r in fitted if r["return_map"]["stable"] and not r["return_map"]["fell"]]
    eig = [r["return_map"]["eigenvalue"] for r in fitted]
    by_ks: dict = defaultdict(list)
    cot_by_ks: dict = defaultdict(list)
    for r in good:
        rm = r["return_map"]
        if rm["fell"]:
            continue
        if _finite(rm["mean_vx"]):
            by_ks[r["k_s"]].append(rm["mean_vx"])
        if _finite(rm.get("cost_of_transport")):
            cot_by_ks[r["k_s"]].append(rm["cost_of_transport"])
    propelled = [r for r in good if r["k_s"] >= 1]
    lasting = [r for r in propelled if walk_lasts(r)]
    energy = {"energy_cells": energy_cells(result)} if any("k_e" in r for r in result["learners"]) else {}
    return energy | dict(
        lasting_propelled=f"{len(lasting)}/{len(propelled)}",
        velocity_by_ks={f"{k:g}": float(np.mean(v)) for k, v in sorted(by_ks.items())},
        cost_of_transport_by_ks={f"{k:g}": float(np.mean(v)) for k, v in sorted(cot_by_ks.items())},
        eigenvalue_median=float(np.median(eig)) if eig else None,
        eigenvalue_range=[float(min(eig)), float(max(eig))] if eig else None,
        stable_successful=f"{len(stable)}/{len(good)}", paper_eigenvalue=PAPER_EIGENVALUE)


def energy_cells(result: dict) -> list[dict]:
    """Per (k_s, k_E) of a run with energy gains: learners, successes, and over the successful
    ones that walk the unperturbed cycles, the mean speed and cost of transport with their 95%
    intervals, and both as a fraction of the same k_s's k_E = 0 mean; and the mean positive
    power over the robot's weight, P / (m g) = CoT x speed (m/s), the energy term's own unit."""
    cells = []
    rows = result["learners"]
    for k_s, k_e in sorted({(r["k_s"], r["k_e"]) for r in rows}):
        rs = [r for r in rows if (r["k_s"], r["k_e"]) == (k_s, k_e)]
        walking = [r["return_map"] for r in rs if r["succeeded"] and not r["return_map"]["fell"]]
        costed = [w for w in walking if _finite(w.get("cost_of_transport"))]
        cells.append({"k_s": k_s, "k_e": k_e, "learners": len(rs), "succeeded": sum(r["succeeded"] for r in rs),
                      "walking": len(walking),
                      "mean_vx": stats.mean_interval([w["mean_vx"] for w in walking]).as_dict(),
                      "cost_of_transport": stats.mean_interval([w["cost_of_transport"] for w in costed]).as_dict(),
                      # work / (m g distance) x distance / time, both over the same cycles
                      "power_over_weight": stats.mean_interval(
                          [w["cost_of_transport"] * w["mean_vx"] for w in costed]).as_dict()})
    for cell in cells:
        base = next((c for c in cells if c["k_s"] == cell["k_s"] and c["k_e"] == 0), None)
        for key in ("mean_vx", "cost_of_transport"):
            ratio = cell[key]["value"] / base[key]["value"] if base and _finite(base[key]["value"]) else None
            cell[f"{key}_of_k_e_0"] = ratio if _finite(ratio) else None
    return cells


def energy_lines(summary: dict) -> list[str]:
    """The cost of transport against k_E, beside the same seeds at k_E = 0."""
    lines = ["## Energy: the cost of transport against k_E", "",
             "Per k_s and energy gain k_E (reward r - k_E P / (m g)), the successful policies that walk the "
             "unperturbed cycles: mean speed and cost of transport with 95% bootstrap intervals over learners, "
             "each as a fraction of the same k_s and seeds at k_E = 0, and the mean positive power over "
             "the robot's weight, P / (m g) = CoT x speed.", "",
             "| k_s | k_E | successes | walking | speed (m/s) | of k_E = 0 | cost of transport | of k_E = 0 | "
             "P / (m g) (m/s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in summary["energy_cells"]:
        speed, cot = stats.Estimate(**c["mean_vx"]), stats.Estimate(**c["cost_of_transport"])
        # an evaluation saved before the power was summarised has none
        power = stats.Estimate(**c["power_over_weight"]) if "power_over_weight" in c else None
        lines.append(f"| {c['k_s']:g} | {c['k_e']:g} | {c['succeeded']}/{c['learners']} | {c['walking']} | "
                     f"{speed.format('.3f')} | {_fmt(c['mean_vx_of_k_e_0'], '.2f')} | {cot.format('.2f')} | "
                     f"{_fmt(c['cost_of_transport_of_k_e_0'], '.2f')} | "
                     f"{power.format('.4f') if power is not None else '-'} |")
    return lines + [""]


def return_map_section(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """Fig 7 and Fig 8: velocity against k_s, the return maps and their eigenvalues."""
    rows = result["learners"]
    plots.velocity_vs_ks(rows, eval_dir / "velocity_vs_ks.png", reference=PAPER_VELOCITY)
    plots.eigenvalues(rows, eval_dir / "eigenvalues.png", reference=PAPER_EIGENVALUE)
    lines = ["## Velocity against k_s (Fig 7)", "",
             f"Mean forward speed over {result['params']['fixed_point_steps']} unperturbed gait cycles "
             f"after {result['params']['settle_seconds']:g} s. The paper: velocity rises with k_s "
             f"(Fig 7); its Fig 6 gait walks at {PAPER_VELOCITY} m/s. Cost of transport over the same "
             "cycles: the actuators' positive mechanical work over m g times the distance along +x "
             "(Collins et al., Science 2005: human walking about 0.2, ASIMO about 3.2).", "",
             "| k_s | policies walking (successful) | mean velocity (m/s) | mean cost of transport | "
             "per policy (m/s) |", "|---|---|---|---|---|"]
    by_ks: dict = defaultdict(list)
    for r in rows:
        by_ks[r["k_s"]].append(r)
    for k_s in sorted(by_ks):
        ok = [r for r in by_ks[k_s] if r["succeeded"] and not r["return_map"]["fell"]]
        mean = summary["velocity_by_ks"].get(f"{k_s:g}")
        each = ", ".join(_fmt(r["return_map"]["mean_vx"]) + ("" if r["succeeded"] else " (not learned)")
                         for r in by_ks[k_s])
        cost = summary.get("cost_of_transport_by_ks", {}).get(f"{k_s:g}")
        lines.append(f"| {k_s:g} | {len(ok)}/{sum(r['succeeded'] for r in by_ks[k_s])} | {_fmt(mean)} | "
                     f"{_fmt(cost, '.2f')} | {each} |")
    lines += ["", "![velocity vs k_s](eval/velocity_vs_ks.png)", ""]
    if "energy_cells" in summary:
        lines += energy_lines(summary)
    lines += ["## Does the walk last?", "",
              f"Each policy's speed over the first and the second half of the same "
              f"{result['params']['fixed_point_steps']} unperturbed cycles, beside its speed in the run's "
              "own 20 s walk (summary.json, started as its trials were), and its heading's drift over "
              f"them. A walk lasts when it does not fall in them and keeps at least "
              f"{LASTING_SPEED_FRACTION:.0%} of its 20 s speed in their second half. "
              f"Successful k_s >= 1 policies whose walk lasts: **{summary['lasting_propelled']}**.", "",
              "| learner | k_s | 20 s walk (m/s) | first half | second half | heading drift (deg) | "
              "largest heading (deg) | lasts |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rm, lasts = r["return_map"], walk_lasts(r)
        lines.append(f"| {r['learner']} | {r['k_s']:g} | {_fmt(r.get('trial_walk_vx'))} | "
                     f"{_fmt(rm.get('mean_vx_first_half'))} | {_fmt(rm.get('mean_vx_last_half'))} | "
                     f"{_fmt(rm.get('heading_drift_deg'), '+.1f')} | {_fmt(rm.get('heading_largest_deg'), '+.1f')} | "
                     f"{'-' if lasts is None else 'yes' if lasts else 'no'} |")
    lines += ["",
              "## Return-map stability (Fig 8)", "",
              "State: the step length (fore-aft distance from the right ankle to the left) at each "
              "left touchdown. Perturbation: the target of (q5 - q6) offset by a uniform "
              f"+/-{result['params']['perturbation_amplitude']:g} from a random moment to the next left "
              "touchdown (x_n); x_{n+1} is the touchdown after it. Eigenvalue: least-squares slope "
              f"of x_(n+1) on x_n. The paper: {PAPER_EIGENVALUE} from 50 perturbations.", "",
              f"Successful policies with |eigenvalue| < 1 (and no fall): **{summary['stable_successful']}**; "
              f"median eigenvalue {_fmt(summary['eigenvalue_median'])}"
              + (f", range {summary['eigenvalue_range'][0]:.3f} to {summary['eigenvalue_range'][1]:.3f}"
                 if summary["eigenvalue_range"] else "") + " (successful policies).", "",
              "| learner | k_s | learned | fell | fixed point (mm) | gait cycle (s) | pairs | eigenvalue +/- s.e. | paper |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rm = r["return_map"]
        fell = f"at {rm['fall_seconds']:.1f} s" if rm["fell"] else "no"
        lines.append(
            f"| {r['learner']} | {r['k_s']:g} | {'yes' if r['succeeded'] else 'no'} | "
            f"{fell} | {_fmt(rm['fixed_point'], '.1f', 1000)} | "
            f"{_fmt(rm['gait_cycle_s'], '.2f')} | {rm['perturbations']} | "
            f"{_fmt(rm['eigenvalue'])} +/- {_fmt(rm['eigenvalue_stderr'])} | {PAPER_EIGENVALUE} |")
    lines += ["", "![eigenvalues](eval/eigenvalues.png)", ""]
    for r in rows:
        if r["return_map"]["perturbations"]:
            name = f"return_map_{r['learner']:02d}.png"
            plots.return_map(r["return_map"], eval_dir / name,
                             title=f"learner {r['learner']}, k_s={r['k_s']:g} (cf. Fig 8)")
            lines.append(f"![return map, learner {r['learner']}](eval/{name})")
    lines.append("")
    return lines


# ---------------------------------------------------------------- slopes

def summarise_slopes(result: dict) -> dict:
    walking = [r for r in _succeeded(result) if r["slopes"]["uphill_deg"] is not None]
    walked = [r["slopes"] for r in walking]
    propelled = [r["slopes"] for r in walking if r["k_s"] >= 1]
    return dict(
        slope_uphill_median=float(np.median([s["uphill_deg"] for s in walked])) if walked else None,
        slope_downhill_median=float(np.median([s["downhill_deg"] for s in walked])) if walked else None,
        # k_s >= 1: the policies that learned a propulsive feedback, as Fig 8 is judged
        propelled_slopes_median=[float(np.median([s["uphill_deg"] for s in propelled])),
                                 float(np.median([s["downhill_deg"] for s in propelled]))] if propelled else None,
        propelled_slopes_widest=[float(max(s["uphill_deg"] for s in propelled)),
                                 float(min(s["downhill_deg"] for s in propelled))] if propelled else None,
        paper_slopes_deg=list(PAPER_SLOPES_DEG))


def slopes_section(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """The range of floor inclinations each policy walks, beside the paper's."""
    rows = result["learners"]
    plots.slope_ranges(rows, eval_dir / "slopes.png", reference=PAPER_SLOPES_DEG)
    up, down = summary["slope_uphill_median"], summary["slope_downhill_median"]
    lines = ["## Slopes", "",
             f"Floor inclinations in 1-degree steps, {result['params']['slope_seconds']:g} s from standing "
             "without a fall; the range is contiguous from 0. The paper: "
             f"{PAPER_SLOPES_DEG[0]:+g} to {PAPER_SLOPES_DEG[1]:+g} degrees.", "",
             f"Median over the successful policies that walk on level ground: "
             f"{_fmt(up, '+.0f')} to {_fmt(down, '+.0f')} degrees."
             + (" Over the k_s >= 1 ones: median {:+g} to {:+g}, steepest {:+g} and {:+g}.".format(
                 *summary["propelled_slopes_median"], *summary["propelled_slopes_widest"])
                if summary.get("propelled_slopes_median") else ""), "",
             "| learner | k_s | learned | uphill (deg) | downhill (deg) | paper |", "|---|---|---|---|---|---|"]
    for r in rows:
        s = r["slopes"]
        lines.append(f"| {r['learner']} | {r['k_s']:g} | {'yes' if r['succeeded'] else 'no'} | "
                     f"{_fmt(s['uphill_deg'], '+.0f')} | {_fmt(s['downhill_deg'], '+.0f')} | "
                     f"{PAPER_SLOPES_DEG[0]:+g} / {PAPER_SLOPES_DEG[1]:+g} |")
    lines += ["", "![slopes](eval/slopes.png)", ""]
    return lines


# ---------------------------------------------------------------- pushes

def summarise_pushes(result: dict) -> dict:
    rows, good = result["learners"], _succeeded(result)
    out = {}
    for name in rows[0]["pushes"]:
        values = [r["pushes"][name]["impulse"] for r in good]
        out[f"push_{name}_median_Ns"] = float(np.median(values)) if values else None
    return out


def pushes_section(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """The largest pelvis impulse each policy survives, per direction."""
    rows = result["learners"]
    plots.push_impulses(rows, eval_dir / "pushes.png")
    names = list(rows[0]["pushes"])
    p = result["params"]
    lines = ["## Pushes", "",
             f"A force on the pelvis for {p['push_seconds']:g} s from the first left touchdown after "
             f"{p['push_after_seconds']:g} s; survived = no fall in the next {p['push_observe_seconds']:g} s. "
             f"Largest survived impulse by bisection over [0, {p['max_impulse']:g}] N s "
             f"({p['push_rounds']} rounds; `>=` when every impulse tried was survived). "
             "The paper reports no push figures.", "",
             "| learner | k_s | learned | " + " | ".join(f"{n} (N s)" for n in names) + " |",
             "|---|---|---|" + "---|" * len(names)]
    for r in rows:
        cells = [(">=" if r["pushes"][n]["capped"] else "") + f"{r['pushes'][n]['impulse']:.2f}" for n in names]
        lines.append(f"| {r['learner']} | {r['k_s']:g} | {'yes' if r['succeeded'] else 'no'} | "
                     + " | ".join(cells) + " |")
    medians = ", ".join(f"{n} {_fmt(summary[f'push_{n}_median_Ns'], '.2f')}" for n in names)
    lines += ["", f"Medians over the successful policies (N s): {medians}.", "",
              "![pushes](eval/pushes.png)", ""]
    return lines


# ---------------------------------------------------------------- the references

def summarise_references(result: dict) -> dict:
    out = {}
    for actor, ref in result["references"].items():
        rm, slopes = ref["return_map"], ref["slopes"]
        out[f"{actor}_slopes_deg"] = [slopes["uphill_deg"], slopes["downhill_deg"]]
        out[f"{actor}_mean_vx"] = rm["mean_vx"]
        out[f"{actor}_cost_of_transport"] = rm.get("cost_of_transport")
        out[f"{actor}_pushes_Ns"] = {name: p["impulse"] for name, p in ref["pushes"].items()}
    return out


def references_section(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """The hand-designed feedback and a_5 = 0 in the protocols the policies walked."""
    refs = result["references"]
    names = list(next(iter(refs.values()))["pushes"])
    lines = ["## The hand-designed feedback and a_5 = 0, in the same protocols", "",
             "What the policies' figures above compare with: the feedback that starts every learning "
             "trial (a_5 = K d theta_roll/dt) and no propulsive feedback at all, each walked as the "
             "policies were (same start, same protocols).", "",
             "| feedback | mean velocity (m/s) | cost of transport | first / second half | heading drift (deg) | "
             "fell | eigenvalue | uphill (deg) | downhill (deg) | " + " | ".join(f"push {n} (N s)" for n in names) + " |",
             "|---|---|---|---|---|---|---|---|---|" + "---|" * len(names)]
    for ref in refs.values():
        rm, slopes = ref["return_map"], ref["slopes"]
        fell = f"at {rm['fall_seconds']:.1f} s" if rm["fell"] else "no"
        pushes = [(">=" if ref["pushes"][n]["capped"] else "") + f"{ref['pushes'][n]['impulse']:.2f}" for n in names]
        lines.append(f"| {ref['label']} | {_fmt(rm['mean_vx'])} | {_fmt(rm.get('cost_of_transport'), '.2f')} | "
                     f"{_fmt(rm.get('mean_vx_first_half'))} / "
                     f"{_fmt(rm.get('mean_vx_last_half'))} | {_fmt(rm.get('heading_drift_deg'), '+.1f')} | {fell} | "
                     f"{_fmt(rm['eigenvalue'])} | {_fmt(slopes['uphill_deg'], '+.0f')} | "
                     f"{_fmt(slopes['downhill_deg'], '+.0f')} | " + " | ".join(pushes) + " |")
    lines.append("")
    return lines


# ---------------------------------------------------------------- transfer to the hardware robot

def summarise_transfer(result: dict) -> dict:
    t = result["transfer"]
    return {"walk_hardware": f"{t['walk_hardware']}/{t['succeeded_in_simulation']}"}


def transfer_section(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """How many successful policies walk on the hardware robot, beside the paper's 14 of 20."""
    t = result["transfer"]
    robot = "hardware robot" if t.get("robot", "hardware") == "hardware" else f"`{t['robot']}` hardware robot"
    start = (f"its first {t['hand_seconds']:g} s with the hand-designed feedback, as its trials started"
             if t.get("hand_seconds") else "from standing")
    lines = [f"## Transfer to the {robot}", "",
             f"Each successful policy walks {t['seconds']:g} s on the {robot} "
             f"(`docs/hardware.md`), {start}, {t['repeats']} times, each with other sensor noise.", "",
             f"Walked in every try: **{t['walk_hardware']} of {t['succeeded_in_simulation']}**; "
             f"in at least one: {t['walk_hardware_any']}; on the nominal robot: {t['walk_nominal']}. "
             f"The paper: {PAPER_HARDWARE[0]} of {PAPER_HARDWARE[1]} on the real QRIO.", "",
             "| learner | k_s | learned | walks (of tries) | mean vx hardware / nominal (m/s) |",
             "|---|---|---|---|---|"]
    for r in t["learners"]:
        lines.append(f"| {r['learner']} | {r['k_s']:g} | {'yes' if r['succeeded'] else 'no'} | "
                     f"{r['walks_hardware']}/{t['repeats']} | {_fmt(r['mean_vx_hardware'])} / "
                     f"{_fmt(r['mean_vx_nominal'])} |")
    lines.append("")
    return lines


@dataclasses.dataclass(frozen=True)
class Section:
    """An evaluation's part of the report: its summary figures, from the whole result, and its
    report.md lines (given the result, the summary and the directory its plots go to)."""

    summarise: Callable[[dict], dict]
    render: Callable[[dict, dict, Path], list[str]]
    per_learner: bool = True    # its result is one per learner, kept in each learner's row

    def holds(self, name: str, result: dict) -> bool:
        """Whether ``result`` has the results of evaluation ``name``."""
        if self.per_learner:
            return bool(result["learners"]) and name in result["learners"][0]
        return name in result


# In report order, which is the order the evaluations run in.
SECTIONS: dict[str, Section] = {
    "return_map": Section(summarise_return_map, return_map_section),
    "slopes": Section(summarise_slopes, slopes_section),
    "pushes": Section(summarise_pushes, pushes_section),
    "references": Section(summarise_references, references_section, per_learner=False),
    "transfer": Section(summarise_transfer, transfer_section, per_learner=False),
}


def summarise(result: dict) -> dict:
    """The headline figures of every evaluation ``result`` holds."""
    summary = base_summary(result)
    for name, section in SECTIONS.items():
        if section.holds(name, result):
            summary.update(section.summarise(result))
    return summary


def write_evaluation(out_dir: Path, result: dict) -> dict:
    """``out_dir/eval/evaluation.json``: the result with its summary.  Returns the summary."""
    eval_dir = out_dir / "eval"
    eval_dir.mkdir(parents=True, exist_ok=True)
    summary = summarise(result)
    (eval_dir / "evaluation.json").write_text(json.dumps(json_safe({**result, "summary": summary}), indent=1))
    return summary


def render_sections(result: dict, summary: dict, eval_dir: Path) -> list[str]:
    """Every section ``result`` holds, in report order, its plots drawn into ``eval_dir``."""
    lines = evaluation_header(result, summary)
    for name, section in SECTIONS.items():
        if section.holds(name, result):
            lines += section.render(result, summary, eval_dir)
    return lines
