"""Physics engines behind one small interface.

An engine advances a batch of robots by one control period under constant servo targets.
Its state is a JAX pytree with a leading batch axis, so the controller and the learner run
inside the same ``jit``/``lax.scan`` whatever the engine:

* ``mujoco``: MuJoCo C, one robot after another on the calling thread (the scalar reference);
* ``native``: MuJoCo C stepping the batch on all cores, inside XLA through an FFI handler
  (``native_step``), else through ``mujoco.rollout`` in a callback;
* ``mjx``: MuJoCo MJX, ``vmap``-ed, on whatever device JAX uses.

The two C engines reach MuJoCo through a callback (``buffer_callback`` on one CPU device,
which writes into XLA's own buffers; ``pure_callback`` elsewhere), or, for ``native`` on one
CPU device, through the FFI handler that makes the same calls; both keep the full physics
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
from jax.experimental.buffer_callback import buffer_callback

from mjxcpg.jaxutil.pytree import tree_where
from mjxcpg.physics import native_step
from mjxcpg.physics.model import Sensors, positive_power, power_sensor_slices
from mjxcpg.robots.qrio import QRIO

ENGINES = ("mujoco", "native", "mjx")
_FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CTRL_AND_XFRC = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED
# The native engine uses its threads from this many robots per thread; below, one thread steps
# the whole batch, since handing 4 robots to each of 2 threads of ``mujoco.rollout`` gained
# nothing over one thread (``mjxcpg bench``'s physics at batches 4 and 8); the FFI handler
# keeps the same threshold.
_ROBOTS_PER_THREAD = 8
_CPU_SLICE = 32  # MJX on the CPU steps at most this many robots in one vmap (MjxEngine._map)


def _one_cpu_device() -> bool:
    """Whether this process's XLA runs on one CPU device, where the C engines may write into
    XLA's own buffers (in a host callback or inside XLA)."""
    return jax.default_backend() == "cpu" and jax.local_device_count() == 1


def default_engine() -> str:
    """MJX when JAX sees an accelerator, the native C batch otherwise."""
    return "mjx" if jax.default_backend() in ("gpu", "cuda", "rocm", "tpu") else "native"


class Engine(abc.ABC):
    """Steps a batch of robots; all methods but ``__init__`` are pure and jittable."""

    name: str

    def __init__(self, model: mujoco.MjModel, substeps: int, pelvis: str = QRIO.pelvis):
        self.model = model
        self.substeps = substeps
        self.pelvis = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, pelvis)  # what ``pelvis_force`` pushes

    @abc.abstractmethod
    def init(self, qpos: np.ndarray, batch: int) -> Any:
        """``batch`` robots at rest in pose ``qpos``, sensors read."""

    @abc.abstractmethod
    def step(self, state: Any, ctrl: jax.Array, active: jax.Array | None = None,
             pelvis_force: jax.Array | None = None) -> Any:
        """Advance the robots where ``active`` holds (all when None) by ``substeps`` physics
        steps under servo targets ``ctrl``; the others keep their state.

        ``pelvis_force`` (batch, 3), newtons in the world frame, pushes each robot's pelvis at
        its centre of mass for this control period (MuJoCo's ``xfrc_applied``); None is no
        push, and then the step is exactly the one without the argument.
        """

    @abc.abstractmethod
    def sensors(self, state: Any) -> Sensors:
        """Ground truth and sensor readings, with a leading batch axis."""

    def reset(self, state: Any, initial: Any, mask: jax.Array) -> Any:
        """Put the robots where ``mask`` holds back to ``initial``."""
        return tree_where(mask, initial, state)

    def threads_for(self, batch: int) -> int:
        """The host threads that step a batch of ``batch`` robots side by side."""
        return 1


class CState(NamedTuple):
    physics: jax.Array        # (batch, nstate) float32, mjSTATE_FULLPHYSICS
    sensordata: jax.Array     # (batch, nsensordata)
    positive_work: jax.Array  # (batch,) the actuators' over the last control period (``Sensors``)


class _CEngine(Engine):
    """MuJoCo C reached through a host callback."""

    def __init__(self, model: mujoco.MjModel, substeps: int, pelvis: str = QRIO.pelvis):
        super().__init__(model, substeps, pelvis)
        self.nstate = mujoco.mj_stateSize(model, _FULLPHYSICS)
        self._data = mujoco.MjData(model)
        self._power = power_sensor_slices(model)

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
            positive_work=jnp.zeros(batch, jnp.float32),
        )

    def sensors(self, state: CState) -> Sensors:
        nq, nv = self.model.nq, self.model.nv
        return Sensors(qpos=state.physics[:, 1:1 + nq],
                       qvel=state.physics[:, 1 + nq:1 + nq + nv],
                       sensordata=state.sensordata, positive_work=state.positive_work)

    def step(self, state: CState, ctrl: jax.Array, active: jax.Array | None = None,
             pelvis_force: jax.Array | None = None) -> CState:
        batch = state.physics.shape[0]
        inputs = [state.physics, state.sensordata, state.positive_work, ctrl.astype(jnp.float32),
                  jnp.ones(batch, bool) if active is None else active]
        if pelvis_force is not None:
            inputs.append(pelvis_force.astype(jnp.float32))
        outputs = tuple(jax.ShapeDtypeStruct(x.shape, jnp.float32) for x in state)
        if _one_cpu_device():
            # The host writes the stepped rows straight into XLA's buffers, which alias the
            # inputs, so idle robots cost no copy and nothing is packed or allocated.  (Over
            # several devices, buffer_callback runs once per device: there the batch goes to one
            # device through pure_callback.)
            stepped = buffer_callback(
                self._host_step_in_place, outputs, vmap_method="sequential",
                input_output_aliases={0: 0, 1: 1, 2: 2})(*inputs)
        else:  # the host works on copies
            stepped = jax.pure_callback(self._host_step_copied, outputs, *inputs, vmap_method="sequential")
        return CState(*stepped)

    def _host_step_in_place(self, _context, out, *inputs) -> None:
        physics, sensordata, work = (np.asarray(buffer) for buffer in out)  # views, aliasing inputs 0-2
        self._host_step(physics, sensordata, work, *(np.asarray(x) for x in inputs[3:]))

    def _host_step_copied(self, physics, sensordata, work, *inputs) -> tuple[np.ndarray, ...]:
        physics, sensordata, work = np.array(physics), np.array(sensordata), np.array(work)
        self._host_step(physics, sensordata, work, *(np.asarray(x) for x in inputs))
        return physics, sensordata, work

    def _host_step(self, physics: np.ndarray, sensordata: np.ndarray, work: np.ndarray, ctrl: np.ndarray,
                   active: np.ndarray, pelvis_force: np.ndarray | None = None) -> None:
        """Step the active rows of ``physics``, ``sensordata`` and ``work`` (float32) in place."""
        rows = slice(None) if active.all() else np.flatnonzero(active)
        start = physics[rows].astype(np.float64)
        if len(start) == 0:
            return
        force = None if pelvis_force is None else pelvis_force[rows]
        stepped, stepped_sensors, stepped_work = self._simulate(start, ctrl[rows], force)
        diverged = self._diverged(start, stepped)
        if diverged is not None:
            stepped[diverged] = np.nan
            stepped_sensors[diverged] = np.nan
            stepped_work[diverged] = np.nan
        physics[rows], sensordata[rows], work[rows] = stepped, stepped_sensors, stepped_work

    def _period_work(self, sensordata: np.ndarray) -> np.ndarray:
        """(..., substeps, nsensordata) of every physics step of a period -> the actuators'
        positive work over it (J): each step's power (``model.positive_power``) times its length."""
        force, velocity = self._power
        return positive_power(sensordata[..., force], sensordata[..., velocity]).sum(axis=-1) * self.model.opt.timestep

    def _diverged(self, start: np.ndarray, stepped: np.ndarray) -> np.ndarray | None:
        """Which rows diverged, or None if none did.  MuJoCo resets a diverged simulation to
        time 0, so its clock did not advance by the control period; a NaN start time fails
        that test too, and a row sums to a finite number only if it is finite."""
        expected = self.substeps * self.model.opt.timestep
        on_time = np.abs(stepped[:, 0] - start[:, 0] - expected) <= 1e-6 + 1e-3 * expected
        if on_time.all() and np.isfinite(stepped.sum()):  # the usual case, in few numpy calls
            return None
        return ~(on_time & np.isfinite(stepped.sum(axis=1)))

    @abc.abstractmethod
    def _simulate(self, physics: np.ndarray, ctrl: np.ndarray,
                  pelvis_force: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host side: (batch, nstate) float64, (batch, nu) and optional (batch, 3) of any float
        type -> new state, sensordata and the period's positive actuator work, float64."""


class MujocoEngine(_CEngine):
    """The scalar reference: plain ``mj_step``, one robot at a time."""

    name = "mujoco"

    def _simulate(self, physics, ctrl, pelvis_force=None):
        model, data = self.model, self._data
        new_physics = np.empty_like(physics)
        sensordata = np.empty((len(physics), model.nsensordata))
        work = np.empty(len(physics))
        substep_sensors = np.empty((self.substeps, model.nsensordata))
        for b in range(len(physics)):
            mujoco.mj_setState(model, data, physics[b], _FULLPHYSICS)
            data.qacc_warmstart[:] = 0
            data.ctrl[:] = ctrl[b]
            if pelvis_force is not None:
                data.xfrc_applied[self.pelvis, :3] = pelvis_force[b]
            for t in range(self.substeps):
                mujoco.mj_step(model, data)
                substep_sensors[t] = data.sensordata
            data.xfrc_applied[:] = 0
            mujoco.mj_getState(model, data, new_physics[b], _FULLPHYSICS)
            sensordata[b], work[b] = data.sensordata, self._period_work(substep_sensors)
        return new_physics, sensordata, work


def native_threads() -> int:
    """The native engine's thread count: ``MJXCPG_NATIVE_THREADS`` where set, else the CPUs
    this process may run on (its affinity, as Slurm's ``--cpus-per-task`` or ``taskset`` set
    it, not the machine's cores)."""
    override = os.environ.get("MJXCPG_NATIVE_THREADS")
    if override:
        if not override.isdigit() or int(override) < 1:
            raise ValueError(f"MJXCPG_NATIVE_THREADS must be a positive whole number, not {override!r}")
        return int(override)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class NativeEngine(_CEngine):
    """MuJoCo C on all cores: the fast batch engine for CPUs.  Inside XLA through the FFI
    handler of ``native_step`` when it could be built, else ``mujoco.rollout``'s thread pool
    in a host callback; the same MuJoCo calls, the same results."""

    name = "native"

    def __init__(self, model: mujoco.MjModel, substeps: int, pelvis: str = QRIO.pelvis,
                 threads: int | None = None):
        from mujoco import rollout

        super().__init__(model, substeps, pelvis)
        self.threads = threads or native_threads()
        self._datas = [mujoco.MjData(model) for _ in range(self.threads)]
        self._pool = rollout.Rollout(nthread=self.threads if self.threads > 1 else 0)
        self._inline = rollout.Rollout(nthread=0)  # small batches: thread hand-offs cost more than they save
        self._buffers: dict[int, _RolloutBuffers] = {}
        # The FFI handler's: one MjData per thread, passed by the address of their addresses
        # (the handler runs one call at a time).
        self._ffi_datas = [mujoco.MjData(model) for _ in range(self.threads)]
        self._ffi_addresses = np.array([d._address for d in self._ffi_datas], np.int64)

    def step(self, state: CState, ctrl: jax.Array, active: jax.Array | None = None,
             pelvis_force: jax.Array | None = None) -> CState:
        """MuJoCo C inside XLA (``native_step``), on the threads from the batch that uses
        them, when the handler could be built; otherwise, and with ``pelvis_force``, the host
        callback."""
        batch = state.physics.shape[0]
        in_xla = _one_cpu_device() and pelvis_force is None
        target = native_step.step_handler() if in_xla else None
        if target is None:
            return super().step(state, ctrl, active, pelvis_force)
        outputs = tuple(jax.ShapeDtypeStruct(x.shape, jnp.float32) for x in state)
        force, velocity = self._power
        stepped = jax.ffi.ffi_call(target, outputs, input_output_aliases={0: 0, 1: 1, 2: 2},
                                   vmap_method="sequential")(
            state.physics, state.sensordata, state.positive_work, ctrl.astype(jnp.float32),
            jnp.ones(batch, bool) if active is None else active,
            model=np.int64(self.model._address), datas=np.int64(self._ffi_addresses.ctypes.data),
            threads=np.int64(self.threads_for(batch)), substeps=np.int64(self.substeps),
            force_address=np.int64(force.start), velocity_address=np.int64(velocity.start))
        return CState(*stepped)

    def _simulate(self, physics, ctrl, pelvis_force=None):
        batch = len(physics)
        spec = mujoco.mjtState.mjSTATE_CTRL
        if pelvis_force is not None:  # the control vector becomes (ctrl, xfrc_applied of every body)
            spec = _CTRL_AND_XFRC
            xfrc = np.zeros((batch, self.model.nbody, 6))
            xfrc[:, self.pelvis, :3] = pelvis_force
            ctrl = np.concatenate([ctrl, xfrc.reshape(batch, -1)], axis=1)
        control = np.broadcast_to(ctrl[:, None, :], (batch, self.substeps, ctrl.shape[1])).astype(np.float64)
        runner, datas = (self._pool, self._datas) if self.threads_for(batch) > 1 else (self._inline, self._datas[:1])
        out = self._outputs(batch)
        # The checks and allocations of ``rollout`` cost as much as a tenth of the stepping at
        # the paper's batch; the arrays here are float64, C-ordered and of the right shapes.
        runner.rollout(out.models, datas, np.ascontiguousarray(physics, np.float64), control,
                       control_spec=int(spec), skip_checks=True, nstep=self.substeps,
                       initial_warmstart=out.warmstart, state=out.state, sensordata=out.sensordata)
        return out.state[:, -1].copy(), out.sensordata[:, -1].copy(), self._period_work(out.sensordata)

    def threads_for(self, batch: int) -> int:
        """All the threads from ``_ROBOTS_PER_THREAD`` robots per thread, else one."""
        return self.threads if batch >= _ROBOTS_PER_THREAD * self.threads else 1

    def _outputs(self, batch: int) -> _RolloutBuffers:
        if batch not in self._buffers:
            model = self.model
            self._buffers[batch] = _RolloutBuffers(
                models=[model] * batch, warmstart=np.zeros((batch, model.nv)),
                state=np.empty((batch, self.substeps, self.nstate)),
                sensordata=np.empty((batch, self.substeps, model.nsensordata)))
        return self._buffers[batch]


class _RolloutBuffers(NamedTuple):
    """What ``mujoco.rollout`` reads and writes for a batch of one size, kept between calls."""

    models: list
    warmstart: np.ndarray   # zeros: every control period starts the solver cold
    state: np.ndarray
    sensordata: np.ndarray


class MjxState(NamedTuple):
    data: Any                 # batched ``mjx.Data``
    positive_work: jax.Array  # (batch,) the actuators' over the last control period (``Sensors``)


class MjxEngine(Engine):
    """MuJoCo MJX (JAX implementation), ``vmap``-ed over the batch."""

    name = "mjx"

    def __init__(self, model: mujoco.MjModel, substeps: int, pelvis: str = QRIO.pelvis):
        with contextlib.redirect_stdout(io.StringIO()):  # mjx prints when the optional warp is absent
            from mujoco import mjx

        super().__init__(model, substeps, pelvis)
        self._mjx = mjx
        self.mjx_model = mjx.put_model(model, impl="jax")
        self._power = power_sensor_slices(model)

    def init(self, qpos: np.ndarray, batch: int) -> MjxState:
        mjx = self._mjx
        data = mjx.make_data(self.model, impl="jax")
        data = data.replace(qpos=jnp.asarray(qpos, data.qpos.dtype))
        data = jax.jit(mjx.forward)(self.mjx_model, data)
        return MjxState(data=jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), data),
                        positive_work=jnp.zeros(batch, data.qpos.dtype))

    def sensors(self, state: MjxState) -> Sensors:
        data = state.data
        return Sensors(qpos=data.qpos, qvel=data.qvel, sensordata=data.sensordata,
                       positive_work=state.positive_work)

    def step(self, state: MjxState, ctrl: jax.Array, active: jax.Array | None = None,
             pelvis_force: jax.Array | None = None) -> MjxState:
        mjx, model = self._mjx, self.mjx_model
        force, velocity = self._power
        dt = self.model.opt.timestep

        def one_robot(data, u):
            def physics_step(_, carry):
                data, work = carry
                data = mjx.step(model, data)
                return data, work + positive_power(data.sensordata[force], data.sensordata[velocity]) * dt
            return jax.lax.fori_loop(0, self.substeps, physics_step,
                                     (data.replace(ctrl=u), jnp.zeros((), data.qpos.dtype)))

        def one_pushed_robot(data, u, push):
            pushed = data.replace(xfrc_applied=data.xfrc_applied.at[self.pelvis, :3].set(push))
            stepped, work = one_robot(pushed, u)
            return stepped.replace(xfrc_applied=data.xfrc_applied), work

        if pelvis_force is None:
            stepped = MjxState(*self._map(one_robot, state.data, ctrl))
        else:
            stepped = MjxState(*self._map(one_pushed_robot, state.data, ctrl,
                                          pelvis_force.astype(state.data.qpos.dtype)))
        # In lockstep every robot costs the same, so idle ones are stepped and discarded.
        return stepped if active is None else tree_where(active, stepped, state)

    @staticmethod
    def _map(one_robot, *batched):
        """``vmap`` over the robots; on the CPU, in slices of at most ``_CPU_SLICE`` robots.

        jaxlib's CPU Cholesky (MJX's Newton solver) splits a large batch over XLA's thread
        pool from inside that pool and waits; with as few threads as this project's 2-core
        machines, two such calls can hold every thread and deadlock (seen from 256 robots).
        Batches of up to 32 never did, and in slices of 32, runs of 256 and 1,024 robots finish.
        """
        batch = batched[0].qpos.shape[0]
        if jax.default_backend() != "cpu" or batch <= _CPU_SLICE:
            return jax.vmap(one_robot)(*batched)
        slices = -(-batch // _CPU_SLICE)
        pad = slices * _CPU_SLICE - batch  # padded with copies of the first robots

        def split(x):  # explicit shapes: MJX data has empty leaves, which reshape(-1) rejects
            x = jnp.concatenate([x, x[:pad]]) if pad else x
            return x.reshape((slices, _CPU_SLICE) + x.shape[1:])

        stepped = jax.lax.map(lambda args: jax.vmap(one_robot)(*args), jax.tree.map(split, batched))
        return jax.tree.map(lambda x: x.reshape((slices * _CPU_SLICE,) + x.shape[2:])[:batch], stepped)


def make_engine(name: str, model: mujoco.MjModel, substeps: int, pelvis: str = QRIO.pelvis) -> Engine:
    """Build the engine called ``name`` (one of ``ENGINES``); ``pelvis`` names the body that
    ``Engine.step``'s ``pelvis_force`` pushes."""
    engines = {"mujoco": MujocoEngine, "native": NativeEngine, "mjx": MjxEngine}
    if name not in engines:
        raise ValueError(f"unknown engine {name!r}; choose one of {', '.join(ENGINES)}")
    return engines[name](model, substeps, pelvis)
