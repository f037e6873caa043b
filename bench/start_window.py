"""How a final policy survives the start of a walk: falls over a grid of hand-over times.

A walk from standing is one start among many: a learning trial hands the gait over from the
hand-designed feedback at a random time, and ``eval`` walks from standing (a hand-over at 0).
This walks each chosen final policy (its mean, no noise), or a control (``--controller hand``:
the hand-designed feedback throughout; ``zero``: a_5 = 0 after the hand-over), on the run's
engine for ``--seconds`` after hand-designed starts of every length in ``--grid START STOP
STEP`` (seconds), and prints:

* the walks that fall, of all walked, and the robots that fall after some start;
* per start, the robots that fall;
* per robot that falls, each start it falls after and when (``start@fall``, seconds);
* the direction the walk first takes: the mean velocity along +x from 0.3 to 1.5 s
  (``--early``), for walks that fall and walks that do not, and how many of each go backward.

    NPROC=1 .venv/bin/python bench/start_window.py runs/stats_heading
    NPROC=1 .venv/bin/python bench/start_window.py runs/stats_heading --grid 0 0.4 0.016
    NPROC=1 .venv/bin/python bench/start_window.py runs/stats_heading --controller hand --learners 60
    NPROC=1 .venv/bin/python bench/start_window.py runs/stats_heading --grid 0 0.704 0.016 --set hand_fade_seconds=2

``--learners`` defaults to every k_s >= 1 learner. ``--set NAME=VALUE`` changes a controller
constant (``ControllerParams``) of the run's. ``--json FILE`` writes every walk there.
"""

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import numpy as np

from mjxcpg.control import walk
from mjxcpg.learning.learner import actor_feedback
from mjxcpg.training import runs


def start_measures(fallen: np.ndarray, forward_position: np.ndarray, dt: float, early: tuple[float, float]):
    """Per robot of one batch of walks (rows of ``fallen`` and ``forward_position``, per control
    period): fell, the fall's time (s; nan without one) and the mean v_x over ``early``
    (s), ended at the fall if it comes first."""
    fell = fallen.any(axis=1)
    first = np.argmax(fallen, axis=1)
    a = round(early[0] / dt)
    b = np.maximum(np.minimum(round(early[1] / dt), np.where(fell, first, fallen.shape[1]) - 1), a + 1)
    x = forward_position.astype(np.float64)
    early_vx = (x[np.arange(len(b)), b] - x[:, a]) / ((b - a) * dt)
    return fell, np.where(fell, first * dt, np.nan), early_vx


def walk_starts(sim, feedback, weights, hand_seconds: np.ndarray, seconds: float, early: tuple[float, float]):
    """``start_measures`` of every robot (columns) walked after each hand-over time (rows)."""
    rows = []
    for hand in hand_seconds:
        trace = walk.walk_from_standing(sim, feedback, weights, seconds, hand_seconds=float(hand))
        rows.append(start_measures(np.asarray(trace.fallen), np.asarray(trace.forward_position), sim.control_dt, early))
    return tuple(np.stack(column) for column in zip(*rows))


def add_start_arguments(parser: argparse.ArgumentParser, grid: tuple[float, float, float]) -> None:
    """The arguments every start-of-walk tool takes: the run, its robots, what acts, the grid."""
    parser.add_argument("run", type=Path)
    parser.add_argument("--learners", type=int, nargs="+", default=None, help="default: every k_s >= 1 learner")
    parser.add_argument("--controller", choices=("policy", "hand", "zero"), default="policy")
    parser.add_argument("--grid", type=float, nargs=3, default=grid, metavar=("START", "STOP", "STEP"),
                        help="hand-over times (s), STOP included")


def hand_over_times(grid: tuple[float, float, float], tool: str, latest: float | None = None) -> np.ndarray:
    """The hand-over times of ``--grid START STOP STEP``; a one-line exit if it is not a grid
    (or, with ``latest``, if STOP is past it)."""
    start, stop, step = grid
    if step <= 0 or stop < start or start < 0 or (latest is not None and stop > latest):
        bound = "STOP" if latest is None else f"STOP <= {latest:g}"
        raise SystemExit(f"{tool}: --grid needs 0 <= START <= {bound} and STEP > 0")
    return np.round(np.arange(start, stop + step / 2, step), 6)


def chosen_actors(args: argparse.Namespace, spec, task, state, tool: str):
    """The robots walked (``--learners``, default every k_s >= 1 learner), their final weights
    and what acts after the hand-over (``--controller``, from ``actor_feedback``)."""
    chosen = (runs.check_learners(spec, args.learners) if args.learners
              else [k for k in range(spec.batch) if spec.k_s[k] >= 1])
    if not chosen:
        raise SystemExit(f"{tool}: the run has no k_s >= 1 learner; name some with --learners")
    weights = jax.tree.map(lambda w: w[np.asarray(chosen)], state.learners.weights)
    feedback = actor_feedback(dataclasses.replace(task, trial=dataclasses.replace(task.trial, actor=args.controller)))
    return chosen, weights, feedback


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_start_arguments(parser, (0.0, 3.0, 0.05))
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--early", type=float, nargs=2, default=(0.3, 1.5), metavar=("FROM", "TO"))
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="controller constants changed from the run's, e.g. hand_fade_seconds=2")
    args = parser.parse_args()
    hands = hand_over_times(args.grid, "start_window")
    spec, sim, task, state = runs.load_run(args.run)
    try:
        changes = {name: float(value) for name, value in (item.split("=", 1) for item in args.set)}
        sim = sim.rebuild(params=dataclasses.replace(sim.params, **changes))
    except (ValueError, TypeError) as error:
        raise SystemExit(f"start_window: --set needs NAME=VALUE with a ControllerParams name ({error})") from None
    chosen, weights, feedback = chosen_actors(args, spec, task, state, "start_window")
    fell, when, early_vx = walk_starts(sim, feedback, weights, hands, args.seconds, tuple(args.early))

    print(f"{args.run}, {args.controller}{''.join(' ' + item for item in args.set)}: {len(chosen)} robots x {len(hands)} hand-overs "
          f"{hands[0]:g}-{hands[-1]:g} s, {args.seconds:g} s each")
    print(f"walks with a fall: {int(fell.sum())} of {fell.size} ({fell.mean():.1%}); "
          f"robots that fall after some start: {int(fell.any(axis=0).sum())} of {len(chosen)}")
    print("\n| hand-over (s) | falls | robots |\n|---|---|---|")
    for i in np.flatnonzero(fell.any(axis=1)):
        print(f"| {hands[i]:g} | {int(fell[i].sum())} | {' '.join(str(chosen[j]) for j in np.flatnonzero(fell[i]))} |")
    print("\n| robot | k_s | falls | start@fall (s) |\n|---|---|---|---|")
    for j in np.flatnonzero(fell.any(axis=0)):
        starts = ", ".join(f"{hands[i]:g}@{when[i, j]:.1f}" for i in np.flatnonzero(fell[:, j]))
        print(f"| {chosen[j]} | {spec.k_s[chosen[j]]:g} | {int(fell[:, j].sum())} | {starts} |")
    print(f"\nmean v_x from {args.early[0]:g} to {args.early[1]:g} s (m/s): 10th, 50th, 90th percentile; backward")
    for name, mask in (("fall", fell), ("no fall", ~fell)):
        if mask.any():
            v = early_vx[mask]
            print(f"  {name}: {int(mask.sum())} walks, {np.percentile(v, 10):+.3f} {np.median(v):+.3f} "
                  f"{np.percentile(v, 90):+.3f}; backward {int((v < 0).sum())}")
    backward = early_vx < 0
    if backward.any():
        print(f"  of the walks that start backward, {int(fell[backward].sum())} of {int(backward.sum())} fall; "
              f"of those that start forward, {int(fell[~backward].sum())} of {int((~backward).sum())}")
    if args.json:
        args.json.write_text(json.dumps({
            "run": str(args.run), "controller": args.controller, "set": args.set, "learners": chosen, "hand_seconds": hands.tolist(),
            "seconds": args.seconds, "early": list(args.early), "fell": fell.tolist(),
            "fall_s": np.where(fell, when, -1.0).tolist(), "early_vx": early_vx.tolist()}, indent=1))


if __name__ == "__main__":
    try:
        main()
    except runs.RunError as error:
        raise SystemExit(f"start_window: {error}") from None
