"""A run directory holding the stored learned policy (tests/data), made without learning.

``make_learned_run(out)`` writes ``out/config.json`` and one checkpoint whose single learner
has the stored policy mean (critic zero, w^sigma = ``w_sigma``, by default as initialised) and
counts as succeeded:
enough for every command that reloads a run (walk --checkpoint, render, the hardware
transfer, online learning).
"""

import json
from pathlib import Path

import jax.numpy as jnp

from mjxcpg.training import config, runs, train

STORED_POLICY = Path(__file__).resolve().parent / "data" / "learned_policy_ks10_seed1.json"


def make_learned_run(out: Path, engine: str = "native", w_sigma: float | None = None) -> Path:
    record = json.loads(STORED_POLICY.read_text())
    spec = config.validate(train.RunSpec(k_s=(record["k_s"],), seeds=(record["seed"],),
                                         basis_grid=record["basis_grid"], basis_width=record["basis_width"]))
    sim = spec.simulation(engine)
    task = train.make_task(sim, spec)
    state = train.init_run(sim, task, spec)
    weights = state.learners.weights._replace(
        mean=jnp.asarray(record["policy_mean_weights"], jnp.float32)[None])
    if w_sigma is not None:
        weights = weights._replace(sigma=jnp.full_like(weights.sigma, w_sigma))
    book = state.learners.book._replace(trials_to_success=jnp.array([record["trials_to_success"]], jnp.int32))
    state = state._replace(learners=state.learners._replace(weights=weights, book=book))
    runs.write_run(out, spec, engine, state)
    return out
