"""Run configurations: typed dataclasses read from TOML (the package's ``configs/``, or a file
of the user's) or JSON, validated.

An unknown key, a value of the wrong type or an impossible value is a ``ValueError`` whose
one-line message names the key.  Every number of a spec, whether a config file or a
command-line flag gave it, passes ``validate``: finite, and in its range of ``RANGES``
(``mjxcpg.training.checks``).

The learners are either spelled out, ``k_s`` and ``seeds`` (one pair per learner), or
generated (``expand_learners``): ``k_s_values`` with ``seeds_per_k_s`` learners per value
(default 1), seeds counting up from ``first_seed`` (default 0), and optionally ``learners``,
the count the sequence is repeated (and cut) to.  "10 seeds per k_s from seed 100":

    k_s_values = [0.0, 1.0, 2.0]
    seeds_per_k_s = 10
    first_seed = 100

A config that names a ``platform`` (a robot of ``mjxcpg.robots.PLATFORMS``; default QRIO)
starts from that robot's controller and reward height (``RunSpec.for_platform``); its own
``[controller]`` and ``[trial]`` keys change those.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import re
import tomllib
import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mjxcpg import robots
from mjxcpg.learning.learner import ACTORS
from mjxcpg.training import checks
from mjxcpg.training.checks import COUNT, FINITE, NON_NEGATIVE, NON_NEGATIVE_COUNT, POSITIVE, SEED, Range
from mjxcpg.training.train import RunSpec

# Package data, so that an installed (non-editable) mjxcpg finds its configs too.
CONFIG_DIR = importlib.resources.files("mjxcpg") / "configs"


def _check(value: Any, annotation: Any, key: str, base: Any = None) -> Any:
    origin = typing.get_origin(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ValueError(f"{key}: expected a table, got {type(value).__name__}")
        return from_dict(annotation, value, key, base)
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
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is str and not isinstance(value, str):
        raise ValueError(f"{key}: expected a string, got {value!r}")
    return value


def from_dict(cls: type, data: dict, prefix: str = "", base: Any = None) -> Any:
    """Build dataclass ``cls`` from ``data``, checking every key and type.  A key ``data``
    leaves out takes its value from ``base`` (an instance of ``cls``, or a dict of some of
    its fields), else the field's default; a table ``data`` gives changes ``base``'s value."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    defaults = {} if base is None else base if isinstance(base, dict) else {
        name: getattr(base, name) for name in fields}
    kwargs = {}
    for key, value in data.items():
        name = f"{prefix}.{key}" if prefix else key
        if key not in fields:
            raise ValueError(f"unknown key {name!r}")
        kwargs[key] = _check(value, hints[key], name, defaults.get(key))
    return cls(**(defaults | kwargs))


# The range of each number of a spec by its key (list entries share their list's key); a
# number not listed need only be finite.
RANGES: dict[str, Range] = {
    "k_s": FINITE,
    "seeds": SEED,
    "k_e": NON_NEGATIVE,
    "learner.tau": POSITIVE,
    "learner.alpha": NON_NEGATIVE,
    "learner.kappa_c": POSITIVE,
    "learner.beta_mu": NON_NEGATIVE,
    "learner.beta_sigma": NON_NEGATIVE,
    "learner.kappa_mu": POSITIVE,
    "learner.kappa_sigma": POSITIVE,
    "learner.a_max": POSITIVE,
    "learner.noise_correlation_s": NON_NEGATIVE,
    "learner.stepping_a_max": NON_NEGATIVE,
    "learner.rate_scale": NON_NEGATIVE,
    "learner.max_abs_td_error": POSITIVE,
    "learner.mean_step_sigma_power": NON_NEGATIVE,
    "trial.trial_seconds": POSITIVE,
    "trial.hand_seconds": NON_NEGATIVE,
    "trial.velocity_filter_s": POSITIVE,
    "trial.success_streak": COUNT,
    "trial.max_trials": COUNT,
    "trial.trials_after_success": NON_NEGATIVE_COUNT,
    "controller.cpg.tau": POSITIVE,
    "controller.cpg.tau_adapt": POSITIVE,
    "controller.amp_x": NON_NEGATIVE,
    "controller.amp_z": NON_NEGATIVE,
    "controller.z0": POSITIVE,
    "controller.control_dt": POSITIVE,
    "controller.cpg_substeps": COUNT,
    "controller.h_heading": NON_NEGATIVE,
    "controller.max_turn": dataclasses.replace(NON_NEGATIVE, high=0.5),
    "controller.heading_command": Range(low=-1.0, high=1.0),  # rad
    "controller.slope_reflex_s": NON_NEGATIVE,
    "controller.hand_fade_seconds": NON_NEGATIVE,
    "controller.max_ankle_pitch": dataclasses.replace(NON_NEGATIVE, high=0.5),
    "controller.slope_posture": dataclasses.replace(NON_NEGATIVE, high=1.0),
    "physics_dt": POSITIVE,
    "basis_grid": dataclasses.replace(COUNT, low=2),
    "basis_width": POSITIVE,
    "chunk_seconds": POSITIVE,
}


def _numbers(value: Any, name: str = "") -> Iterator[tuple[str, Any]]:
    """(name, number) of every number in ``value``, a spec or a part of one."""
    if dataclasses.is_dataclass(value):
        for field in dataclasses.fields(value):
            yield from _numbers(getattr(value, field.name), f"{name}.{field.name}" if name else field.name)
    elif isinstance(value, (tuple, list)):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{name}[{i}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield name, value


def range_of(name: str) -> Range:
    """The range of the spec's number ``name`` (``RANGES``, list indices left out)."""
    return RANGES.get(re.sub(r"\[\d+\]", "", name), FINITE)


def validate(spec: RunSpec) -> RunSpec:
    """Reject impossible values, naming the key: every number against its range, then the
    rules that relate several values."""
    for name, value in _numbers(spec):
        checks.check(name, value, range_of(name))
    rules = [
        ("k_s", len(spec.k_s) > 0, "needs at least one learner"),
        ("seeds", len(spec.seeds) == len(spec.k_s), "needs one seed per k_s entry"),
        ("k_e", spec.k_e is None or len(spec.k_e) == len(spec.k_s), "needs one energy gain per k_s entry"),
        ("trial.hand_seconds", spec.trial.hand_seconds[0] <= spec.trial.hand_seconds[1]
         < spec.trial.trial_seconds, "must be low <= high < trial_seconds"),
        ("trial.actor", spec.trial.actor in ACTORS, f"must be one of {', '.join(ACTORS)}"),
        ("learner.w_sigma_bounds", spec.learner.w_sigma_bounds is None
         or spec.learner.w_sigma_bounds[0] <= spec.learner.w_sigma_bounds[1], "must be low <= high"),
        ("controller.vsr_sign", spec.controller.vsr_sign in (-1.0, 1.0), "must be -1 or 1"),
        ("controller.control_dt", spec.controller.control_dt < min(
            spec.learner.kappa_c, spec.learner.kappa_mu, spec.learner.kappa_sigma),
         "must be shorter than every trace time constant"),
        ("chunk_seconds", spec.chunk_seconds >= spec.controller.control_dt, "must cover a control period"),
    ]
    for key, ok, message in rules:
        if not ok:
            raise ValueError(f"{key}: {message}")
    return spec


GENERATOR_KEYS = ("k_s_values", "seeds_per_k_s", "first_seed", "learners", "k_e_values")


def expand_learners(data: dict) -> dict:
    """``data`` with the generator keys (``GENERATOR_KEYS``) replaced by the ``k_s`` and
    ``seeds`` lists they stand for; ``data`` itself if it has none.

    Each of ``k_s_values`` appears ``seeds_per_k_s`` times in a row; the whole sequence repeats
    until there are ``learners`` entries (default: one pass); learner i gets seed
    ``first_seed + i``.  With ``k_e_values``, those learners come once per energy gain k_E,
    with the same k_s and seeds each time: each k_E > 0 beside the same seeds at k_E = 0.
    """
    given = [key for key in GENERATOR_KEYS if key in data]
    if not given:
        return data
    if "k_s_values" not in data:
        raise ValueError(f"{given[0]}: needs k_s_values")
    for key in ("k_s", "seeds", "k_e"):
        if key in data:
            raise ValueError(f"{key}: give either k_s, seeds and k_e or k_s_values, not both")
    values = _check(data["k_s_values"], tuple[float, ...], "k_s_values")
    if not values:
        raise ValueError("k_s_values: needs at least one value")
    for i, value in enumerate(values):
        checks.check(f"k_s_values[{i}]", value, RANGES["k_s"])
    per_value = checks.check("seeds_per_k_s", data.get("seeds_per_k_s", 1), COUNT)
    first_seed = checks.check("first_seed", data.get("first_seed", 0), SEED)
    one_pass = [k for k in values for _ in range(per_value)]
    count = checks.check("learners", data.get("learners", len(one_pass)), COUNT)
    k_s = [one_pass[i % len(one_pass)] for i in range(count)]
    seeds = list(range(first_seed, first_seed + count))
    rest = {key: value for key, value in data.items() if key not in GENERATOR_KEYS}
    if "k_e_values" not in data:
        return {"k_s": k_s, "seeds": seeds, **rest}
    gains = _check(data["k_e_values"], tuple[float, ...], "k_e_values")
    if not gains:
        raise ValueError("k_e_values: needs at least one value")
    for i, value in enumerate(gains):
        checks.check(f"k_e_values[{i}]", value, RANGES["k_e"])
    return {"k_s": k_s * len(gains), "seeds": seeds * len(gains), "k_e": [g for g in gains for _ in k_s], **rest}


def config_names() -> list[str]:
    """The configs that ship with mjxcpg, by name."""
    return sorted(p.name.removesuffix(".toml") for p in CONFIG_DIR.iterdir() if p.name.endswith(".toml"))


def load_spec(name_or_path: str, platform: str | None = None) -> RunSpec:
    """A config by name (one of ``config_names()``) or by path (.toml or .json); ``platform``
    in place of the config's own."""
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
    if not isinstance(data, dict):
        raise ValueError(f"{name_or_path}: a config is a table of keys, not a {type(data).__name__}")
    return spec_from_config(expand_learners(data | ({} if platform is None else {"platform": platform})))


def spec_from_config(data: dict) -> RunSpec:
    """The spec of a config's (expanded) table: its platform's defaults, changed by ``data``."""
    platform = _check(data.get("platform", robots.DEFAULT_PLATFORM), str, "platform")
    if platform not in robots.PLATFORMS:
        raise ValueError(f"platform: unknown {platform!r}; choose one of {', '.join(robots.PLATFORMS)}")
    return validate(from_dict(RunSpec, data, base=RunSpec.platform_defaults(platform)))


def spec_to_dict(spec: RunSpec) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(spec)))


# Keys added to the spec after runs had been recorded (each by its path of keys), in the
# order they were added, those added together in one group, with the value that a run
# recorded without them had: such a run's record is the spec without that group and every
# later one.
ADDED_KEYS: tuple[dict[tuple[str, ...], Any], ...] = (
    {("learner", "unit_slope"): False}, {("platform",): robots.DEFAULT_PLATFORM},
    {("learner", "fall_impulse"): False}, {("learner", "mean_step_sigma_power"): 0.0},
    {("controller", "h_heading"): 0.0, ("controller", "max_turn"): 0.3,
     ("controller", "slope_reflex_s"): 0.0, ("controller", "max_ankle_pitch"): 0.2},
    {("controller", "slope_posture"): 0.0}, {("k_e",): None},
    {("controller", "heading_command"): 0.0}, {("controller", "hand_fade_seconds"): 0.0},
    {("learner", "stepping_a_max"): 0.0})


def earlier_spec_dicts(spec: RunSpec) -> list[dict]:
    """``spec`` as each earlier version of the code recorded it, newest first, as far back
    as it could have recorded it (every key added since at its old value)."""
    earlier = []
    for first_missing in reversed(range(len(ADDED_KEYS))):
        data = spec_to_dict(spec)
        for group in ADDED_KEYS[first_missing:]:
            for path, value in group.items():
                table = data
                for key in path[:-1]:
                    table = table[key]
                if table[path[-1]] != value:
                    return earlier
                del table[path[-1]]
        earlier.append(data)
    return earlier


def spec_from_dict(data: dict) -> RunSpec:
    return validate(from_dict(RunSpec, data))

