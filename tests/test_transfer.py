"""The engine transfer: final policies walked on MuJoCo C and on MJX."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from learned_run import make_learned_run

from mjxcpg.cli import main
from mjxcpg.evaluation import transfer
from mjxcpg.learning.actor_critic import Weights
from mjxcpg.training import train


def test_perturbed_weights_repeat_each_learner_the_first_walk_as_learned():
    mean = jnp.arange(1.0, 7.0).reshape(2, 3)
    weights = Weights(critic=jnp.zeros((2, 3)), mean=mean, sigma=jnp.array([0.1, 0.2]))
    walked = transfer.perturbed_weights(weights, walks=4, learners=[5, 9])
    assert walked.mean.shape == (8, 3) and walked.sigma.tolist() == pytest.approx([0.1] * 4 + [0.2] * 4)
    expected = np.repeat(np.asarray(mean), 4, axis=0)
    np.testing.assert_array_equal(walked.mean[::4], mean)  # as learned
    relative = np.abs(np.asarray(walked.mean) / expected - 1)
    # 1e-6 times a standard normal draw: nonzero, and below 6e-6 (|n| < 6 for 18 draws but
    # once in 1e7); float32 rounds a weight near 1-6 by at most 6e-8 of itself
    others = np.delete(relative, [0, 4], axis=0)
    assert (others > 0).mean() > 0.5 and others.max() < 6e-6 + 6e-8
    # a learner's walks are the same whichever learners share its batch
    alone = transfer.perturbed_weights(weights._replace(mean=mean[1:], critic=weights.critic[1:],
                                                        sigma=weights.sigma[1:]), walks=4, learners=[9])
    np.testing.assert_array_equal(alone.mean, walked.mean[4:])


def test_compare_engines_leaves_out_policies_that_fall_on_either_engine(monkeypatch):
    """Three successful policies, two walks each (speeds given, not walked): one agrees, one
    is 20% faster on MJX, one falls once on MJX; only the first two are compared."""
    speeds = {"native": np.array([[0.05, 0.07], [0.05, 0.05], [0.06, 0.06]]),
              "mjx": np.array([[0.06, 0.06], [0.06, 0.06], [0.06, np.nan]])}
    monkeypatch.setattr(transfer, "engine_speeds", lambda spec, weights, learners, engine, seconds, walks:
                        speeds[engine])
    spec = train.RunSpec(k_s=(1.0, 2.0, 3.0), seeds=(0, 1, 2))
    result = transfer.compare_engines(spec, None, [True, True, True], "native", walks=2, learners=[4, 5, 6])
    assert [r["learner"] for r in result["learners"]] == [4, 5, 6]
    assert result["successful_that_fell"] == [6] and result["compared"] == 2
    assert result["learners"][0]["mjx_over_c"] == pytest.approx(1.0)
    assert result["learners"][2]["mean_vx_mjx"] == pytest.approx(0.06)      # over its upright walk
    assert result["median_abs_difference"] == pytest.approx(0.1)           # 0 and 0.2
    assert result["max_abs_difference"] == pytest.approx(0.2) and result["within_10_percent"] == 1


def test_transfer_replaces_an_earlier_result_only_with_force(tmp_path, capsys):
    """Refused before any walk: the earlier transfer.json stays as it was."""
    run = make_learned_run(tmp_path / "run")
    (run / "summary.json").write_text("{}")
    (run / "transfer.json").write_text('{"earlier": true}')
    assert main(["transfer", "--run", str(run), "--walks", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg: error:") and "\n" not in err and "--force" in err
    assert (run / "transfer.json").read_text() == '{"earlier": true}'


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
