"""mjxcpg: CPG biped walking learned with a continuous-time policy gradient on MuJoCo and MJX.

The Python API (README, "Python API"): ``load_spec``, ``sweep``, ``load_run``,
``evaluate_policies``, ``reproduce``, ``RunSpec``, ``EvalParams``, ``ReproductionBudget`` and
``EVALUATIONS``, from ``mjxcpg.api``.  They are imported on
first use, so that ``import mjxcpg`` imports neither JAX nor MuJoCo: MuJoCo reads its OpenGL
back end (``MUJOCO_GL``) once, when it is imported, and the ``render`` command chooses one
first.
"""

import importlib

__version__ = "0.1.0"

_API = ("RunSpec", "EvalParams", "EVALUATIONS", "load_spec", "sweep", "load_run", "evaluate_policies", "reproduce",
        "ReproductionBudget")
__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module("mjxcpg.api"), name)
    raise AttributeError(f"module 'mjxcpg' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
