"""Run configurations: typed dataclasses read from TOML (the package's ``configs/``, or a file
of the user's) or JSON, validated.

An unknown key, a value of the wrong type or an impossible value is a ``ValueError`` whose
one-line message names the key.

The learners are either spelled out, ``k_s`` and ``seeds`` (one pair per learner), or
generated (``expand_learners``): ``k_s_values`` with ``seeds_per_k_s`` learners per value
(default 1), seeds counting up from ``first_seed`` (default 0), and optionally ``learners``,
the count the sequence is repeated (and cut) to.  "10 seeds per k_s from seed 100":

    k_s_values = [0.0, 1.0, 2.0]
    seeds_per_k_s = 10
    first_seed = 100
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any

from mjxcpg.learning.learner import ACTORS
from mjxcpg.training.train import RunSpec

# Package data, so that an installed (non-editable) mjxcpg finds its configs too.
CONFIG_DIR = importlib.resources.files("mjxcpg") / "configs"


def _check(value: Any, annotation: Any, key: str) -> Any:
    origin = typing.get_origin(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ValueError(f"{key}: expected a table, got {type(value).__name__}")
        return from_dict(annotation, value, key)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        return _check(value, next(a for a in options if a is not type(None)), key)
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{key}: expected a list, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ValueError(f"{key}: expected {len(args)} values, got {len(value)}")
        return tuple(_check(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"{key}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key}: expected an integer, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: dict, prefix: str = "") -> Any:
    """Build dataclass ``cls`` from ``data``, checking every key and type."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for key, value in data.items():
        name = f"{prefix}.{key}" if prefix else key
        if key not in fields:
            raise ValueError(f"unknown key {name!r}")
        kwargs[key] = _check(value, hints[key], name)
    return cls(**kwargs)


def validate(spec: RunSpec) -> RunSpec:
    """Reject impossible values, naming the key."""
    rules = [
        ("k_s", len(spec.k_s) > 0, "needs at least one learner"),
        ("seeds", len(spec.seeds) == len(spec.k_s), "needs one seed per k_s entry"),
        ("trial.max_trials", spec.trial.max_trials >= 1, "must be at least 1"),
        ("trial.trial_seconds", spec.trial.trial_seconds > 0, "must be positive"),
        ("trial.success_streak", spec.trial.success_streak >= 1, "must be at least 1"),
        ("trial.hand_seconds", 0 <= spec.trial.hand_seconds[0] <= spec.trial.hand_seconds[1]
         < spec.trial.trial_seconds, "must be 0 <= low <= high < trial_seconds"),
        ("trial.velocity_filter_s", spec.trial.velocity_filter_s > 0, "must be positive"),
        ("trial.trials_after_success", spec.trial.trials_after_success >= 0, "must be non-negative"),
        ("trial.actor", spec.trial.actor in ACTORS, f"must be one of {', '.join(ACTORS)}"),
        ("learner.noise_correlation_s", spec.learner.noise_correlation_s >= 0, "must be non-negative"),
        ("learner.tau", spec.learner.tau > 0, "must be positive"),
        ("learner.rate_scale", spec.learner.rate_scale >= 0, "must be non-negative"),
        ("learner.a_max", spec.learner.a_max > 0, "must be positive"),
        ("controller.control_dt", spec.controller.control_dt > 0, "must be positive"),
        ("controller.control_dt", spec.controller.control_dt < min(
            spec.learner.kappa_c, spec.learner.kappa_mu, spec.learner.kappa_sigma),
         "must be shorter than every trace time constant"),
        ("controller.cpg_substeps", spec.controller.cpg_substeps >= 1, "must be at least 1"),
        ("physics_dt", spec.physics_dt is None or spec.physics_dt > 0, "must be positive"),
        ("chunk_seconds", spec.chunk_seconds >= spec.controller.control_dt, "must cover a control period"),
        ("basis_grid", spec.basis_grid >= 2, "must be at least 2"),
    ]
    for key, ok, message in rules:
        if not ok:
            raise ValueError(f"{key}: {message}")
    return spec


GENERATOR_KEYS = ("k_s_values", "seeds_per_k_s", "first_seed", "learners")


def _whole(data: dict, key: str, default: int, minimum: int) -> int:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{key}: expected an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{key}: must be at least {minimum}")
    return value


def expand_learners(data: dict) -> dict:
    """``data`` with the generator keys (``GENERATOR_KEYS``) replaced by the ``k_s`` and
    ``seeds`` lists they stand for; ``data`` itself if it has none.

    Each of ``k_s_values`` appears ``seeds_per_k_s`` times in a row; the whole sequence repeats
    until there are ``learners`` entries (default: one pass); learner i gets seed
    ``first_seed + i``.
    """
    given = [key for key in GENERATOR_KEYS if key in data]
    if not given:
        return data
    if "k_s_values" not in data:
        raise ValueError(f"{given[0]}: needs k_s_values")
    for key in ("k_s", "seeds"):
        if key in data:
            raise ValueError(f"{key}: give either k_s and seeds or k_s_values, not both")
    values = _check(data["k_s_values"], tuple[float, ...], "k_s_values")
    if not values:
        raise ValueError("k_s_values: needs at least one value")
    per_value = _whole(data, "seeds_per_k_s", 1, 1)
    first_seed = _whole(data, "first_seed", 0, 0)
    one_pass = [k for k in values for _ in range(per_value)]
    count = _whole(data, "learners", len(one_pass), 1)
    k_s = [one_pass[i % len(one_pass)] for i in range(count)]
    rest = {key: value for key, value in data.items() if key not in GENERATOR_KEYS}
    return {"k_s": k_s, "seeds": list(range(first_seed, first_seed + count)), **rest}


def config_names() -> list[str]:
    """The configs that ship with mjxcpg, by name."""
    return sorted(p.name.removesuffix(".toml") for p in CONFIG_DIR.iterdir() if p.name.endswith(".toml"))


def load_spec(name_or_path: str) -> RunSpec:
    """A config by name (one of ``config_names()``) or by path (.toml or .json)."""
    path = Path(name_or_path)
    source = CONFIG_DIR / f"{name_or_path}.toml" if not path.suffix else path
    if not source.is_file():
        raise ValueError(f"no config {name_or_path!r} (known: {', '.join(config_names())})")
    suffix = Path(source.name).suffix
    try:
        text = source.read_text()
        data = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{name_or_path}: not valid {suffix[1:].upper()}: {error}") from None
    return validate(from_dict(RunSpec, expand_learners(data)))


def spec_to_dict(spec: RunSpec) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(spec)))


def spec_from_dict(data: dict) -> RunSpec:
    return validate(from_dict(RunSpec, data))

