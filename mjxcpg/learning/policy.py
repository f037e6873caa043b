"""Stochastic Gaussian policy for the learned feedback a_5 (eqs 10-12 of Endo et al. 2005).

The policy draws an unbounded v ~ N(mu(x; w^mu), sigma(w^sigma)^2) (eqs 11-12) and
squashes it into the feedback a = a_max g(v) (eq 10).  The likelihood ratio, and hence
every gradient here, is that of v, not of a.  mu is the NGnet of eq (25) and sigma the
sigmoid of eq (26) (see ``mjxcpg.learning.ngnet``).  Pure JAX for one learner; ``vmap`` over
learners.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def squash(v: jax.Array) -> jax.Array:
    """Eq (10)'s g(x) = (2 / pi) arctan(pi x / 2): slope 1 at 0, range (-1, 1)."""
    return (2.0 / jnp.pi) * jnp.arctan(0.5 * jnp.pi * v)


def feedback_action(v: jax.Array, a_max: float, v_scale: float = 1.0) -> jax.Array:
    """Eq (10): a_j = a_j^max g(v_j / v_scale).

    ``v_scale`` = 1 is the printed form.  ``v_scale`` = a_max keeps the slope at 0 at 1 for
    every a_max, so a larger a_max raises the ceiling without amplifying the exploration
    noise or the mean's steps near 0."""
    return a_max * squash(v / v_scale)


def sample_action(mean: jax.Array, std: jax.Array, noise: jax.Array) -> jax.Array:
    """Eq (12): v = mu(x; w^mu) + sigma(w^sigma) n, with n ~ N(0, 1) given as ``noise``."""
    return mean + std * noise


def log_policy(v: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    """Eq (11), log: ln pi = -ln(sqrt(2 pi) sigma) - (v - mu)^2 / (2 sigma^2)."""
    return -_LOG_SQRT_2PI - jnp.log(std) - 0.5 * ((v - mean) / std) ** 2


def noise_decay(correlation_s: float, dt: float) -> float:
    """The per-period factor a = exp(-dt / tau_n) of ``exploration_noise``; 0 (white noise,
    as eq 12 prints) when ``correlation_s`` is 0."""
    return math.exp(-dt / correlation_s) if correlation_s > 0 else 0.0


def exploration_noise(previous: jax.Array, innovation: jax.Array, decay: float) -> jax.Array:
    """Eq (12)'s n(t), optionally correlated in time: n_t = a n_{t-1} + sqrt(1 - a^2) xi_t with
    xi_t ~ N(0, 1), an AR(1) process (an Ornstein-Uhlenbeck process with time constant tau_n
    sampled every dt) whose variance settles at 1 within a few tau_n of n = 0, where every
    trial starts it.  a = 0 gives the paper's white noise n_t = xi_t.

    White noise redrawn every control period is low-passed by the CPG (tau = 0.1 s), so most
    of it never reaches the legs; noise held over a fraction of a step does.
    """
    return decay * previous + math.sqrt(1.0 - decay**2) * innovation


def log_policy_gradients(v: jax.Array, mean: jax.Array, std: jax.Array, b: jax.Array,
                         decay: float = 0.0, previous_noise: jax.Array | float = 0.0,
                         previous_b: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Eq (21)'s d ln pi / dw for eq (11) with mu = w^mu . b (eq 25), sigma = sigmoid(w^sigma) (eq 26).

    Returns ``(d ln pi / d w^mu, d ln pi / d w^sigma)`` of shapes (K,) and (), or (M, K) and
    (M,) for M independent outputs (``v``, ``mean``, ``std`` of shape (M,)).  With white
    noise (``decay`` = 0):

    * d ln pi / d w^mu_k = (v - mu) / sigma^2 * b_k;
    * d ln pi / d w^sigma = ((v - mu)^2 - sigma^2) / sigma^3 * sigma (1 - sigma),
      the last factor being d sigma / d w^sigma of the sigmoid.

    With ``exploration_noise``'s AR(1) noise the action is Gaussian given the past:
    v_t ~ N(mu_t + a (v_{t-1} - mu_{t-1}), (sigma s)^2), s = sqrt(1 - a^2), and this is the
    gradient of that density's log, with xi = (n_t - a n_{t-1}) / s the innovation, n = (v - mu)
    / sigma the noise (``previous_noise`` is n_{t-1}) and ``previous_b`` = b(x_{t-1}):

    * d ln pi / d w^mu = xi / (sigma s) * (b_t - a b_{t-1});
    * d ln pi / d w^sigma = (xi^2 - 1) / sigma * sigma (1 - sigma).

    At a = 0 both reduce to the white-noise forms above.  ``previous_b`` None (the first
    action of a trial, where n_{t-1} = 0) counts as b_{t-1} = 0.
    """
    scale = math.sqrt(1.0 - decay**2)
    innovation = ((v - mean) / std - decay * previous_noise) / scale
    basis_gradient = b if previous_b is None else b - decay * previous_b
    grad_mean = (innovation / (std * scale))[..., None] * basis_gradient
    grad_sigma = (innovation**2 - 1.0) / std * std * (1.0 - std)
    return grad_mean, grad_sigma
