"""Stochastic Gaussian policy for the learned feedback a_5 (eqs 10-12 of Endo et al. 2005).

The policy draws an unbounded v ~ N(mu(x; w^mu), sigma(w^sigma)^2) (eqs 11-12) and
squashes it into the feedback a = a_max g(v) (eq 10).  The likelihood ratio, and hence
every gradient here, is that of v, not of a.  mu is the NGnet of eq (25) and sigma the
sigmoid of eq (26) (see ``mjxcpg.ngnet``).  Pure JAX for one learner; ``vmap`` over
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


def feedback_action(v: jax.Array, a_max: float) -> jax.Array:
    """Eq (10): a_j = a_j^max g(v_j)."""
    return a_max * squash(v)


def sample_action(mean: jax.Array, std: jax.Array, noise: jax.Array) -> jax.Array:
    """Eq (12): v = mu(x; w^mu) + sigma(w^sigma) n, with n ~ N(0, 1) given as ``noise``."""
    return mean + std * noise


def log_policy(v: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    """Eq (11), log: ln pi = -ln(sqrt(2 pi) sigma) - (v - mu)^2 / (2 sigma^2)."""
    return -_LOG_SQRT_2PI - jnp.log(std) - 0.5 * ((v - mean) / std) ** 2


def log_policy_gradients(v: jax.Array, mean: jax.Array, std: jax.Array,
                         b: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Eq (21)'s d ln pi / dw for eq (11) with mu = w^mu . b (eq 25), sigma = sigmoid(w^sigma) (eq 26).

    Returns ``(d ln pi / d w^mu, d ln pi / d w^sigma)`` of shapes (K,) and ():

    * d ln pi / d w^mu_k = (v - mu) / sigma^2 * b_k;
    * d ln pi / d w^sigma = ((v - mu)^2 - sigma^2) / sigma^3 * sigma (1 - sigma),
      the last factor being d sigma / d w^sigma of the sigmoid.
    """
    error = v - mean
    grad_mean = (error / std**2) * b
    grad_sigma = (error**2 - std**2) / std**3 * std * (1.0 - std)
    return grad_mean, grad_sigma
