"""Walking speed against the gain K of a roll-rate feedback, raw and squashed as a policy's.

Each feedback walks 20 s from standing on the native engine, one batch of robots per form:

* ``linear``: a_5 = K d theta_roll/dt, the hand-designed form;
* ``a_max = 1``, ``2``, ``3``: a_5 = a_max g(K d theta_roll/dt / a_max), the learned
  policy's squashing (eq 10) with slope K at 0.

A second table gives the mean pelvis height of the same walks, the other term of the reward
(eq 27: r = k_H (h - h') + k_S v_x).

    NPROC=1 .venv/bin/python bench/feedback_gains.py
"""

import jax.numpy as jnp

from mjxcpg.control import walk
from mjxcpg.control.sim import make_simulation
from mjxcpg.learning import policy

GAINS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)


def main() -> None:
    sim = make_simulation("native")
    forms = {
        "linear": lambda obs, k: k * obs.gyro[0],
        "a_max = 1": lambda obs, k: policy.feedback_action(k * obs.gyro[0], 1.0),
        "a_max = 2": lambda obs, k: policy.feedback_action(k * obs.gyro[0], 2.0, 2.0),
        "a_max = 3": lambda obs, k: policy.feedback_action(k * obs.gyro[0], 3.0, 3.0),
    }
    gaits = {name: walk.summarise(walk.walk_from_standing(sim, feedback, jnp.array(GAINS), 20.0),
                                  sim.control_dt, sim.layout.weight)
             for name, feedback in forms.items()}
    header = ["| feedback | " + " | ".join(f"K = {k:g}" for k in GAINS) + " |", "|---|" + "---|" * len(GAINS)]
    for title, cell in (("20 s velocity (m/s)", lambda g: f"{g.mean_vx:.3f}"),
                        ("mean pelvis height (m)", lambda g: f"{g.mean_pelvis_height:.4f}")):
        print(f"\n{title}\n")
        print("\n".join(header))
        for name, row in gaits.items():
            cells = [f"falls at {g.seconds:.1f} s" if g.fell else cell(g) for g in row]
            print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
