"""The progress line's time left against the time a run actually had left, read from the
run's TensorBoard events (``tensorboard/run``: ``progress/eta_s`` after every chunk, with its
wall time), at 10%, 50% and 90% of the run's wall time from its first chunk to its last: the
estimate the line showed then (that of the last chunk ended by then) against the time left
from that chunk's end.

    python bench/eta_accuracy.py runs/quick [runs/paper ...]

A run resumed in several sessions counts the pauses between them as time left."""

import sys
from pathlib import Path

from mjxcpg.training.events import EVENTS_DIR, RUN_NAME, read_events

FRACTIONS = (0.1, 0.5, 0.9)


def eta_at_fractions(run_dir: Path) -> list[dict]:
    events = [(wall, values) for wall, _, values in read_events(run_dir / EVENTS_DIR / RUN_NAME)]
    first, last = events[0][0], events[-1][0]
    rows = []
    for fraction in FRACTIONS:
        wall, values = [e for e in events if e[0] <= first + fraction * (last - first)][-1]
        eta, left = values.get("progress/eta_s"), last - wall
        rows.append({"fraction": fraction, "elapsed_s": wall - first, "eta_s": eta, "left_s": left,
                     "ratio": None if eta is None or left <= 0 else eta / left})
    return rows


if __name__ == "__main__":
    for run in sys.argv[1:]:
        print(f"{run}: seconds from the first chunk's end to the last chunk's end")
        print("| at | elapsed (s) | ETA (s) | actually left (s) | ETA / left |\n|---|---|---|---|---|")
        for r in eta_at_fractions(Path(run)):
            eta = "?" if r["eta_s"] is None else f"{r['eta_s']:.3g}"
            ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
            print(f"| {r['fraction']:.0%} | {r['elapsed_s']:.3g} | {eta} | {r['left_s']:.3g} | {ratio} |")
