"""Physics engines behind one small interface.

An engine advances a batch of robots by one control period under constant servo targets.
Its state is a JAX pytree with a leading batch axis, so the controller and the learner run
inside the same ``jit``/``lax.scan`` whatever the engine:

* ``mujoco``: MuJoCo C, one robot after another on the calling thread (the scalar reference);
* ``native``: MuJoCo C stepping the batch on all cores through ``mujoco.rollout``;
* ``mjx``: MuJoCo MJX, ``vmap``-ed, on whatever device JAX uses.

The two C engines reach the host through ``jax.pure_callback`` and keep the full physics
state (``mjSTATE_FULLPHYSICS``) in the pytree; each control period starts the solver from a
zero warm start, so that their results do not depend on thread scheduling or on which
``MjData`` served a robot.  They give identical results for the same inputs.  A robot whose
simulation diverges (MuJoCo resets such data and warns) comes back as NaN.
"""

from __future__ import annotations

import abc
import contextlib
import io
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.pytree import tree_where
from mjxcpg.robot import Sensors

ENGINES = ("mujoco", "native", "mjx")
_FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


def default_engine() -> str:
    """MJX when JAX sees an accelerator, the native C batch otherwise."""
    return "mjx" if jax.default_backend() in ("gpu", "cuda", "rocm", "tpu") else "native"


class Engine(abc.ABC):
    """Steps a batch of robots; all methods but ``__init__`` are pure and jittable."""

    name: str

    def __init__(self, model: mujoco.MjModel, substeps: int):
        self.model = model
        self.substeps = substeps

    @abc.abstractmethod
    def init(self, qpos: np.ndarray, batch: int) -> Any:
        """``batch`` robots at rest in pose ``qpos``, sensors read."""

    @abc.abstractmethod
    def step(self, state: Any, ctrl: jax.Array, active: jax.Array | None = None) -> Any:
        """Advance the robots where ``active`` holds (all when None) by ``substeps`` physics
        steps under servo targets ``ctrl``; the others keep their state."""

    @abc.abstractmethod
    def sensors(self, state: Any) -> Sensors:
        """Ground truth and sensor readings, with a leading batch axis."""

    def reset(self, state: Any, initial: Any, mask: jax.Array) -> Any:
        """Put the robots where ``mask`` holds back to ``initial``."""
        return tree_where(mask, initial, state)


class CState(NamedTuple):
    physics: jax.Array     # (batch, nstate) float32, mjSTATE_FULLPHYSICS
    sensordata: jax.Array  # (batch, nsensordata)


class _CEngine(Engine):
    """MuJoCo C reached through a host callback."""

    def __init__(self, model: mujoco.MjModel, substeps: int):
        super().__init__(model, substeps)
        self.nstate = mujoco.mj_stateSize(model, _FULLPHYSICS)
        self._data = mujoco.MjData(model)

    def init(self, qpos: np.ndarray, batch: int) -> CState:
        data = self._data
        mujoco.mj_resetData(self.model, data)
        data.qpos[:] = qpos
        mujoco.mj_forward(self.model, data)
        physics = np.empty(self.nstate)
        mujoco.mj_getState(self.model, data, physics, _FULLPHYSICS)
        return CState(
            physics=jnp.tile(jnp.asarray(physics, jnp.float32), (batch, 1)),
            sensordata=jnp.tile(jnp.asarray(data.sensordata, jnp.float32), (batch, 1)),
        )

    def sensors(self, state: CState) -> Sensors:
        nq, nv = self.model.nq, self.model.nv
        return Sensors(qpos=state.physics[:, 1:1 + nq],
                       qvel=state.physics[:, 1 + nq:1 + nq + nv],
                       sensordata=state.sensordata)

    def step(self, state: CState, ctrl: jax.Array, active: jax.Array | None = None) -> CState:
        if active is None:
            active = jnp.ones(state.physics.shape[0], bool)
        shapes = (jax.ShapeDtypeStruct(state.physics.shape, jnp.float32),
                  jax.ShapeDtypeStruct(state.sensordata.shape, jnp.float32))
        physics, sensordata = jax.pure_callback(
            self._host_step, shapes, state.physics, state.sensordata, ctrl.astype(jnp.float32),
            active, vmap_method="sequential")
        return CState(physics=physics, sensordata=sensordata)

    def _host_step(self, physics: np.ndarray, sensordata: np.ndarray, ctrl: np.ndarray,
                   active: np.ndarray):
        new_physics, new_sensordata = np.array(physics), np.array(sensordata)
        rows = np.flatnonzero(active)
        if rows.size == 0:
            return new_physics, new_sensordata
        start = np.asarray(physics[rows], np.float64)
        stepped, stepped_sensors = self._simulate(start, np.asarray(ctrl[rows], np.float64))
        # MuJoCo resets a diverged simulation to time 0: report it as NaN instead.
        elapsed = stepped[:, 0] - start[:, 0]
        diverged = ~np.isclose(elapsed, self.substeps * self.model.opt.timestep, rtol=1e-3, atol=1e-6)
        diverged |= ~np.isfinite(stepped).all(axis=1)
        stepped[diverged] = np.nan
        stepped_sensors[diverged] = np.nan
        new_physics[rows], new_sensordata[rows] = stepped, stepped_sensors
        return new_physics, new_sensordata

    @abc.abstractmethod
    def _simulate(self, physics: np.ndarray, ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Host side: (batch, nstate), (batch, nu) -> new state and sensordata."""


class MujocoEngine(_CEngine):
    """The scalar reference: plain ``mj_step``, one robot at a time."""

    name = "mujoco"

    def _simulate(self, physics, ctrl):
        model, data = self.model, self._data
        new_physics = np.empty_like(physics)
        sensordata = np.empty((len(physics), model.nsensordata))
        for b in range(len(physics)):
            mujoco.mj_setState(model, data, physics[b], _FULLPHYSICS)
            data.qacc_warmstart[:] = 0
            data.ctrl[:] = ctrl[b]
            for _ in range(self.substeps):
                mujoco.mj_step(model, data)
            mujoco.mj_getState(model, data, new_physics[b], _FULLPHYSICS)
            sensordata[b] = data.sensordata
        return new_physics, sensordata


class NativeEngine(_CEngine):
    """MuJoCo C on a thread pool (``mujoco.rollout``): the fast batch engine for CPUs."""

    name = "native"

    def __init__(self, model: mujoco.MjModel, substeps: int, threads: int | None = None):
        from mujoco import rollout

        super().__init__(model, substeps)
        self.threads = threads or os.cpu_count() or 1
        self._datas = [mujoco.MjData(model) for _ in range(self.threads)]
        self._pool = rollout.Rollout(nthread=self.threads if self.threads > 1 else 0)

    def _simulate(self, physics, ctrl):
        batch = len(physics)
        control = np.repeat(ctrl[:, None, :], self.substeps, axis=1)
        states, sensordata = self._pool.rollout(
            self.model, self._datas, physics, control, nstep=self.substeps,
            initial_warmstart=np.zeros((batch, self.model.nv)))
        return states[:, -1], sensordata[:, -1]


class MjxEngine(Engine):
    """MuJoCo MJX (JAX implementation), ``vmap``-ed over the batch."""

    name = "mjx"

    def __init__(self, model: mujoco.MjModel, substeps: int):
        with contextlib.redirect_stdout(io.StringIO()):  # mjx prints when the optional warp is absent
            from mujoco import mjx

        super().__init__(model, substeps)
        self._mjx = mjx
        self.mjx_model = mjx.put_model(model, impl="jax")

    def init(self, qpos: np.ndarray, batch: int):
        mjx = self._mjx
        data = mjx.make_data(self.model, impl="jax")
        data = data.replace(qpos=jnp.asarray(qpos, jnp.float32))
        data = jax.jit(mjx.forward)(self.mjx_model, data)
        return jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), data)

    def sensors(self, state) -> Sensors:
        return Sensors(qpos=state.qpos, qvel=state.qvel, sensordata=state.sensordata)

    def step(self, state, ctrl: jax.Array, active: jax.Array | None = None):
        mjx, model = self._mjx, self.mjx_model

        def one_robot(data, u):
            data = data.replace(ctrl=u)
            return jax.lax.fori_loop(0, self.substeps, lambda _, d: mjx.step(model, d), data)

        stepped = jax.vmap(one_robot)(state, ctrl)
        # In lockstep every robot costs the same, so idle ones are stepped and discarded.
        return stepped if active is None else tree_where(active, stepped, state)


def make_engine(name: str, model: mujoco.MjModel, substeps: int) -> Engine:
    """Build the engine called ``name`` (one of ``ENGINES``)."""
    engines = {"mujoco": MujocoEngine, "native": NativeEngine, "mjx": MjxEngine}
    if name not in engines:
        raise ValueError(f"unknown engine {name!r}; choose one of {', '.join(ENGINES)}")
    return engines[name](model, substeps)
