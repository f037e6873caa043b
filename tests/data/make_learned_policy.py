"""Regenerate ``tests/data/learned_policy_ks10_seed1.json``: one learned policy for the tests.

The tests that walk "the same learned policy on both engines" need a policy a clean clone
has without learning one first.  This script learns it with

    mjxcpg learn --k-s 10 --seed 1 --engine native --trials 200

(tens of trials, under a minute on a 2-core CPU) and stores the policy mean's NGnet
weights w^mu (eq 25, 225 numbers) with the settings needed to read them back.  Run it from
the repository root:

    .venv/bin/python tests/data/make_learned_policy.py [--run-dir DIR]

The learner's state is otherwise discarded: walking with the policy's mean (no noise, as
``mjxcpg walk --checkpoint`` does) needs only w^mu, the basis and a_max.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from mjxcpg.cli import main as mjxcpg_main
from mjxcpg.robots.qrio import QRIO
from mjxcpg.training.runs import load_run

POLICY_PATH = Path(__file__).resolve().parent / "learned_policy_ks10_seed1.json"
K_S, SEED, ENGINE, TRIALS = 10.0, 1, "native", 200


def learn_and_export(run_dir: Path, out: Path = POLICY_PATH) -> dict:
    """Learn the policy in ``run_dir`` (replaced if it exists) and write ``out``."""
    argv = ["learn", "--k-s", f"{K_S:g}", "--seed", str(SEED), "--engine", ENGINE,
            "--trials", str(TRIALS), "--out", str(run_dir), "--force", "--quiet"]
    if mjxcpg_main(argv) != 0:
        raise SystemExit("learning failed")
    learned = json.loads((run_dir / "learn.json").read_text())
    if not learned["succeeded"]:
        raise SystemExit(f"the learner did not succeed within {TRIALS} trials")
    spec, _, task, state = load_run(run_dir)
    record = {
        "command": "mjxcpg " + " ".join(argv[:-4]),
        "k_s": K_S, "seed": SEED, "engine": ENGINE,
        "trials_to_success": learned["trials_to_success"],
        "mean_vx_on_learning_engine": learned["mean_vx"],
        "mujoco_version": mujoco.__version__,
        "model_sha256": model_fingerprint(),
        "git_commit": git_commit(),
        "basis_grid": spec.basis_grid, "basis_width": spec.basis_width,
        "a_max": task.learner.a_max,
        "policy_mean_weights": [float(w) for w in np.asarray(state.learners.weights.mean[0])],
    }
    out.write_text(json.dumps(record, indent=1) + "\n")
    return record


def model_fingerprint(path=QRIO.mjcf_resource()) -> str:
    """SHA-256 of the robot's MJCF without its comments (``conftest.model_fingerprint``): the
    tests refuse a policy learned on another model."""
    return hashlib.sha256(re.sub(r"<!--.*?-->", "", path.read_text(), flags=re.S).encode()).hexdigest()


def git_commit() -> str | None:
    """The commit the policy was learned at (with ``+dirty`` for uncommitted changes), or
    None outside a git checkout."""
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return commit + ("+dirty" if dirty else "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", type=Path, help="where to keep the learning run (default: a temporary dir)")
    args = parser.parse_args(argv)
    if args.run_dir is not None:
        record = learn_and_export(args.run_dir)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            record = learn_and_export(Path(tmp) / "run")
    print(f"wrote {POLICY_PATH}: success after {record['trials_to_success']} trials, "
          f"mean_vx {record['mean_vx_on_learning_engine']:.4f} m/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
