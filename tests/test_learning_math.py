"""The learner's mathematics: NGnet (eqs 23-26), policy (10-12), actor-critic (15-22)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.learning import actor_critic as ac
from mjxcpg.learning import ngnet, policy

BASIS = ngnet.make_basis()
NUM_BASIS = BASIS.centers.shape[0]
PRINTED = ac.LearnerParams(rate_scale=1.0, w_sigma_bounds=None)  # the paper's rates as printed

basis_at = jax.jit(jax.vmap(lambda x: ngnet.normalized_basis(BASIS, x)))
activations_at = jax.jit(jax.vmap(lambda x: ngnet.gaussian_activations(BASIS, x)))


# --------------------------------------------------------------------------- NGnet


def test_basis_is_an_even_15_by_15_grid():
    assert BASIS.centers.shape == (225, 2)
    assert BASIS.centers.dtype == jnp.float32
    axis = np.linspace(-2.0, 2.0, 15)
    for dim in range(2):
        np.testing.assert_allclose(np.unique(np.asarray(BASIS.centers[:, dim])), axis, atol=1e-6)
    np.testing.assert_allclose(BASIS.inv_widths, [14.0 / 4.0] * 2, rtol=1e-6)


def test_normalized_basis_sums_to_one_and_is_finite_far_outside():
    rng = np.random.default_rng(0)
    inside = rng.uniform(-2.0, 2.0, (64, 2))
    outside = np.array([[5.0, 0.0], [-30.0, 2.0], [1e3, -1e3], [0.0, 1e6], [-1e30, np.inf]])
    xs = jnp.asarray(np.concatenate([inside, outside]), jnp.float32)
    b = np.asarray(basis_at(xs))
    assert np.all(np.isfinite(b)) and np.all(b >= 0.0)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, rtol=1e-5)
    assert np.all(np.isfinite(np.asarray(activations_at(xs))))
    # far outside, the basis is that of the nearest edge of the grid
    corner = int(np.argmax(np.asarray(BASIS.centers) @ np.array([1.0, -1.0])))
    assert int(np.argmax(b[-3])) == corner


def test_basis_peaks_at_its_centres():
    phi = np.asarray(activations_at(BASIS.centers))
    np.testing.assert_allclose(np.diag(phi), 1.0, rtol=1e-6)
    b = np.asarray(basis_at(BASIS.centers))
    np.testing.assert_array_equal(np.argmax(b, axis=1), np.arange(NUM_BASIS))
    # the printed eq (24) without the square would put a neighbour at exp(-1) too; with the
    # square, a neighbour at one spacing is exp(-1) and a diagonal neighbour exp(-2)
    np.testing.assert_allclose(phi[0, 1], math.exp(-1.0), rtol=1e-5)
    np.testing.assert_allclose(phi[0, 16], math.exp(-2.0), rtol=1e-5)


def test_ngnet_value_and_policy_std():
    b = basis_at(jnp.array([[0.3, -0.7]]))[0]
    weights = jnp.arange(NUM_BASIS, dtype=jnp.float32)
    np.testing.assert_allclose(ngnet.ngnet_value(weights, b), np.dot(weights, b), rtol=1e-6)
    np.testing.assert_allclose(ngnet.ngnet_value(jnp.full(NUM_BASIS, 2.5), b), 2.5, rtol=1e-5)
    np.testing.assert_allclose(ngnet.policy_std(jnp.array([0.0, 2.0])),
                               [0.5, 1.0 / (1.0 + math.exp(-2.0))], rtol=1e-6)


# --------------------------------------------------------------------------- policy


def test_squash_and_feedback_action():
    v = jnp.array([-1e6, -1.0, 0.0, 1e-3, 2.0 / math.pi, 1e6])
    g = np.asarray(policy.squash(v))
    np.testing.assert_allclose(g[[0, 2, 5]], [-1.0, 0.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(g[3], 1e-3, rtol=1e-4)   # slope 1 at the origin
    np.testing.assert_allclose(g[4], 0.5, rtol=1e-6)    # (2/pi) arctan(1) = 0.5
    np.testing.assert_allclose(policy.feedback_action(v, 0.7), 0.7 * g, rtol=1e-6)


def test_unit_slope_feedback_keeps_slope_one_and_reaches_a_max():
    params = ac.LearnerParams(a_max=3.0, unit_slope=True)
    a = np.asarray(policy.feedback_action(jnp.array([1e-3, 6.0 / math.pi, 1e7]), params.a_max, params.v_scale))
    np.testing.assert_allclose(a[0], 1e-3, rtol=1e-4)   # slope 1 at 0, as with a_max = 1
    np.testing.assert_allclose(a[1], 1.5, rtol=1e-6)    # 3 (2/pi) arctan(1) = 1.5
    np.testing.assert_allclose(a[2], 3.0, rtol=1e-5)    # ceiling a_max
    assert ac.LearnerParams(a_max=3.0).v_scale == 1.0   # the printed form by default


def test_sample_action_and_log_policy():
    mean, std = jnp.float32(0.4), jnp.float32(0.3)
    np.testing.assert_allclose(policy.sample_action(mean, std, jnp.float32(2.0)), 1.0, rtol=1e-6)
    v = jnp.linspace(-2.0, 2.0, 9)
    np.testing.assert_allclose(policy.log_policy(v, mean, std),
                               jax.scipy.stats.norm.logpdf(v, mean, std), rtol=1e-5)


@jax.jit
def _gradients_both_ways(x, v, w_mean, w_sigma):
    def log_pi(w_mean, w_sigma):
        b = ngnet.normalized_basis(BASIS, x)
        return policy.log_policy(v, ngnet.ngnet_value(w_mean, b), ngnet.policy_std(w_sigma))

    b = ngnet.normalized_basis(BASIS, x)
    mean, std = ngnet.ngnet_value(w_mean, b), ngnet.policy_std(w_sigma)
    closed = policy.log_policy_gradients(v, mean, std, b)
    return closed, jax.grad(log_pi, argnums=(0, 1))(w_mean, w_sigma)


def test_log_policy_gradients_match_autodiff():
    rng = np.random.default_rng(1)
    for _ in range(8):
        x = jnp.asarray(rng.uniform(-2.5, 2.5, 2), jnp.float32)
        w_mean = jnp.asarray(rng.normal(0.0, 1.0, NUM_BASIS), jnp.float32)
        w_sigma = jnp.float32(rng.uniform(-2.0, 2.0))
        v = jnp.float32(rng.normal(0.0, 1.5))
        (closed_mean, closed_sigma), (auto_mean, auto_sigma) = _gradients_both_ways(
            x, v, w_mean, w_sigma)
        scale = float(jnp.max(jnp.abs(auto_mean)))
        np.testing.assert_allclose(closed_mean, auto_mean, rtol=1e-4, atol=1e-6 * scale)
        np.testing.assert_allclose(closed_sigma, auto_sigma, rtol=1e-4, atol=1e-6)


@functools.partial(jax.jit, static_argnums=6)
def _correlated_gradients_both_ways(x, x_prev, v, v_prev, w_mean, w_sigma, decay):
    """Closed form against autodiff of the AR(1) policy's conditional log-density, written
    out here: v_t ~ N(mu_t + a (v_{t-1} - mu_{t-1}), (sigma sqrt(1 - a^2))^2)."""
    def log_pi(w_mean, w_sigma):
        mu = ngnet.ngnet_value(w_mean, ngnet.normalized_basis(BASIS, x))
        mu_prev = ngnet.ngnet_value(w_mean, ngnet.normalized_basis(BASIS, x_prev))
        std = ngnet.policy_std(w_sigma) * jnp.sqrt(1.0 - decay**2)
        return jax.scipy.stats.norm.logpdf(v, mu + decay * (v_prev - mu_prev), std)

    b, b_prev = ngnet.normalized_basis(BASIS, x), ngnet.normalized_basis(BASIS, x_prev)
    mean, std = ngnet.ngnet_value(w_mean, b), ngnet.policy_std(w_sigma)
    previous_noise = (v_prev - ngnet.ngnet_value(w_mean, b_prev)) / std
    closed = policy.log_policy_gradients(v, mean, std, b, decay, previous_noise, b_prev)
    return closed, jax.grad(log_pi, argnums=(0, 1))(w_mean, w_sigma)


def test_correlated_noise_gradients_match_autodiff():
    rng = np.random.default_rng(2)
    for decay in (0.5, policy.noise_decay(0.2, 0.008)):
        for _ in range(4):
            x, x_prev = (jnp.asarray(rng.uniform(-2.0, 2.0, 2), jnp.float32) for _ in range(2))
            w_mean = jnp.asarray(rng.normal(0.0, 1.0, NUM_BASIS), jnp.float32)
            w_sigma = jnp.float32(rng.uniform(-2.0, 2.0))
            v, v_prev = (jnp.float32(rng.normal(0.0, 1.5)) for _ in range(2))
            (closed_mean, closed_sigma), (auto_mean, auto_sigma) = _correlated_gradients_both_ways(
                x, x_prev, v, v_prev, w_mean, w_sigma, decay)
            scale = float(jnp.max(jnp.abs(auto_mean)))
            # float32 ratios of order 1 / (1 - a^2) = 13 at a = exp(-0.04): a relative 1e-3
            np.testing.assert_allclose(closed_mean, auto_mean, rtol=1e-3, atol=1e-5 * scale)
            np.testing.assert_allclose(closed_sigma, auto_sigma, rtol=1e-3, atol=1e-4 * abs(float(auto_sigma)) + 1e-6)


@jax.jit
def _two_output_gradients_both_ways(x, v, w_mean, w_sigma):
    """Two independent Gaussian outputs: autodiff of the joint log-density written out here,
    ln N(v_1; mu_1, sigma_1^2) + ln N(v_2; mu_2, sigma_2^2), against the closed form."""
    def log_pi(w_mean, w_sigma):
        b = ngnet.normalized_basis(BASIS, x)
        mu = jnp.stack([jnp.sum(w_mean[j] * b) for j in range(2)])
        return jnp.sum(jax.scipy.stats.norm.logpdf(v, mu, jax.nn.sigmoid(w_sigma)))

    b = ngnet.normalized_basis(BASIS, x)
    closed = policy.log_policy_gradients(v, ngnet.ngnet_value(w_mean, b), ngnet.policy_std(w_sigma), b)
    return closed, jax.grad(log_pi, argnums=(0, 1))(w_mean, w_sigma)


def test_two_output_gradients_match_autodiff_of_the_joint_density():
    rng = np.random.default_rng(3)
    for _ in range(6):
        x = jnp.asarray(rng.uniform(-2.5, 2.5, 2), jnp.float32)
        w_mean = jnp.asarray(rng.normal(0.0, 1.0, (2, NUM_BASIS)), jnp.float32)
        w_sigma = jnp.asarray(rng.uniform(-2.0, 2.0, 2), jnp.float32)
        v = jnp.asarray(rng.normal(0.0, 1.5, 2), jnp.float32)
        (closed_mean, closed_sigma), (auto_mean, auto_sigma) = _two_output_gradients_both_ways(
            x, v, w_mean, w_sigma)
        assert closed_mean.shape == (2, NUM_BASIS) and closed_sigma.shape == (2,)
        scale = float(jnp.max(jnp.abs(auto_mean)))
        np.testing.assert_allclose(closed_mean, auto_mean, rtol=1e-4, atol=1e-6 * scale)
        np.testing.assert_allclose(closed_sigma, auto_sigma, rtol=1e-4, atol=1e-6)


def test_two_output_traces_are_each_outputs_one_output_traces():
    """The outputs are independent, so each one's traces after a few steps are those of a
    one-output learner fed that output's samples alone (same TD-free trace law, eq 21)."""
    two = ac.LearnerParams(stepping_a_max=0.4, mean_step_sigma_power=2.0)
    one = ac.LearnerParams(mean_step_sigma_power=2.0)
    rng = np.random.default_rng(4)
    w_mean = jnp.asarray(rng.normal(0.0, 0.5, (2, NUM_BASIS)), jnp.float32)
    w_sigma = jnp.asarray([-0.3, 0.7], jnp.float32)
    pair, single = ac.init_traces(NUM_BASIS, 2), [ac.init_traces(NUM_BASIS) for _ in range(2)]
    for _ in range(5):
        b = ngnet.normalized_basis(BASIS, jnp.asarray(rng.uniform(-2, 2, 2), jnp.float32))
        mean, std = ngnet.ngnet_value(w_mean, b), ngnet.policy_std(w_sigma)
        v = jnp.asarray(rng.normal(0.0, 1.0, 2), jnp.float32)
        pair = ac.accumulate_traces(two, pair, b, v, mean, std, 0.008)
        single = [ac.accumulate_traces(one, single[j], b, v[j], mean[j], std[j], 0.008) for j in range(2)]
    for j in range(2):
        np.testing.assert_allclose(pair.mean[j], single[j].mean, rtol=1e-6)
        np.testing.assert_allclose(pair.sigma[j], single[j].sigma, rtol=1e-6)
    np.testing.assert_allclose(pair.critic, single[0].critic, rtol=1e-6)


def test_two_output_action_is_eq_10_per_output():
    params = ac.LearnerParams(a_max=3.0, unit_slope=True, stepping_a_max=0.4)
    v = jnp.asarray([1.2, -0.3], jnp.float32)
    expected = [3.0 * (2 / math.pi) * math.atan(math.pi / 2 * 1.2 / 3.0),
                0.4 * (2 / math.pi) * math.atan(math.pi / 2 * -0.3 / 0.4)]
    np.testing.assert_allclose(params.action(v), expected, rtol=1e-6)
    assert params.outputs == 2 and ac.LearnerParams().outputs == 1


def test_correlated_noise_is_a_unit_variance_ar1():
    """n_t = a n_{t-1} + sqrt(1 - a^2) xi_t: stationary variance 1, lag-k autocorrelation a^k
    (an Ornstein-Uhlenbeck process with time constant tau_n sampled every dt: a = exp(-dt/tau_n))."""
    decay = policy.noise_decay(0.2, 0.008)
    assert decay == math.exp(-0.04) and policy.noise_decay(0.0, 0.008) == 0.0
    xi = jax.random.normal(jax.random.PRNGKey(0), (200_000,))
    _, n = jax.lax.scan(lambda prev, x: (policy.exploration_noise(prev, x, decay),) * 2, jnp.float32(0), xi)
    n = np.asarray(n[1000:])
    assert abs(n.var() - 1.0) < 0.05   # the sample's standard error is about 0.03 at this correlation
    lag = 25                            # 0.2 s: autocorrelation e^-1
    assert abs(np.corrcoef(n[:-lag], n[lag:])[0, 1] - decay**lag) < 0.03


# --------------------------------------------------------------------------- actor-critic


def test_trace_and_weight_steps():
    grad = jnp.array([1.0, -2.0])
    trace = jnp.array([0.5, 0.5])
    np.testing.assert_allclose(ac.decay_trace(trace, grad, 0.01, 0.5),
                               (1 - 0.02) * trace + 0.01 * grad, rtol=1e-6)
    steady = jax.lax.fori_loop(0, 5000, lambda _, e: ac.decay_trace(e, grad, 0.01, 0.5),
                               jnp.zeros(2))
    np.testing.assert_allclose(steady, 0.5 * grad, rtol=1e-4)   # kappa * grad
    np.testing.assert_allclose(ac.update_weights(jnp.ones(2), 2.0, trace, 3.0, 0.1),
                               1.0 + 3.0 * 2.0 * trace * 0.1, rtol=1e-6)


def test_td_errors():
    np.testing.assert_allclose(ac.td_error(1.0, 2.0, 1.5, 0.1, 1.0), 1.0 - 2.0 + 5.0, rtol=1e-6)
    # Doya's form r + [(1 - dt/tau) V(t) - V(t - dt)] / dt, tau != 1
    np.testing.assert_allclose(ac.td_error(0.3, 2.0, 1.5, 0.1, 0.5),
                               0.3 + ((1 - 0.2) * 2.0 - 1.5) / 0.1, rtol=1e-6)
    # at a fall the value is 0
    np.testing.assert_allclose(ac.terminal_td_error(-1.0, 0.8, 0.1, impulse=False), -1.8, rtol=1e-6)
    # as an impulse, delta dt over the fall's period is r_fall - V(t - dt)
    np.testing.assert_allclose(ac.terminal_td_error(-1.0, 0.8, 0.1, impulse=True) * 0.1, -1.8, rtol=1e-6)


def test_learner_update_rates_and_safeguards():
    weights = ac.init_weights(PRINTED, NUM_BASIS)
    assert weights.sigma.shape == () and weights.critic.dtype == jnp.float32
    traces = ac.Traces(critic=jnp.ones(NUM_BASIS), mean=jnp.ones(NUM_BASIS),
                       sigma=jnp.float32(1.0))
    params = ac.LearnerParams(rate_scale=0.1, w_sigma_bounds=None)
    new = ac.learner_update(params, weights, traces, jnp.float32(100.0), 0.01)
    np.testing.assert_allclose(new.critic, 7.8, rtol=1e-5)
    np.testing.assert_allclose(new.mean, 19.5, rtol=1e-5)
    np.testing.assert_allclose(new.sigma, 19.5, rtol=1e-5)
    guarded = ac.LearnerParams(rate_scale=0.1, max_abs_td_error=10.0, w_sigma_bounds=(-3.0, 1.0))
    new = ac.learner_update(guarded, weights, traces, jnp.float32(100.0), 0.01)
    np.testing.assert_allclose(new.critic, 0.78, rtol=1e-5)
    np.testing.assert_allclose(new.sigma, 1.0, rtol=1e-6)
    # a fall as an impulse: its delta is (r - V) / dt, and the clip scales with it, so a fall's
    # delta of -1.8 / 0.01 = -180 passes a clip of 10 / 0.01 = 1000 whole: 7.8 x -1.8 x 0.1 ...
    impulse = ac.LearnerParams(rate_scale=0.1, max_abs_td_error=10.0, fall_impulse=True, w_sigma_bounds=None)
    fall = ac.terminal_td_error(-1.0, 0.8, 0.01, impulse=True)
    new = ac.learner_update(impulse, weights, traces, fall, 0.01, at_fall=True)
    np.testing.assert_allclose(new.critic, 78 * 0.1 * -180 * 0.01, rtol=1e-5)   # alpha x scale x delta x dt
    # ... while the same delta outside a fall is clipped at 10
    new = ac.learner_update(impulse, weights, traces, fall, 0.01, at_fall=False)
    np.testing.assert_allclose(new.critic, 78 * 0.1 * -10 * 0.01, rtol=1e-5)


def test_mean_step_sigma_power_scales_the_printed_gradient_by_sigma_over_sigma_0():
    """One trace step from zero is dt x grad.  As printed, d ln pi / d w^mu = (v - mu) / sigma^2 b;
    at power 2, (v - mu) / sigma_0^2 b, sigma_0 = sigmoid(init_w_sigma); at power 1, (v - mu) /
    (sigma sigma_0) b: at v - mu = 0.3, sigma = 0.2 and sigma_0 = sigmoid(-1) = 0.2689, the
    printed factor is 0.3 / 0.04 = 7.5, at power 2 0.3 / 0.07233 = 4.148 and at power 1
    0.3 / 0.05379 = 5.578; sigma's own trace is unchanged."""
    b = jnp.array([0.25, 0.75])
    v, mean, std, dt = jnp.float32(0.8), jnp.float32(0.5), jnp.float32(0.2), 0.01
    printed = ac.LearnerParams(init_w_sigma=-1.0)
    scaled = ac.LearnerParams(init_w_sigma=-1.0, mean_step_sigma_power=2.0)
    linear = ac.LearnerParams(init_w_sigma=-1.0, mean_step_sigma_power=1.0)
    sigma_0 = 1.0 / (1.0 + math.exp(1.0))
    zero = ac.init_traces(2)
    as_printed = ac.accumulate_traces(printed, zero, b, v, mean, std, dt)
    as_scaled = ac.accumulate_traces(scaled, zero, b, v, mean, std, dt)
    np.testing.assert_allclose(as_printed.mean, dt * 7.5 * b, rtol=1e-5)
    np.testing.assert_allclose(as_scaled.mean, dt * 0.3 / sigma_0**2 * b, rtol=1e-5)
    np.testing.assert_allclose(ac.accumulate_traces(linear, zero, b, v, mean, std, dt).mean,
                               dt * 0.3 / (0.2 * sigma_0) * b, rtol=1e-5)
    np.testing.assert_allclose(as_scaled.sigma, as_printed.sigma, rtol=1e-6)
    # at sigma = sigma_0 the two agree: the first steps are the printed ones
    std_0 = jnp.float32(sigma_0)
    at_start = ac.accumulate_traces(scaled, zero, b, v, mean, std_0, dt)
    printed_at_start = ac.accumulate_traces(printed, zero, b, v, mean, std_0, dt)
    np.testing.assert_allclose(at_start.mean, printed_at_start.mean, rtol=1e-5)


def _critic_step(params, dt, weights, traces, b, b_prev, reward, noise, cached_value=None):
    """One control step in the order of the module docstring; returns new state and V."""
    value = ngnet.ngnet_value(weights.critic, b)
    previous = (ngnet.ngnet_value(weights.critic, b_prev) if cached_value is None
                else cached_value)
    delta = ac.td_error(reward, value, previous, dt, params.tau)
    weights = ac.learner_update(params, weights, traces, delta, dt)
    mean, std = ngnet.ngnet_value(weights.mean, b), ngnet.policy_std(weights.sigma)
    v = policy.sample_action(mean, std, noise)
    traces = ac.accumulate_traces(params, traces, b, v, mean, std, dt)
    return weights, traces, value


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _stationary_values(params, dt, steps, cached, x, reward, key):
    """V(x) along ``steps`` control steps on a constant input with a constant reward."""
    b = ngnet.normalized_basis(BASIS, x)

    def step(carry, noise):
        weights, traces, last_value = carry
        weights, traces, value = _critic_step(params, dt, weights, traces, b, b, reward, noise,
                                              last_value if cached else None)
        return (weights, traces, value), value

    init = (ac.init_weights(params, NUM_BASIS), ac.init_traces(NUM_BASIS), jnp.float32(0.0))
    _, values = jax.lax.scan(step, init, jax.random.normal(key, (steps,)))
    return values


def test_critic_converges_to_r_tau_on_a_stationary_input():
    xs = jnp.array([[0.0, 0.0], [0.3, -0.5], [1.9, 1.1], [3.0, -2.5]])
    rewards = jnp.array([1.0, -0.5, 2.0, 0.7])
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    run = jax.vmap(lambda x, r, k: _stationary_values(PRINTED, 0.008, 1250, False, x, r, k))
    values = np.asarray(run(xs, rewards, keys))
    assert np.all(np.isfinite(values))
    np.testing.assert_allclose(values[:, -1], np.asarray(rewards) * PRINTED.tau, rtol=0.02)


def test_cached_previous_value_diverges_at_printed_rates():
    """Why td_error takes V(t - dt) under the current weights (module docstring)."""
    key = jax.random.PRNGKey(0)
    x, reward = jnp.array([0.3, -0.5]), jnp.float32(1.0)
    diverged = _stationary_values(PRINTED, 0.008, 400, True, x, reward, key)
    assert not np.all(np.abs(np.asarray(diverged)) < 10.0)
    scaled = ac.LearnerParams(rate_scale=0.1, w_sigma_bounds=None)
    values = _stationary_values(scaled, 0.008, 2000, True, x, reward, key)
    np.testing.assert_allclose(values[-1], 1.0, rtol=0.02)


@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def _critic_on_a_cycle(params, dt, steps, omega, radius):
    """Learn V on x(t) = radius (cos wt, sin wt) with r(t) = cos wt; return V over a cycle."""

    def point(t):
        return radius * jnp.stack([jnp.cos(omega * t), jnp.sin(omega * t)])

    def step(carry, n):
        weights, traces, b_prev = carry
        t = n * dt
        b = ngnet.normalized_basis(BASIS, point(t))
        weights, traces, _ = _critic_step(params, dt, weights, traces, b, b_prev,
                                          jnp.cos(omega * t), jnp.float32(0.0))
        return (weights, traces, b), None

    init = (ac.init_weights(params, NUM_BASIS), ac.init_traces(NUM_BASIS),
            ngnet.normalized_basis(BASIS, point(0.0)))
    (weights, _, _), _ = jax.lax.scan(step, init, jnp.arange(steps))
    phases = jnp.linspace(0.0, 2 * jnp.pi, 64, endpoint=False)
    values = jax.vmap(lambda p: ngnet.ngnet_value(
        weights.critic, ngnet.normalized_basis(BASIS, point(p / omega))))(phases)
    return phases, values


def test_critic_learns_the_value_of_a_periodic_process():
    """V(t) = int_0^inf e^{-s/tau} cos(w (t + s)) ds = (cos(wt)/tau - w sin(wt)) / (1/tau^2 + w^2)."""
    omega, tau = math.pi, PRINTED.tau
    phases, values = _critic_on_a_cycle(PRINTED, 0.008, 4000, omega, 1.5)
    exact = (np.cos(phases) / tau - omega * np.sin(phases)) / (1 / tau**2 + omega**2)
    amplitude = np.max(np.abs(exact))
    assert np.max(np.abs(np.asarray(values) - exact)) < 0.05 * amplitude


# A tiny control problem: dx/dt = a - x, r = -(x - 1)^2, x fed to the NGnet as (x, 0).
TOY = ac.LearnerParams(a_max=2.0, rate_scale=0.02)
TOY_DT, TOY_STEPS, TOY_EPISODES, TOY_LEARNERS = 0.02, 200, 40, 8


def _toy_episode(weights, key):
    start_key, noise_key = jax.random.split(key)
    x0 = jax.random.uniform(start_key, (), minval=-1.0, maxval=1.0)

    def step(carry, noise):
        weights, traces, x, b_prev = carry
        b = ngnet.normalized_basis(BASIS, jnp.stack([x, 0.0]))
        reward = -((x - 1.0) ** 2)
        value = ngnet.ngnet_value(weights.critic, b)
        previous = ngnet.ngnet_value(weights.critic, b_prev)
        delta = ac.td_error(reward, value, previous, TOY_DT, TOY.tau)
        weights = ac.learner_update(TOY, weights, traces, delta, TOY_DT)
        mean, std = ngnet.ngnet_value(weights.mean, b), ngnet.policy_std(weights.sigma)
        v = policy.sample_action(mean, std, noise)
        traces = ac.accumulate_traces(TOY, traces, b, v, mean, std, TOY_DT)
        x = x + TOY_DT * (policy.feedback_action(v, TOY.a_max) - x)
        return (weights, traces, x, b), reward

    init = (weights, ac.init_traces(NUM_BASIS), x0,
            ngnet.normalized_basis(BASIS, jnp.stack([x0, 0.0])))
    (weights, _, _, _), rewards = jax.lax.scan(
        step, init, jax.random.normal(noise_key, (TOY_STEPS,)))
    return weights, jnp.sum(rewards) * TOY_DT


@jax.jit
def _toy_learners(keys):
    def learner(key):
        weights = ac.init_weights(TOY, NUM_BASIS)
        return jax.lax.scan(_toy_episode, weights, jax.random.split(key, TOY_EPISODES))

    return jax.vmap(learner)(keys)


def test_actor_critic_improves_a_toy_control_problem():
    weights, returns = _toy_learners(jax.random.split(jax.random.PRNGKey(0), TOY_LEARNERS))
    returns = np.asarray(returns)
    assert returns.shape == (TOY_LEARNERS, TOY_EPISODES) and np.all(np.isfinite(returns))
    initial, final = returns[:, :5].mean(), returns[:, -5:].mean()
    # mu = 0 keeps x near 0: return about -4 over 4 s; the optimum is about -0.5
    assert final > initial + 1.5, (initial, final)
    assert np.mean(returns[:, -5:].mean(axis=1) > returns[:, :5].mean(axis=1)) >= 0.75
    b0 = ngnet.normalized_basis(BASIS, jnp.zeros(2))
    mean_at_zero = np.asarray(jax.vmap(lambda w: ngnet.ngnet_value(w, b0))(weights.mean))
    # the target x = 1 needs a = 1, i.e. v = 2/pi ~ 0.64: the mean at x = 0 pushes up
    assert np.median(mean_at_zero) > 0.3, mean_at_zero
    assert np.mean(mean_at_zero > 0.0) >= 0.75, mean_at_zero


def test_policy_std_weight_inverts_eq_26():
    """w^sigma = log(sigma / (1 - sigma)): log(0.25) at sigma 0.2, 0 at 0.5, and the sigmoid of
    eq (26) gives sigma back."""
    assert ngnet.policy_std_weight(0.2) == pytest.approx(math.log(0.25))
    assert ngnet.policy_std_weight(0.5) == 0.0
    for s in (1e-6, 0.3, 0.9):
        # float32 w^sigma of up to 14 in size: a relative 1e-7 of it moves sigma by 2e-6 at most
        assert float(ngnet.policy_std(jnp.float32(ngnet.policy_std_weight(s)))) == pytest.approx(s, rel=1e-5)
