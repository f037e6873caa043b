"""The CPG without feedback against an independent reference integration of the corrected
eqs 1-3 (tau = 0.105, tau' = 0.132, c = 2.08, gamma = 2.5, a fine step): q1 - q2 oscillates
with period 0.61 s and peak 0.85, q3 - q4 and q5 - q6 with period 0.51 s and peak 0.89, and
q5 - q6 lags q3 - q4 by 90 degrees."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.control import cpg

DT = 1e-4


@pytest.fixture(scope="module")
def oscillation():
    params = cpg.CPGParams()

    def body(state, _):
        state = cpg.step(params, state, jnp.zeros(6), DT)
        q = cpg.output(state)
        return state, jnp.stack([q[0] - q[1], q[2] - q[3], q[4] - q[5]])

    _, trace = jax.jit(lambda s: jax.lax.scan(body, s, None, length=int(30 / DT)))(cpg.init_state(params))
    return np.asarray(trace)[int(10 / DT):]


def upward_crossings(x):
    return np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))


@pytest.mark.parametrize("pair, period, peak", [(0, 0.61, 0.85), (1, 0.51, 0.89), (2, 0.51, 0.89)])
def test_period_and_peak(oscillation, pair, period, peak):
    x = oscillation[:, pair]
    measured_period = np.mean(np.diff(upward_crossings(x))) * DT
    assert measured_period == pytest.approx(period, rel=0.03)
    assert x.max() == pytest.approx(peak, rel=0.03)


def test_propulsive_pair_lags_by_quarter_cycle(oscillation):
    lead, lag = upward_crossings(oscillation[:, 1]), upward_crossings(oscillation[:, 2])
    period = np.mean(np.diff(lead))
    delays = [lag[lag > t][0] - t for t in lead[:-2]]
    assert np.mean(delays) / period * 360 == pytest.approx(90, rel=0.03)


def test_feedback_vector_follows_eq8():
    a = cpg.feedback_vector(jnp.float32(0.3), jnp.float32(-0.2))
    np.testing.assert_allclose(a, [0.3, -0.3, 0.3, -0.3, -0.2, 0.2], rtol=1e-6)


def test_leg_targets_are_antisymmetric():
    q = jnp.array([1.0, 0.2, 0.0, 0.0, 0.7, 0.1])
    t = cpg.leg_targets(q, x0=0.01, z0=0.2, amp_x=0.015, amp_z=0.005)
    assert float(t.left_z) == pytest.approx(0.2 - 0.005 * 0.8)
    assert float(t.right_z) == pytest.approx(0.2 + 0.005 * 0.8)
    assert float(t.left_x + t.right_x) == pytest.approx(0.02)
