"""The engine transfer: final policies walked on MuJoCo C and on MJX."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from learned_run import make_learned_run

from mjxcpg.cli import main
from mjxcpg.evaluation import transfer
from mjxcpg.learning.actor_critic import Weights


def test_perturbed_weights_repeat_each_learner_the_first_walk_as_learned():
    mean = jnp.arange(1.0, 7.0).reshape(2, 3)
    weights = Weights(critic=jnp.zeros((2, 3)), mean=mean, sigma=jnp.array([0.1, 0.2]))
    walked = transfer.perturbed_weights(weights, walks=4)
    assert walked.mean.shape == (8, 3) and walked.sigma.tolist() == pytest.approx([0.1] * 4 + [0.2] * 4)
    expected = np.repeat(np.asarray(mean), 4, axis=0)
    np.testing.assert_array_equal(walked.mean[::4], mean)  # as learned
    relative = np.abs(np.asarray(walked.mean) / expected - 1)
    # 1e-6 times a standard normal draw: nonzero, and below 6e-6 (|n| < 6 for 18 draws but
    # once in 1e7); float32 rounds a weight near 1-6 by at most 6e-8 of itself
    others = np.delete(relative, [0, 4], axis=0)
    assert (others > 0).mean() > 0.5 and others.max() < 6e-6 + 6e-8


@pytest.mark.slow
def test_transfer_of_the_stored_policy_agrees_across_engines(tmp_path, capsys):
    """The stored learned policy walked 3 times on each engine, as the CLI does: no fall, and
    its speeds within 5% (the session walks' tolerance for a learned policy, docs/engines.md)."""
    run = make_learned_run(tmp_path / "run")
    (run / "summary.json").write_text("{}")  # transfer asks for a finished run
    assert main(["transfer", "--run", str(run), "--walks", "3", "--json"]) == 0
    result = json.loads((run / "transfer.json").read_text())
    (row,) = result["learners"]
    assert result["hand_seconds"] == 2.0 and len(row["speeds_c"]) == 3
    assert row["falls_c"] == row["falls_mjx"] == 0
    assert abs(row["mjx_over_c"] - 1) < 0.05
