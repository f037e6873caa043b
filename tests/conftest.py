"""Shared, session-scoped simulations and runs: JAX compile time dominates small tests.

Each engine walks one batch of robots for 20 s, compiled once per session:

* ``HAND``: the hand-designed feedback a_5 = d theta_roll/dt (``roll_rate_feedback``, gain 1);
* ``STEPPING``: a_5 = 0;
* ``LEARNED``: the mean of the policy learned with ``mjxcpg learn --k-s 10 --seed 1 --engine
  native --trials 200``, stored in ``tests/data/`` (regenerate it with
  ``tests/data/make_learned_policy.py``).

One feedback function serves the whole batch: a_5 = gain d theta_roll/dt + a_max g(mu(x; w)),
with w = 0 (so mu = 0 and g(0) = 0) for the first two robots and gain 0 for the learned one.
"""

import hashlib
import json
import re
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.cli import main
from mjxcpg.control import walk
from mjxcpg.control.controller import roll_rate_feedback
from mjxcpg.control.sim import make_simulation
from mjxcpg.learning import actor_critic as ac
from mjxcpg.learning.learner import policy_mean_feedback
from mjxcpg.training import config
from mjxcpg.training.train import RunSpec, make_task

WALK_SECONDS = 20.0
HAND, STEPPING, LEARNED = 0, 1, 2            # robots of the session walks
HAND_AND_STEPPING = (1.0, 0.0)               # a_5 gains: the hand-designed controller, then a_5 = 0
LEARNED_POLICY_PATH = Path(__file__).resolve().parent / "data" / "learned_policy_ks10_seed1.json"


class SessionWalk(NamedTuple):
    """One engine's 20 s walk of the robots ``HAND``, ``STEPPING``, ``LEARNED``."""

    trace: walk.Trace               # numpy arrays, (robot, control step)
    gaits: list[walk.GaitSummary]   # per robot


class MixedFeedback(NamedTuple):
    """Per robot: a_5 = roll_rate_gain d theta_roll/dt + the policy mean of ``policy``."""

    roll_rate_gain: jax.Array
    policy: ac.Weights


def model_fingerprint(mjcf: str) -> str:
    """SHA-256 of an MJCF without its comments: the model, not its prose."""
    return hashlib.sha256(re.sub(r"<!--.*?-->", "", mjcf, flags=re.S).encode()).hexdigest()


def load_learned_policy() -> dict:
    """The stored policy record (see ``tests/data/make_learned_policy.py``)."""
    return json.loads(LEARNED_POLICY_PATH.read_text())


def _walk_session_batch(engine: str) -> SessionWalk:
    sim = make_simulation(engine)
    record = load_learned_policy()
    spec = RunSpec(k_s=(record["k_s"],), seeds=(record["seed"],), basis_grid=record["basis_grid"],
                   basis_width=record["basis_width"])
    task = make_task(sim, spec)
    assert task.learner.a_max == record["a_max"], "the stored policy was learned with another a_max"
    policy_feedback = policy_mean_feedback(task)

    def feedback(obs, params: MixedFeedback) -> jax.Array:
        return roll_rate_feedback(obs, params.roll_rate_gain) + policy_feedback(obs, params.policy)

    num_basis = task.basis.centers.shape[0]
    learned_mean = jnp.asarray(record["policy_mean_weights"], jnp.float32)
    assert learned_mean.shape == (num_basis,)
    means = jnp.stack([jnp.zeros(num_basis), jnp.zeros(num_basis), learned_mean])
    batch = means.shape[0]
    params = MixedFeedback(
        roll_rate_gain=jnp.array(HAND_AND_STEPPING + (0.0,)),
        policy=ac.Weights(critic=jnp.zeros_like(means), mean=means, sigma=jnp.zeros(batch)))
    run = walk.make_walk(sim.engine, sim.layout, sim.params, round(WALK_SECONDS / sim.control_dt), feedback)
    trace = jax.device_get(run(sim.engine.init(sim.qpos0, batch), walk.initial_controller(batch), params))
    return SessionWalk(trace=jax.tree.map(np.asarray, trace), gaits=walk.summarise(trace, sim.control_dt, sim.layout.weight))


@pytest.fixture(scope="session")
def mujoco_sim():
    return make_simulation("mujoco")


@pytest.fixture(scope="session")
def session_walk_mujoco() -> SessionWalk:
    """The session's robots (hand, stepping, learned) walking 20 s on MuJoCo C."""
    return _walk_session_batch("mujoco")


@pytest.fixture(scope="session")
def session_walk_mjx() -> SessionWalk:
    """The same robots on MJX, as one batch."""
    return _walk_session_batch("mjx")


@pytest.fixture(scope="session")
def walks_mujoco(session_walk_mujoco):
    """[hand-designed walking, stepping with a_5 = 0, learned policy] for 20 s on MuJoCo C."""
    return session_walk_mujoco.gaits


@pytest.fixture(scope="session")
def walks_mjx(session_walk_mjx):
    """The same robots on MJX."""
    return session_walk_mjx.gaits


@pytest.fixture(scope="session")
def quick_spec():
    return config.load_spec("quick")


@pytest.fixture(scope="session")
def finished_quick(tmp_path_factory):
    """The `quick` sweep, run once, uninterrupted: what every interrupted or damaged run of
    it must end as."""
    out = tmp_path_factory.mktemp("quick") / "run"
    assert main(["sweep", "--config", "quick", "--out", str(out), "--quiet", "--engine", "native",
                 "--no-tensorboard", "--checkpoint-every", "0"]) == 0
    return out
