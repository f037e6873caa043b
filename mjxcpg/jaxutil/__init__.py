"""JAX helpers every layer may use: XLA:CPU settings and jit (``xla``), pytree selection
(``pytree``)."""
