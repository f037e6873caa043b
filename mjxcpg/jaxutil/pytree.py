"""Pytree helpers shared by the engines and the learner."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


def tree_where(condition: jax.Array, when_true: Any, when_false: Any) -> Any:
    """Leaf by leaf ``where``; ``condition`` broadcasts over each leaf's trailing axes
    (a scalar for one learner, a leading batch axis for a batch of robots)."""
    def pick(a, b):
        c = condition.reshape(condition.shape + (1,) * (jnp.ndim(a) - condition.ndim))
        return jnp.where(c, a, b)
    return jax.tree.map(pick, when_true, when_false)
