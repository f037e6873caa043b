"""How the library compiles its controller, learner and engine loops.

XLA:CPU hands small fused element-wise and reduction kernels to the YNNPACK and XNNPACK
libraries.  At this project's sizes (tens of learners, 225 basis functions, 6 neurons) the
call overhead of those kernels dominates: for the paper's 27 learners, the NGnet basis alone
took 110 us of a 140 us control period.  XLA's own generated code does the same work in a
fraction of that, so on the CPU these fusions are turned off.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax

CPU_COMPILER_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "",
    "xla_cpu_experimental_xnn_fusion_type": "",
}


def compiler_options() -> dict[str, str] | None:
    """The XLA options of every ``jit`` below: the ones above on the CPU, none elsewhere."""
    return CPU_COMPILER_OPTIONS if jax.default_backend() == "cpu" else None


def jit(fun: Callable, **kwargs: Any) -> Callable:
    """``jax.jit`` with this library's compiler options."""
    return jax.jit(fun, compiler_options=compiler_options(), **kwargs)
