"""Which way the CPG's oscillators lock at the start of a walk, and how hard the feedback pulls.

The stepping oscillator (neurons 1-2, q1 - q2 lifts the legs in turn) and the propulsive one
(neurons 3-6, q5 - q6 swings them fore and aft) are coupled only through a_5 and the body:
the propulsive oscillator leads the stepping one by some phase in a forward walk and lags it
in a backward one.  This walks each chosen final policy (or ``--controller hand|zero``) 4 s
after hand-designed starts of every length in ``--grid START STOP STEP`` and reports, for the
walks that go backward (mean v_x over 0.3-1.5 s below 0) and those that go forward:

* the feedback's roll-rate gain over the first second after the hand-over: the least-squares
  g of a_5 = g d(theta_roll)/dt (the hand-designed feedback is this form, g = K);
* the phase of q5 - q6 less that of q1 - q2 (degrees, circular mean) over 0.3-1.5 s and over
  3-4 s;

per k_s the median gain and the backward starts; the backward starts per hand-over time; and,
over the policies with starts both ways, the median of each one's gain difference (median over
its backward starts less median over its forward ones).

    NPROC=1 .venv/bin/python bench/start_phase.py runs/stats_heading
    NPROC=1 .venv/bin/python bench/start_phase.py runs/stats_heading --controller hand --learners 60
"""

import argparse

import numpy as np
from start_window import add_start_arguments, chosen_actors, hand_over_times

from mjxcpg.control import walk
from mjxcpg.training import runs

SECONDS = 4.0
EARLY = (0.3, 1.5)   # s, the window of the early direction and the early phase
STEADY = (3.0, 4.0)  # s


def analytic_phase(x: np.ndarray) -> np.ndarray:
    """The phase (rad) of the analytic signal of each column of ``x`` (time along axis 0),
    its mean removed: the Hilbert transform by FFT."""
    x = x - x.mean(axis=0)
    n = x.shape[0]
    spectrum = np.fft.fft(x, axis=0)
    h = np.zeros(n)
    h[0] = 1.0
    h[1:(n + 1) // 2] = 2.0
    if n % 2 == 0:
        h[n // 2] = 1.0
    return np.angle(np.fft.ifft(spectrum * h[:, None], axis=0))


def relative_phase_deg(cpg_z: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Per robot (axis 1 of ``cpg_z``, time x robots x 6), the circular mean over steps
    [start, stop) of the phase of q5 - q6 less that of q1 - q2 (degrees, in (-180, 180])."""
    q = np.maximum(cpg_z, 0.0)
    difference = analytic_phase(q[..., 4] - q[..., 5]) - analytic_phase(q[..., 0] - q[..., 1])
    return np.degrees(np.angle(np.exp(1j * difference[start:stop]).mean(axis=0)))


def roll_rate_gain(roll: np.ndarray, a5: np.ndarray, dt: float, start: int, stop: int) -> np.ndarray:
    """Per robot (rows), the least-squares g of a5 = g d(roll)/dt over steps [start, stop),
    the rate by central differences."""
    rate = np.gradient(roll.astype(np.float64), dt, axis=1)[:, start:stop]
    a = a5.astype(np.float64)[:, start:stop]
    return (rate * a).sum(axis=1) / (rate * rate).sum(axis=1)


def percentiles(values: np.ndarray, digits: int) -> str:
    """The 10th, 50th and 90th percentiles, or "-" without values."""
    return " ".join(f"{v:+.{digits}f}" for v in np.percentile(values, (10, 50, 90))) if len(values) else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_start_arguments(parser, (0.0, 0.72, 0.048))
    args = parser.parse_args()
    hands = hand_over_times(args.grid, "start_phase", latest=SECONDS - 1.0)
    spec, sim, task, state = runs.load_run(args.run)
    chosen, weights, feedback = chosen_actors(args, spec, task, state, "start_phase")
    dt = sim.control_dt
    early, steady = (slice(round(a / dt), round(b / dt)) for a, b in (EARLY, STEADY))
    k_s = np.array([spec.k_s[k] for k in chosen])
    rows = []  # per walk: k_s, early v_x, gain, early phase, steady phase, robot, hand-over
    for hand in hands:
        trace = walk.walk_from_standing(sim, feedback, weights, SECONDS, hand_seconds=float(hand), record_cpg=True)
        x = np.asarray(trace.forward_position, np.float64)
        cpg_z = np.swapaxes(np.asarray(trace.cpg_z), 0, 1)  # time x robots x 6
        h = round(hand / dt)
        rows.append(np.stack([
            k_s, (x[:, early.stop] - x[:, early.start]) / (EARLY[1] - EARLY[0]),
            roll_rate_gain(np.asarray(trace.roll), np.asarray(trace.a5), dt, h, h + round(1.0 / dt)),
            relative_phase_deg(cpg_z, early.start, early.stop), relative_phase_deg(cpg_z, steady.start, steady.stop),
            np.arange(len(chosen)), np.full(len(chosen), hand)], axis=1))
    rows = np.concatenate(rows)
    backward = rows[:, 1] < 0
    print(f"{args.run}, {args.controller}: {len(chosen)} robots x {len(rows) // len(chosen)} hand-overs "
          f"{args.grid[0]:g}-{args.grid[1]:g} s; gain over the first second after the hand-over, phase of q5 - q6 less q1 - q2")
    print("\n10th, 50th and 90th percentiles:\n\n| start | walks | gain | phase 0.3-1.5 s (deg) | phase 3-4 s (deg) |"
          "\n|---|---|---|---|---|")
    for name, mask in (("backward", backward), ("forward", ~backward)):
        print(f"| {name} | {int(mask.sum())} | {percentiles(rows[mask, 2], 2)} | "
              f"{percentiles(rows[mask, 3], 0)} | {percentiles(rows[mask, 4], 0)} |")
    print("\n| k_s | walks | median gain | backward starts |\n|---|---|---|---|")
    for value in np.unique(k_s):
        mask = rows[:, 0] == value
        print(f"| {value:g} | {int(mask.sum())} | {np.median(rows[mask, 2]):.2f} | {int(backward[mask].sum())} |")
    hands, counts = np.unique(rows[backward, 6], return_counts=True)
    print("\nbackward starts per hand-over (s): " + (", ".join(f"{h:g}: {c}" for h, c in zip(hands, counts)) or "none"))
    differences = [np.median(rows[backward & (rows[:, 5] == j), 2]) - np.median(rows[~backward & (rows[:, 5] == j), 2])
                   for j in range(len(chosen)) if (backward & (rows[:, 5] == j)).any() and (~backward & (rows[:, 5] == j)).any()]
    if differences:
        print(f"gain, backward less forward starts, median over the {len(differences)} policies with both: "
              f"{np.median(differences):+.3f}")


if __name__ == "__main__":
    try:
        main()
    except runs.RunError as error:
        raise SystemExit(f"start_phase: {error}") from None
