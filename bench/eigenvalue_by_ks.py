"""Fig 8's return map per k_s, read from one or more ``mjxcpg eval`` outputs: per k_s the
policies that fell over the protocol; over those with an eigenvalue (one that falls before
its pairs has none), the smallest, median and largest eigenvalue and the range of the fixed
point (the step length the gait returns to); within each k_s with five such policies or
more, Spearman's rho between eigenvalue and fixed point.

    NPROC=1 .venv/bin/python bench/eigenvalue_by_ks.py runs/stats_eval_hand [runs/ctrl_zero_eval ...]
"""

import json
import sys
from pathlib import Path

import numpy as np

from mjxcpg.training.stats import spearman


def by_ks(eval_dir: Path) -> list[dict]:
    learners = json.loads((eval_dir / "eval" / "evaluation.json").read_text())["learners"]
    rows = []
    for k_s in sorted({learner["k_s"] for learner in learners}):
        maps = [learner["return_map"] for learner in learners if learner["k_s"] == k_s]
        fitted = [m for m in maps if m["eigenvalue"] is not None]  # a policy that fell early has none
        eigen = np.array([m["eigenvalue"] for m in fitted], float)
        fixed = np.array([m["fixed_point"] for m in fitted], float)
        row = {"k_s": k_s, "policies": len(maps), "fell": sum(m["fell"] for m in maps), "fitted": len(fitted)}
        if fitted:
            row |= {"eigen_min": float(np.min(eigen)), "eigen_median": float(np.median(eigen)),
                    "eigen_max": float(np.max(eigen)), "fixed_mm": (1e3 * fixed.min(), 1e3 * fixed.max()),
                    "rho": spearman(eigen, fixed) if len(fitted) >= 5 else None}
        rows.append(row)
    return rows


if __name__ == "__main__":
    for run in sys.argv[1:]:
        print(f"{run}\n| k_s | policies | fell | eigenvalue: smallest | median | largest | fixed point (mm) "
              "| rho(eigenvalue, fixed point) |\n|---|---|---|---|---|---|---|---|")
        for r in by_ks(Path(run)):
            if not r["fitted"]:
                print(f"| {r['k_s']:g} | {r['policies']} | {r['fell']} | - | - | - | - | - |")
                continue
            rho = "-" if r["rho"] is None else f"{r['rho']:.2f}"
            print(f"| {r['k_s']:g} | {r['policies']} | {r['fell']} | {r['eigen_min']:.3f} | {r['eigen_median']:.3f} | "
                  f"{r['eigen_max']:.3f} | {r['fixed_mm'][0]:.0f}-{r['fixed_mm'][1]:.0f} | {rho} |")
