"""Matsuoka central pattern generator (eqs 1-8 of Endo et al. 2005).

Six neurons: 1-2 form the stepping oscillator (leg length, Z), 3-6 the quad-element
oscillator whose (q5 - q6) drives the legs fore and aft (X).  Everything here is pure JAX
for one robot; ``vmap`` it over a batch.

Corrections to the printed equations:

* eq (1) carries the neuron index i throughout: tau dz_i/dt = -z_i - sum_j w_ij q_j
  - gamma z'_i + c + a_i;
* eq (2) as printed (-z_j + q_j) does not oscillate; Matsuoka (1985) has
  tau' dz'_i/dt = -z'_i + q_i, which is what ``adaptation_rate`` implements.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.robots.qrio import QRIO


def _inhibition_matrix() -> np.ndarray:
    """w[i, j]: inhibitory weight from neuron j to neuron i (1-based in the paper)."""
    w = np.zeros((6, 6))
    for i, j, value in [
        (1, 2, 2.0), (2, 1, 2.0),                              # stepping pair
        (3, 4, 2.0), (4, 3, 2.0), (5, 6, 2.0), (6, 5, 2.0),    # quad element, pairs
        (3, 5, 0.5), (6, 3, 0.5), (4, 6, 0.5), (5, 4, 0.5),    # quad element, circular
    ]:
        w[i - 1, j - 1] = value
    return w


@dataclasses.dataclass(frozen=True)
class CPGParams:
    """Oscillator constants; defaults are the paper's (Velocity Control section), the time
    constants through QRIO's description (``mjxcpg.robots``), which scales them to other robots."""

    tau: float = QRIO.gait.tau
    tau_adapt: float = QRIO.gait.tau_adapt
    bias: float = 2.08
    adaptation: float = 2.5
    weights: tuple[tuple[float, ...], ...] = tuple(map(tuple, _inhibition_matrix()))


class CPGState(NamedTuple):
    z: jax.Array        # membrane states z_i, shape (6,)
    z_adapt: jax.Array  # adaptation states z'_i, shape (6,)


def init_state(params: CPGParams | None = None) -> CPGState:
    """A small asymmetric start, so that the symmetric fixed point is left at once."""
    del params
    z = jnp.array([0.1, 0.0, 0.1, 0.0, 0.0, 0.1])
    return CPGState(z=z, z_adapt=jnp.zeros(6))


def output(state: CPGState) -> jax.Array:
    """Eq (3): q_i = max(0, z_i)."""
    return jnp.maximum(state.z, 0.0)


def membrane_rate(params: CPGParams, state: CPGState, feedback: jax.Array) -> jax.Array:
    """Eq (1): dz_i/dt = (-z_i - sum_j w_ij q_j - gamma z'_i + c + a_i) / tau."""
    w = jnp.asarray(params.weights, dtype=state.z.dtype)
    # The 6 x 6 coupling as a product and a sum rather than a matrix product, which XLA:CPU
    # sends to a library call that costs more than the whole rest of a CPG step.
    coupling = jnp.sum(w * output(state), axis=-1)
    drive = -state.z - coupling - params.adaptation * state.z_adapt
    return (drive + params.bias + feedback) / params.tau


def adaptation_rate(params: CPGParams, state: CPGState) -> jax.Array:
    """Eq (2), corrected after Matsuoka (1985): dz'_i/dt = (-z'_i + q_i) / tau'."""
    return (-state.z_adapt + output(state)) / params.tau_adapt


def step(params: CPGParams, state: CPGState, feedback: jax.Array, dt: float) -> CPGState:
    """Advance eqs (1)-(2) by one explicit Euler step of ``dt`` seconds.

    ``feedback`` is the 6-vector a of eq (1); build it with ``feedback_vector``.
    """
    feedback = jnp.asarray(feedback, dtype=state.z.dtype)
    dz = membrane_rate(params, state, feedback)
    dz_adapt = adaptation_rate(params, state)
    return CPGState(z=state.z + dt * dz, z_adapt=state.z_adapt + dt * dz_adapt)


def integrate(params: CPGParams, state: CPGState, feedback: jax.Array, dt: float,
              substeps: int) -> CPGState:
    """``substeps`` Euler steps of ``dt / substeps`` under a constant feedback."""
    h = dt / substeps
    return jax.lax.fori_loop(0, substeps, lambda _, s: step(params, s, feedback, h), state)


def feedback_vector(a1: jax.Array, a5: jax.Array) -> jax.Array:
    """Eq (8) with a_3 = a_1: a = (a1, -a1, a1, -a1, a5, -a5)."""
    return jnp.stack([a1, -a1, a1, -a1, a5, -a5])


class LegTargets(NamedTuple):
    """Leg-tip (ankle) targets relative to each hip: x forward, z = leg length (down)."""

    left_x: jax.Array
    left_z: jax.Array
    right_x: jax.Array
    right_z: jax.Array


def leg_targets(q: jax.Array, x0: float, z0: float, amp_x: float, amp_z: float) -> LegTargets:
    """Eqs (4)-(7): p_z = Z_0 -/+ A_z (q1 - q2), p_x = X_0 -/+ A_x (q5 - q6)."""
    stepping = q[0] - q[1]
    propulsion = q[4] - q[5]
    return LegTargets(
        left_x=x0 - amp_x * propulsion,
        left_z=z0 - amp_z * stepping,
        right_x=x0 + amp_x * propulsion,
        right_z=z0 + amp_z * stepping,
    )
