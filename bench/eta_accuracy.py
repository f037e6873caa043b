"""The progress line's time left against the time a run actually had left, read from the
run's TensorBoard events (``tensorboard/run``: ``progress/eta_s`` after every chunk, with its
wall time), at 10%, 50% and 90% of the run: the estimate the line showed then (that of the
last chunk ended by then) against the time left from that chunk's end.

By default the fractions are of the run's wall time from its first chunk's end to its last;
with ``--by finished``, of its learners: the first chunk after which at least that fraction
of the batch had finished.

    python bench/eta_accuracy.py [--by finished] runs/quick [runs/printed ...]

A run resumed in several sessions counts the pauses between them as time left."""

import argparse
from pathlib import Path

from mjxcpg.training import runs
from mjxcpg.training.events import EVENTS_DIR, RUN_NAME, read_events

FRACTIONS = (0.1, 0.5, 0.9)


def eta_at_fractions(run_dir: Path, by: str = "wall") -> list[dict]:
    events = [(wall, values) for wall, _, values in read_events(run_dir / EVENTS_DIR / RUN_NAME)]
    first, last = events[0][0], events[-1][0]
    batch = runs.read_config(run_dir)[0].batch
    rows = []
    for fraction in FRACTIONS:
        if by == "finished":
            wall, values = next(e for e in events if e[1]["progress/learners_finished"] >= fraction * batch)
        else:
            wall, values = [e for e in events if e[0] <= first + fraction * (last - first)][-1]
        eta, left = values.get("progress/eta_s"), last - wall
        rows.append({"fraction": fraction, "elapsed_s": wall - first, "finished": int(values["progress/learners_finished"]),
                     "eta_s": eta, "left_s": left, "ratio": None if eta is None or left <= 0 else eta / left})
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--by", choices=("wall", "finished"), default="wall",
                        help="fractions of the wall time (default) or of the learners finished")
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args()
    for run in args.runs:
        print(f"{run}: seconds from the first chunk's end to the last chunk's end; fractions of the "
              + ("wall time" if args.by == "wall" else "learners finished"))
        print("| at | elapsed (s) | learners finished | ETA (s) | actually left (s) | ETA / left |\n"
              "|---|---|---|---|---|---|")
        for r in eta_at_fractions(run, args.by):
            eta = "?" if r["eta_s"] is None else f"{r['eta_s']:.3g}"
            ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
            print(f"| {r['fraction']:.0%} | {r['elapsed_s']:.3g} | {r['finished']} | {eta} | {r['left_s']:.3g} | {ratio} |")
