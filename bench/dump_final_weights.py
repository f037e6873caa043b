"""Write a run's final weights and trials to success to an .npz that any version reads.

Run it with the code that made the run (its checkpoint layout may be an older one's), then
walk the weights with the current code (``bench/transfer_weights.py``):

    git worktree add /tmp/b968 b968e4f
    PYTHONPATH=/tmp/b968 NPROC=1 .venv/bin/python bench/dump_final_weights.py runs/paper_mjx /tmp/paper_mjx.npz
"""

import argparse
from pathlib import Path

import jax
import numpy as np

try:
    from mjxcpg.training import runs
except ImportError:  # the flat layout of earlier versions
    from mjxcpg import runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("out", type=Path)
    args = parser.parse_args()
    _, _, _, state = runs.load_run(args.run, "native")
    weights = jax.device_get(state.learners.weights)
    np.savez(args.out, critic=weights.critic, mean=weights.mean, sigma=weights.sigma,
             trials_to_success=np.asarray(state.learners.book.trials_to_success))
    print(f"{args.out}: {weights.mean.shape[0]} learners")


if __name__ == "__main__":
    main()
