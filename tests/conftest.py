"""Shared, session-scoped simulations: JAX compile time dominates small tests."""

import jax.numpy as jnp
import pytest

from mjxcpg import walk
from mjxcpg.controller import roll_rate_feedback
from mjxcpg.sim import make_simulation

WALK_SECONDS = 20.0
HAND_AND_STEPPING = (1.0, 0.0)  # a_5 gains: the hand-designed controller, then a_5 = 0


def _walk_both(engine: str):
    sim = make_simulation(engine)
    run = walk.make_walk(sim.engine, sim.layout, sim.params, round(WALK_SECONDS / sim.control_dt),
                         roll_rate_feedback)
    batch = len(HAND_AND_STEPPING)
    trace = run(sim.engine.init(sim.qpos0, batch), walk.initial_cpg(batch), jnp.array(HAND_AND_STEPPING))
    return walk.summarise(trace, sim.control_dt)


@pytest.fixture(scope="session")
def mujoco_sim():
    return make_simulation("mujoco")


@pytest.fixture(scope="session")
def walks_mujoco():
    """[hand-designed walking, stepping with a_5 = 0] for 20 s on MuJoCo C."""
    return _walk_both("mujoco")


@pytest.fixture(scope="session")
def walks_mjx():
    """The same two robots on MJX, as one batch."""
    return _walk_both("mjx")
