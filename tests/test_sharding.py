"""The learner axis sharded over four forced host devices gives the unsharded run's results."""

import os
import subprocess
import sys

import jax

from mjxcpg.cli import main
from mjxcpg.training.train import learner_sharding

EIGHT_LEARNERS = """
k_s = [10.0, 10.0, 5.0, 5.0, 0.0, 0.0, 10.0, 2.0]
seeds = [0, 1, 2, 3, 4, 5, 6, 7]
chunk_seconds = 4.0
[trial]
max_trials = 4
trial_seconds = 4.0
hand_seconds = [1.0, 2.0]
success_streak = 2
"""

SHARDED = """
import sys
import jax
from mjxcpg.cli import main
from mjxcpg.training.train import learner_sharding
assert len(learner_sharding(8).mesh.devices.flat) == 4, jax.devices()
sys.exit(main(sys.argv[1:]))
"""


def test_sharding_keeps_two_learners_per_device():
    assert len(jax.devices()) == 1
    assert learner_sharding(27).mesh.devices.size == 1


def test_sharded_sweep_equals_unsharded(tmp_path):
    config = tmp_path / "eight.toml"
    config.write_text(EIGHT_LEARNERS)
    args = ["sweep", "--config", str(config), "--engine", "native", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "one")]) == 0
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    subprocess.run([sys.executable, "-c", SHARDED, *args, "--out", str(tmp_path / "four")],
                   env=env, check=True, capture_output=True)
    for name in ("summary.json", "returns.json"):
        assert (tmp_path / "one" / name).read_text() == (tmp_path / "four" / name).read_text()
