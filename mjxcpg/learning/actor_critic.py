"""Continuous-time TD actor-critic (eqs 15-22 of Endo et al. 2005, after Doya 2000).

The critic V(x; w^c) (eq 23) and the policy mean mu(x; w^mu) (eq 25) are NGnets on one
basis b(x); the policy std is sigma = sigmoid(w^sigma) (eq 26).  The continuous-time laws
are discretised with the control period dt:

* TD error, eq (17), backward Euler as in Doya (2000):
  delta(t) = r(t) - V(t) / tau + (V(t) - V(t - dt)) / dt
           = r(t) + [(1 - dt / tau) V(t) - V(t - dt)] / dt,
  with V(t) = V(x(t); w) and V(t - dt) = V(x(t - dt); w) evaluated with the *same, current*
  critic weights (keep the previous basis vector b(t - dt), not the previous value).
  If V(t - dt) is instead cached from the last step, under the weights of the last step,
  the learning step itself leaks into dV/dt: on a stationary input
  delta_n = r - V_n / tau + g delta_{n-1} with g = alpha (e . b) ~ alpha kappa_c |b|^2,
  which diverges for g > 1.  At the paper's alpha = 78, kappa_c = 0.5 and |b|^2 ~ 0.16
  (15 x 15 grid, width = spacing) g ~ 6; scaled by 0.1, g ~ 0.6.  This explains why an
  early prototype that cached V(t - dt) diverged at the printed rates and learned at 0.1 x
  them; with the current-weights form the printed rates are stable
  (tests/test_learning_math.py).
* Eligibility traces, eqs (18) and (21): e <- (1 - dt / kappa) e + dt * grad, the explicit
  Euler step with Doya's (1 - dt / kappa) factor; a contraction for 0 < dt < kappa, with the
  steady state kappa * grad under a constant gradient.
* Weights, eqs (19) and (22): w <- w + rate * delta * e * dt.

Order within control step n (what the tests do, and what a trial loop should do):
observe x_n and r_n (the reward over (t_{n-1}, t_n]); b_n = b(x_n); delta_n from
V(x_n; w) and V(x_{n-1}; w); ``learner_update`` with the traces as they were after step
n - 1 (they hold the gradients of V(x_{n-1}) and of the action v_{n-1}, whose consequence
delta_n measures); then sample v_n and ``accumulate_traces`` with b_n and v_n.  At the
start of a trial the traces are zero, so the first update is a no-op whatever delta is.

Pure JAX in float32 for one learner; ``vmap`` over learners (``LearnerParams`` is static).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxcpg.learning.ngnet import policy_std
from mjxcpg.learning.policy import feedback_action, log_policy_gradients, noise_decay


@dataclasses.dataclass(frozen=True)
class LearnerParams:
    """Learning constants; defaults are the paper's (Learning ... sections).

    ``rate_scale`` multiplies alpha, beta_mu and beta_sigma.  An early prototype (with a value
    cached from the previous step in the TD error, see the module docstring) diverged at the
    printed rates and learned with 0.1.  On our robot (k_s = 10, seeds 0-2,
    8 ms control period, ``docs/learning.md``) the printed rates drove |w^mu| to 1e4 and
    sigma to 1 within 300 trials (one seed of three succeeded, with a bang-bang policy);
    0.1 sent one seed to NaN through sigma -> 0; 0.03 with sigma kept in
    [sigmoid(-2), sigmoid(2)] = [0.12, 0.88] succeeded at trials 42 and 53 on two seeds.
    Those are the defaults.

    Safeguards: ``max_abs_td_error`` (off by default) clips |delta| before the updates of
    eqs (19) and (22) (scaled by 1/dt at a fall with ``fall_impulse``, as delta is there);
    ``w_sigma_bounds`` = (low, high) clips w^sigma after each update, which bounds sigma of
    eq (26) away from 0 and 1 (``None`` turns it off).
    """

    tau: float = 1.0            # discount time constant of eq (15)
    alpha: float = 78.0         # critic learning rate, eq (19)
    kappa_c: float = 0.5        # critic trace time constant, eq (18)
    beta_mu: float = 195.0      # policy-mean learning rate, eq (22)
    beta_sigma: float = 195.0   # policy-std learning rate, eq (22)
    kappa_mu: float = 1.0       # policy-mean trace time constant, eq (21)
    kappa_sigma: float = 0.1    # policy-std trace time constant, eq (21)
    a_max: float = 1.0          # feedback amplitude of eq (10) (not given in the paper)
    unit_slope: bool = False    # a_5 = a_max g(v / a_max) rather than eq (10)'s a_max g(v)
    noise_correlation_s: float = 0.0  # tau_n of the exploration noise; 0: white, as eq (12)
    rate_scale: float = 0.03    # multiplies alpha, beta_mu, beta_sigma (see above)
    init_w_sigma: float = 0.0   # initial w^sigma: sigma = 0.5
    max_abs_td_error: float | None = None
    # The fall's TD error as the integral of an impulse over its period (see
    # ``terminal_td_error``): delta = (r_fall - V(t - dt)) / dt instead of r_fall - V(t - dt).
    fall_impulse: bool = False
    # p of the factor (sigma / sigma_0)^p on d ln pi / d w^mu, sigma_0 the initial sigma (see
    # ``mean_gradient_scale``): 0 as printed; 2 makes the mean's steps shrink with the
    # exploration instead of growing as 1 / sigma.
    mean_step_sigma_power: float = 0.0
    w_sigma_bounds: tuple[float, float] | None = (-2.0, 2.0)
    # Bound of a second policy output, the learned stepping feedback added to eq (9)'s a_1
    # (``controller.control_step``); 0: the paper's policy, a_5 alone.
    stepping_a_max: float = 0.0

    @property
    def v_scale(self) -> float:
        """The divisor of v inside eq (10)'s g (see ``policy.feedback_action``)."""
        return self.a_max if self.unit_slope else 1.0

    @property
    def outputs(self) -> int:
        """The policy's outputs: 1 (a_5), or 2 (a_5 and the learned stepping feedback)."""
        return 2 if self.stepping_a_max > 0 else 1

    def action(self, v: jax.Array) -> jax.Array:
        """Eq (10) for every output of v (shape () or (2,)): a_j = a_j^max g(v_j / scale_j),
        a_5 with ``a_max`` and ``v_scale``, the stepping feedback alike with ``stepping_a_max``."""
        if self.outputs == 1:
            return feedback_action(v, self.a_max, self.v_scale)
        maxima = jnp.array([self.a_max, self.stepping_a_max], jnp.float32)
        return feedback_action(v, maxima, maxima if self.unit_slope else 1.0)

    def propulsive_mean(self, mean: jax.Array) -> jax.Array:
        """a_5's w^mu of a mean of shape (..., K), or (..., 2, K) with two outputs."""
        return mean if self.outputs == 1 else mean[..., 0, :]

    def propulsive_sigma(self, sigma: jax.Array) -> jax.Array:
        """a_5's w^sigma of a sigma of shape (...), or (..., 2) with two outputs."""
        return sigma if self.outputs == 1 else sigma[..., 0]


class Weights(NamedTuple):
    """Learned parameters of one learner.  With a second policy output
    (``LearnerParams.outputs`` = 2) the mean's and sigma's leading axis is the output's."""

    critic: jax.Array  # w^c, shape (K,), eq (23)
    mean: jax.Array    # w^mu, shape (K,) or (2, K), eq (25)
    sigma: jax.Array   # w^sigma, shape () or (2,), eq (26): std = sigmoid(w^sigma)


class Traces(NamedTuple):
    """Eligibility traces of ``Weights``, leaf for leaf."""

    critic: jax.Array  # e^c, shape (K,), eq (18)
    mean: jax.Array    # e^mu, shape (K,) or (2, K), eq (21)
    sigma: jax.Array   # e^sigma, shape () or (2,), eq (21)


def output_shape(outputs: int) -> tuple[int, ...]:
    """The shape of a per-output value (an action, its noise, w^sigma): () for one output."""
    return () if outputs == 1 else (outputs,)


def init_weights(params: LearnerParams, num_basis: int) -> Weights:
    """Zero critic and mean (V = 0, mu = 0); w^sigma = ``params.init_w_sigma``."""
    zeros = jnp.zeros(num_basis, jnp.float32)
    shape = output_shape(params.outputs)
    return Weights(critic=zeros, mean=jnp.zeros(shape + (num_basis,), jnp.float32),
                   sigma=jnp.full(shape, params.init_w_sigma, jnp.float32))


def init_traces(num_basis: int, outputs: int = 1) -> Traces:
    """All traces zero, as at the start of every trial."""
    shape = output_shape(outputs)
    return Traces(critic=jnp.zeros(num_basis, jnp.float32),
                  mean=jnp.zeros(shape + (num_basis,), jnp.float32), sigma=jnp.zeros(shape, jnp.float32))


def td_error(reward: jax.Array, value: jax.Array, previous_value: jax.Array,
             dt: float, tau: float) -> jax.Array:
    """Eq (17), backward Euler (Doya 2000): delta = r - V(t) / tau + (V(t) - V(t - dt)) / dt.

    Equivalently r(t) + [(1 - dt / tau) V(t) - V(t - dt)] / dt.  ``value`` is
    V(x(t); w^c), ``previous_value`` is V(x(t - dt); w^c) with the same current weights
    (see the module docstring for why not the value cached from the previous step).
    """
    return reward - value / tau + (value - previous_value) / dt


def terminal_td_error(fall_reward: jax.Array, previous_value: jax.Array, dt: float,
                      impulse: bool) -> jax.Array:
    """Eq (17) at a fall, Doya's (2000) terminal condition: the value just before the fall
    should equal the fall's reward (the paper's r = -1, a one-off punishment, not a rate),
    with nothing after it.

    ``impulse=False``: delta = r_fall - V(t - dt), entering eqs (19) and (22) like any
    period's delta, times dt.  ``impulse=True``: delta = (r_fall - V(t - dt)) / dt, so that
    delta dt over the fall's period is the integral of eq (17)'s delta across a reward
    impulse of r_fall and the value's jump to 0: the update of a continuous-time learner.
    The first form makes a fall 1/dt = 125 times weaker at an 8 ms period.
    """
    delta = fall_reward - previous_value
    return delta / dt if impulse else delta


def decay_trace(trace: jax.Array, grad: jax.Array, dt: float, kappa: float) -> jax.Array:
    """Eqs (18) and (21), explicit Euler: e <- (1 - dt / kappa) e + dt * grad.

    de/dt = -e / kappa + grad, stepped with Doya's (1 - dt / kappa) factor; stable (a
    contraction with a non-negative factor) for dt < kappa, e.g. dt = 8 ms against the
    smallest time constant kappa_sigma = 0.1 s.
    """
    return (1.0 - dt / kappa) * trace + dt * grad


def update_weights(weights: jax.Array, delta: jax.Array, trace: jax.Array, rate: float,
                   dt: float) -> jax.Array:
    """Eqs (19) and (22), explicit Euler: w <- w + rate * delta * e * dt."""
    return weights + rate * delta * trace * dt


def learner_update(params: LearnerParams, weights: Weights, traces: Traces,
                   delta: jax.Array, dt: float, at_fall: jax.Array | bool = False) -> Weights:
    """Eq (19) for w^c (rate alpha) and eq (22) for w^mu, w^sigma (rates beta_mu, beta_sigma).

    Every rate is multiplied by ``params.rate_scale``; the optional safeguards of
    ``LearnerParams`` (``max_abs_td_error``, ``w_sigma_bounds``) apply here.  ``at_fall``
    with ``params.fall_impulse`` scales the clip by 1/dt, as the impulse scales delta.
    """
    if params.max_abs_td_error is not None:
        bound = params.max_abs_td_error
        if params.fall_impulse:
            bound = jnp.where(at_fall, bound / dt, bound)
        delta = jnp.clip(delta, -bound, bound)
    scale = params.rate_scale
    w_sigma = update_weights(weights.sigma, delta, traces.sigma, scale * params.beta_sigma, dt)
    if params.w_sigma_bounds is not None:
        w_sigma = jnp.clip(w_sigma, *params.w_sigma_bounds)
    return Weights(
        critic=update_weights(weights.critic, delta, traces.critic, scale * params.alpha, dt),
        mean=update_weights(weights.mean, delta, traces.mean, scale * params.beta_mu, dt),
        sigma=w_sigma,
    )


def mean_gradient_scale(params: LearnerParams, std: jax.Array) -> jax.Array:
    """The factor (sigma / sigma_0)^p on eq (21)'s d ln pi / d w^mu, p =
    ``params.mean_step_sigma_power`` and sigma_0 eq (26) at ``params.init_w_sigma``: exactly 1
    as printed (p = 0).

    As printed, the gradient (v - mu) / sigma^2 b = n / sigma b grows as sigma shrinks, so
    the mean's steps grow as exploration ends.  sigma^2 is the inverse of the Fisher
    information of the Gaussian's mean: at p = 2 the gradient (v - mu) / sigma_0^2 b = n sigma /
    sigma_0^2 b has the natural gradient's dependence on sigma; at p = 1, n / sigma_0 b, the
    steps do not depend on sigma.  Normalised so that the first steps, at sigma_0, are the
    printed ones.  With correlated noise the gradient, xi / (sigma s) (b_t - a b_{t-1}), is
    1 / sigma times the same kind of factor, and is scaled alike.
    """
    return (std / policy_std(params.init_w_sigma)) ** params.mean_step_sigma_power


def accumulate_traces(params: LearnerParams, traces: Traces, b: jax.Array, v: jax.Array,
                      mean: jax.Array, std: jax.Array, dt: float,
                      previous_noise: jax.Array | float = 0.0,
                      previous_b: jax.Array | None = None) -> Traces:
    """Eq (18) with dV/dw^c = b (eq 23) and eq (21) with the gradients of ln pi (eq 11).

    ``b`` is the basis at the current input, ``v`` the sample drawn there (eq 12) as
    mean + std n with mean = w^mu . b, std = sigmoid(w^sigma) and n the exploration noise;
    with correlated noise (``params.noise_correlation_s`` > 0) the gradient also needs the
    last period's noise n_{t-1} and basis b_{t-1} (``policy.log_policy_gradients``).
    With two outputs, ``v``, ``mean``, ``std`` and the noise have shape (2,): the outputs are
    independent Gaussians, so ln pi is the sum of theirs and each output's traces take its own
    gradient.
    """
    decay = noise_decay(params.noise_correlation_s, dt)
    grad_mean, grad_sigma = log_policy_gradients(v, mean, std, b, decay, previous_noise, previous_b)
    grad_mean = mean_gradient_scale(params, std)[..., None] * grad_mean
    return Traces(
        critic=decay_trace(traces.critic, b, dt, params.kappa_c),
        mean=decay_trace(traces.mean, grad_mean, dt, params.kappa_mu),
        sigma=decay_trace(traces.sigma, grad_sigma, dt, params.kappa_sigma),
    )
