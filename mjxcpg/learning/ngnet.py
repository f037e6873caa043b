"""Normalised Gaussian network (eqs 23-26 of Endo et al. 2005, after Doya 2000).

One NGnet basis is shared by the critic V(x; w^c) (eq 23) and the policy mean
mu(x; w^mu) (eq 25); the policy standard deviation is a sigmoid of one scalar (eq 26).
The input x is the pelvis angular velocity (d theta_roll/dt, d theta_pitch/dt).

Everything is pure JAX in float32 for one learner; ``vmap`` over learners with the basis
unbatched (``in_axes=None``).

Correction to the printed equations: eq (24) prints
phi_k = exp(-||s_k^T (x - c_k)||); Doya's (2000) NGnet is a Gaussian, with the norm
*squared*, which is what ``gaussian_activations`` implements.
"""

from __future__ import annotations

import math

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class NGnetBasis(NamedTuple):
    """Centres and inverse widths of the K Gaussians of eq (24)."""

    centers: jax.Array     # c_k, shape (K, 2)
    inv_widths: jax.Array  # s_k, shape (2,): the same diagonal scale for every k


def make_basis(grid: int = 15, low: float = -2.0, high: float = 2.0,
               width_scale: float = 1.0) -> NGnetBasis:
    """The paper's basis: ``grid`` x ``grid`` centres at even intervals over [low, high]^2.

    Centre k = i * grid + j sits at (g_i, g_j), g = linspace(low, high, grid); with the
    defaults, 15 x 15 = 225 centres over [-2, 2]^2 (Numerical Simulation Setup).

    The paper does not give s_k.  We take the Gaussian width equal to the grid spacing,
    s_k = 1 / (spacing * width_scale) in each dimension, so that a neighbouring centre is at
    phi = exp(-1) and the normalised basis interpolates smoothly between centres without
    washing out the resolution of the grid.  ``width_scale`` widens (> 1) or narrows (< 1)
    every Gaussian.
    """
    axis = np.linspace(low, high, grid)
    first, second = np.meshgrid(axis, axis, indexing="ij")
    centers = np.stack([first.ravel(), second.ravel()], axis=-1)
    spacing = (high - low) / (grid - 1)
    inv_widths = np.full(2, 1.0 / (spacing * width_scale))
    return NGnetBasis(centers=jnp.asarray(centers, jnp.float32),
                      inv_widths=jnp.asarray(inv_widths, jnp.float32))


# Inputs are clamped to the grid's box widened by this many widths (s_k^-1) on every side.
# Beyond it the normalised basis no longer changes in float32 (the next row of centres
# weighs less than exp(-2 * 20 - 1) ~ 1e-18 relative to the edge row), and the clamp keeps
# huge or infinite inputs from overflowing the squared distances into inf - inf = NaN.
_CLAMP_MARGIN_WIDTHS = 20.0


def _gaussian_exponents(basis: NGnetBasis, x: jax.Array) -> jax.Array:
    """-||s_k * (x - c_k)||^2 for every k, shape (K,): the log of phi_k in eq (24)."""
    margin = _CLAMP_MARGIN_WIDTHS / basis.inv_widths
    low = jnp.min(basis.centers, axis=0) - margin
    high = jnp.max(basis.centers, axis=0) + margin
    x = jnp.clip(jnp.asarray(x, basis.centers.dtype), low, high)
    scaled = basis.inv_widths * (x - basis.centers)
    return -jnp.sum(scaled**2, axis=-1)


def gaussian_activations(basis: NGnetBasis, x: jax.Array) -> jax.Array:
    """Eq (24), unnormalised: phi_k(x) = exp(-||s_k * (x - c_k)||^2), shape (K,).

    The printed eq (24) lacks the square; Doya (2000), which the paper cites for the
    NGnet, has it, and without it the "Gaussian" is a cone.  Far from the grid every phi_k
    underflows to 0 (finite, never NaN); use ``normalized_basis`` for b_k, which stays
    well defined there.
    """
    return jnp.exp(_gaussian_exponents(basis, x))


def normalized_basis(basis: NGnetBasis, x: jax.Array) -> jax.Array:
    """Eq (24): b_k(x) = phi_k(x) / sum_l phi_l(x), shape (K,), summing to 1.

    Computed in log space (a softmax of the exponents, which subtracts the largest exponent
    before exponentiating), so inputs far outside the grid, where every phi_k underflows,
    give the basis of the nearest centres instead of 0 / 0; inputs more than 20 widths
    outside are clamped to that distance, where b no longer changes in float32.
    """
    return jax.nn.softmax(_gaussian_exponents(basis, x))


def ngnet_value(weights: jax.Array, b: jax.Array) -> jax.Array:
    """Eqs (23) and (25): sum_k w_k b_k(x), the critic V or the policy mean mu."""
    # A product and a sum, which XLA fuses with its neighbours; a dot is a library call.
    return jnp.sum(weights * b, axis=-1)


def policy_std(w_sigma: jax.Array) -> jax.Array:
    """Eq (26): sigma = 1 / (1 + exp(-w^sigma)), the policy's standard deviation.

    The paper calls sigma the "variance" but uses it as the standard deviation in eqs
    (11)-(12); so do we.
    """
    return jax.nn.sigmoid(w_sigma)


def policy_std_weight(std: float) -> float:
    """Eq (26) inverted: the w^sigma = log(sigma / (1 - sigma)) whose sigma is ``std``, in (0, 1)."""
    return math.log(std / (1.0 - std))
