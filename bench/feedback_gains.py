"""Walking speed against the gain K of a roll-rate feedback, raw and squashed as a policy's.

Each feedback walks 20 s from standing on the native engine, one batch of robots per form:

* ``linear``: a_5 = K d theta_roll/dt, the hand-designed form;
* ``a_max = 1``, ``a_max = 2``: a_5 = a_max g(K d theta_roll/dt / a_max), the learned
  policy's squashing (eq 10) with slope K at 0.

    NPROC=1 .venv/bin/python bench/feedback_gains.py
"""

import jax.numpy as jnp

from mjxcpg import policy, walk
from mjxcpg.sim import make_simulation

GAINS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


def main() -> None:
    sim = make_simulation("native")
    forms = {
        "linear": lambda obs, k: k * obs.gyro[0],
        "a_max = 1": lambda obs, k: policy.feedback_action(k * obs.gyro[0], 1.0),
        "a_max = 2": lambda obs, k: policy.feedback_action(k * obs.gyro[0] / 2.0, 2.0),
    }
    print("| feedback | " + " | ".join(f"K = {k:g}" for k in GAINS) + " |")
    print("|---|" + "---|" * len(GAINS))
    for name, feedback in forms.items():
        trace = walk.walk_from_standing(sim, feedback, jnp.array(GAINS), 20.0)
        cells = [f"falls at {g.seconds:.1f} s" if g.fell else f"{g.mean_vx:.3f}"
                 for g in walk.summarise(trace, sim.control_dt)]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
