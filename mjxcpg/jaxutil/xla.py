"""How the library compiles and runs its controller, learner and engine loops on XLA:CPU.

XLA:CPU hands small fused element-wise and reduction kernels to the YNNPACK and XNNPACK
libraries.  At this project's sizes (tens of learners, 225 basis functions, 6 neurons) the
call overhead of those kernels dominates the work (``docs/performance.md`` has the
measurement); XLA's own generated code does the same work in a fraction of the time, so on
the CPU these fusions are turned off.

For the same reason the command line gives XLA:CPU one thread (``one_cpu_thread``).
"""

from __future__ import annotations

import os
import time
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
    """``jax.jit`` with this library's compiler options.  It asks JAX for its backend, which
    starts XLA: call it when a function is built, not at import, where XLA would start before
    the process has set its threads."""
    return jax.jit(fun, compiler_options=compiler_options(), **kwargs)


def compile_timed(jitted: Callable, *args: Any) -> tuple[Callable, float]:
    """``jitted`` traced and compiled ahead of time for ``args`` (arrays or
    ``jax.ShapeDtypeStruct``), and the seconds that took."""
    start = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - start


def one_cpu_thread() -> None:
    """Give XLA:CPU's intra-op thread pool one thread, unless ``NPROC`` is already set.

    XLA sizes that pool from the ``NPROC`` environment variable (default: one thread per core)
    when the CPU backend starts, so this must run before JAX computes anything; the command
    line calls it first thing.  The C engines step physics on threads of their own, and the
    learner's kernels are small: XLA spreading them over its threads costs more in hand-offs
    than it saves.  On the 2-core benchmark machine, at the paper's batch of 27, one thread
    cut the native engine's time between two physics calls from about 92 to 68 us; MJX on
    the CPU was as fast within noise, or faster (docs/performance.md).  Set ``NPROC`` to the
    core count to get XLA's default back, for example for MJX on a CPU with many cores.
    """
    os.environ.setdefault("NPROC", "1")
