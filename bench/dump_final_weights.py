"""Write a run's final weights and trials to success to an .npz that any version reads, for
``bench/transfer_weights.py`` (which walks a few learners many times):

    NPROC=1 .venv/bin/python bench/dump_final_weights.py runs/printed_mjx_today /tmp/w.npz

A run whose checkpoint this version does not read (an older layout): run this script with
the code that made the run, and walk the weights with this one.
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
