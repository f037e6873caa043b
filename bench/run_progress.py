"""Per learner, from the newest checkpoint of a run, finished or still going: trials so far,
trials to success (-1: not yet), the mean velocity and the falls of its last 20 trials (the
learning trials' own numbers, exploration noise included), and sigma.

    NPROC=1 .venv/bin/python bench/run_progress.py runs/stats [more runs]
"""

import sys
from pathlib import Path

import numpy as np

from mjxcpg.training import runs


def main(run_dirs: list[str]) -> None:
    for run_dir in run_dirs:
        spec, _, _, state = runs.load_run(Path(run_dir))
        book = state.learners.book
        trials, to_success = np.asarray(book.trial), np.asarray(book.trials_to_success)
        velocities, falls, sigmas = (np.asarray(x) for x in (book.velocities, book.falls, book.sigmas))
        print(run_dir)
        for i, k_s in enumerate(spec.k_s):
            n = int(trials[i])
            last = slice(max(0, n - 20), n)
            print(f"  {i:3d} k_s={k_s:4g} trials={n:4d} to_success={int(to_success[i]):4d} "
                  f"v_last20={np.mean(velocities[i, last]):.3f} falls_last20={int(falls[i, last].sum()):2d} "
                  f"sigma={sigmas[i, max(n - 1, 0)]:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
