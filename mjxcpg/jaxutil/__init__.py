"""JAX helpers every layer may use: XLA:CPU settings and jit (``xla``), pytree selection
(``pytree``), several processes through ``jax.distributed`` (``processes``)."""
