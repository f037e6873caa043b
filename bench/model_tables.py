"""The walking figures of docs/model.md, re-measured on the current model.

20 s walks from standing on the MuJoCo C engine (``native``), a_5 = K d(theta_roll)/dt, for
several VSR gains h_VSR and signs s (``ControllerParams.h_vsr``, ``vsr_sign``).  Each row of
the table is two batched walks: K = 0, 0.5, 1, 2 (and -1 on the shipped row) with A_x = 15 mm,
and K = 0 with A_x = 0.  A cell reads "walks V m/s" (mean forward speed after 2 s of settling),
"steps" (A_x = 0, no fall) or "falls at T s".  Below the table: the entrained gait cycles
and the backward walk quoted in the text:

    NPROC=1 .venv/bin/python bench/model_tables.py
    NPROC=1 .venv/bin/python bench/model_tables.py --alone   # each robot in a batch of its own

``--alone`` walks every robot by itself, as ``mjxcpg walk`` does; float32 rounding in the
vectorised controller depends on the batch size, so the figures move a little.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import jax.numpy as jnp

from mjxcpg.control import walk
from mjxcpg.control.controller import ControllerParams, roll_rate_feedback
from mjxcpg.control.sim import make_simulation

SECONDS = 20.0
GAINS = (0.0, 0.5, 1.0, 2.0)
# (h_VSR, sign, the K columns shown); the shipped controller is (0.3, -1)
ROWS = ((1.8, -1.0, GAINS), (1.8, 1.0, (1.0,)), (0.9, -1.0, GAINS),
        (0.3, -1.0, GAINS), (0.3, 1.0, GAINS))
SHIPPED = (ControllerParams().h_vsr, ControllerParams().vsr_sign)


def walks(h_vsr: float, sign: float, amp_x: float, gains,
          alone: bool = False) -> dict[float, walk.GaitSummary]:
    """Summaries of 20 s walks, one robot per gain K: one batch, or one call per robot."""
    if alone:
        return {k: walks(h_vsr, sign, amp_x, (k,))[k] for k in gains}
    params = dataclasses.replace(ControllerParams(), h_vsr=h_vsr, vsr_sign=sign, amp_x=amp_x)
    sim = make_simulation("native", params=params)
    trace = walk.walk_from_standing(sim, lambda obs, k: roll_rate_feedback(obs, k),
                                    jnp.array(gains), SECONDS)
    return dict(zip(gains, walk.summarise(trace, sim.control_dt, sim.layout.weight)))


def cell(s: walk.GaitSummary | None, stepping_in_place: bool = False) -> str:
    if s is None:
        return ""
    if s.fell:
        return f"falls at {s.seconds:.1f} s"
    return "steps" if stepping_in_place else f"walks {s.mean_vx:.3f} m/s"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--alone", action="store_true", help="walk each robot in its own batch")
    alone = parser.parse_args().alone
    start = time.perf_counter()
    print("| h_VSR, sign | a_5 = 0 | a_5 = 0, A_x = 0 | K = 0.5 | K = 1 | K = 2 |")
    print("|---|---|---|---|---|---|")
    results = {}
    for h_vsr, sign, shown in ROWS:
        extra = (-1.0,) if (h_vsr, sign) == SHIPPED else ()
        forward = walks(h_vsr, sign, ControllerParams().amp_x, tuple(shown) + extra, alone)
        in_place = walks(h_vsr, sign, 0.0, (0.0,))[0.0] if 0.0 in shown else None
        results[h_vsr, sign] = forward, in_place
        cells = [cell(forward.get(0.0)), cell(in_place, stepping_in_place=True)]
        cells += [cell(forward.get(k)) for k in GAINS[1:]]
        print(f"| {h_vsr}, {sign:+.0f} | " + " | ".join(cells) + " |", flush=True)

    paper = results[1.8, -1.0][0][1.0]
    print(f"\nh_VSR = 1.8, s = -1, K = 1 (the paper's reflex gains, hand-designed a_5): "
          f"{cell(paper)}, gait cycle {paper.gait_period:.2f} s")
    forward, in_place = results[SHIPPED]
    cycles = [s.gait_period for k, s in forward.items() if k >= 0 and not s.fell]
    cycles += [in_place.gait_period] if not in_place.fell else []
    print(f"h_VSR = 0.3, s = -1 (shipped), every walk of the row that did not fall: gait cycle "
          f"{min(cycles):.2f}-{max(cycles):.2f} s")
    print(f"h_VSR = 0.3, s = -1, K = -1: {cell(forward[-1.0])}, "
          f"gait cycle {forward[-1.0].gait_period:.2f} s")
    print(f"\n{time.perf_counter() - start:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
