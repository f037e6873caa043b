"""Many learners in lockstep: ``vmap`` over learners, ``lax.scan`` over control steps,
a thin Python loop over chunks for progress and checkpoints (after PureJaxRL's layout)."""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any, Callable, NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg import robots
from mjxcpg.control.controller import ControllerParams
from mjxcpg.jaxutil import xla
from mjxcpg.learning import actor_critic as ac
from mjxcpg.learning import ngnet
from mjxcpg.learning.learner import (LearnerState, Task, TrialParams, home_ctrl, init_learner, is_done, learner_step,
                            period_draws)
from mjxcpg.control.sim import Simulation, make_simulation


class RunState(NamedTuple):
    physics: Any          # the engine's batched state
    learners: LearnerState  # batched over learners


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What a run is: one learner per (k_s, seed) pair."""

    k_s: tuple[float, ...]
    seeds: tuple[int, ...]
    # Energy reward gains k_E, one per learner (``mjxcpg.learning.learner.reward``); None: no
    # energy term for any, the paper's reward.
    k_e: tuple[float, ...] | None = None
    # The robot (mjxcpg.robots.PLATFORMS).  ``for_platform`` gives its controller and reward
    # height; a config that names a platform starts from those (mjxcpg.training.config).
    platform: str = robots.DEFAULT_PLATFORM
    learner: ac.LearnerParams = ac.LearnerParams()
    trial: TrialParams = TrialParams()
    controller: ControllerParams = ControllerParams()
    physics_dt: float | None = None
    basis_grid: int = 15
    basis_width: float = 1.0
    chunk_seconds: float = 20.0

    @property
    def batch(self) -> int:
        return len(self.k_s)

    @staticmethod
    def platform_defaults(platform: str) -> dict:
        """The fields that depend on the robot: its controller and reward height (from its
        gait constants, ``RobotDescription.gait``)."""
        robot = robots.platform(platform)
        return {"platform": platform, "controller": ControllerParams.of(robot),
                "trial": TrialParams(h_ref=robot.gait.h_ref)}

    @classmethod
    def for_platform(cls, platform: str, **fields) -> "RunSpec":
        """A spec of ``platform`` (``platform_defaults``) with ``fields`` given."""
        return cls(**(cls.platform_defaults(platform) | fields))

    def simulation(self, engine: str | None = None, **build) -> Simulation:
        """This run's simulation on ``engine``; ``build``: other fields of ``make_simulation``."""
        return make_simulation(engine, params=self.controller, physics_dt=self.physics_dt,
                               platform=self.platform, **build)


def make_task(sim: Simulation, spec: RunSpec) -> Task:
    return Task(layout=sim.layout, controller=sim.params, learner=spec.learner,
                trial=spec.trial, basis=ngnet.make_basis(spec.basis_grid, width_scale=spec.basis_width))


def init_run(sim: Simulation, task: Task, spec: RunSpec) -> RunState:
    gains = spec.k_e if spec.k_e is not None else (None,) * spec.batch
    learners = [init_learner(task, k, s, e) for k, s, e in zip(spec.k_s, spec.seeds, gains)]
    return RunState(physics=sim.engine.init(sim.qpos0, spec.batch),
                    learners=jax.tree.map(lambda *xs: jnp.stack(xs), *learners))


class Transition(NamedTuple):
    """What a chunk asked its engine in one control period (``make_chunk(record=True)``)."""

    physics: Any       # the batched engine state stepped, after the period's resets
    ctrl: jax.Array    # (batch, nu) servo targets
    active: jax.Array  # (batch,) robots stepped


def make_chunk(sim: Simulation, task: Task, steps: int, record: bool = False) -> Callable:
    """A jitted ``chunk(run, initial) -> run`` advancing every learner by ``steps`` control
    periods; with ``record``, ``-> (run, transitions)``, a ``Transition`` per period stacked
    on a leading axis (the benchmarks replay them as physics alone)."""
    engine = sim.engine
    home = home_ctrl(task)
    step_learners = jax.vmap(functools.partial(learner_step, task), in_axes=(0, 0, None, 0))
    learners_done = jax.vmap(functools.partial(is_done, task))
    # (steps, batch) draws: every period's random numbers, drawn before the loop
    draws_of = functools.partial(period_draws, outputs=task.learner.outputs)
    chunk_draws = jax.vmap(jax.vmap(draws_of), in_axes=(None, 0))

    def body(carry: tuple[RunState, Any], draws):
        run, initial = carry
        learners, ctrl, ended = step_learners(run.learners, engine.sensors(run.physics), home, draws)
        physics = engine.reset(run.physics, initial, ended)
        active = ~learners_done(learners)  # a finished learner's robot stands still: the C engines skip it
        stepped = RunState(engine.step(physics, ctrl, active), learners)
        return (stepped, initial), Transition(physics, ctrl, active) if record else None

    @xla.jit
    def chunk(run: RunState, initial: Any):
        periods = run.learners.period + jnp.arange(steps)[:, None]
        draws = chunk_draws(run.learners.key, periods)
        (run, _), transitions = jax.lax.scan(body, (run, initial), draws)
        return (run, transitions) if record else run

    return chunk


def _devices_of(x: Any) -> frozenset | None:
    """The devices an array lives on (None for a host array)."""
    return frozenset(x.sharding.device_set) if hasattr(x, "sharding") else None


class AheadOfTime:
    """A jitted function of array arguments, traced and compiled ahead of time
    (``jit(...).lower(...).compile()``) for each argument structure, type (shape, dtype,
    weak type) and set of devices it is called with, so that a caller's timing can leave
    that out: ``compile_seconds`` is what all the tracing and compiling so far took.
    Arguments on the same devices must be sharded alike or equivalently (on one device all
    are), as the loop's are: a compiled function refuses others.  Before it compiles, it
    waits for its arguments: work still computing them is not counted as compilation."""

    def __init__(self, jitted: Callable):
        self._jitted = jitted
        self._compiled: dict[tuple, Callable] = {}
        self.compile_seconds = 0.0

    def __call__(self, *args: Any) -> Any:
        leaves, structure = jax.tree.flatten(args)
        key = (structure, tuple((jax.typeof(x), _devices_of(x)) for x in leaves))
        if key not in self._compiled:
            jax.block_until_ready(args)
            self._compiled[key], seconds = xla.compile_timed(self._jitted, *args)
            self.compile_seconds += seconds
        return self._compiled[key](*args)


def learner_sharding(batch: int) -> jax.sharding.NamedSharding:
    """The learner axis split over as many of this process's JAX devices as divide the batch
    evenly (with several processes, each steps its own block of learners on its own).

    Each device keeps at least two learners: XLA compiles a batch of one differently (its
    degenerate axis is dropped), which would change results in the last bit.
    """
    devices = jax.local_devices()
    count = max(n for n in range(1, len(devices) + 1)
                if batch % n == 0 and (n == 1 or batch // n >= 2))
    mesh = jax.sharding.Mesh(np.array(devices[:count]), ("learners",))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("learners"))


def shard_learners(tree: Any, batch: int) -> Any:
    """Place every leaf (leading axis = learners) across the devices; a no-op on one device."""
    chex.assert_tree_shape_prefix(tree, (batch,))  # a leaf without the learner axis would be split wrongly
    return jax.device_put(tree, learner_sharding(batch))


def done_mask(task: Task, learners: LearnerState) -> np.ndarray:
    """Which learners have succeeded or used their budget, on the host (only the
    bookkeeping, which is all ``is_done`` reads, leaves the devices)."""
    return np.asarray(is_done(task, learners._replace(book=jax.device_get(learners.book))))


def compacted_size(active: int, batch: int) -> int:
    """The rows a chunk runs with ``active`` of ``batch`` learners unfinished: the smallest
    power of two (at least 2) that holds them, once it is at most half the batch; the whole
    batch before.

    A finished learner's weights and recorded trials are frozen, so leaving it out changes no
    result, only the cost: the controller and learner run for fewer robots.  (Its CPG, traces
    and counters still advance while it pads a chunk, so a checkpoint's finished learners
    differ in those with compaction.)  Sizes come from a short ladder (each is
    compiled once), and a batch never shrinks to one, which XLA compiles differently.
    """
    size = max(2, 1 << max(active - 1, 0).bit_length())
    return batch if size > batch // 2 else size


def compacted_rows(done: np.ndarray) -> np.ndarray | None:
    """The learners a chunk runs once many have finished (``compacted_size``): the
    unfinished ones, padded with finished ones; None for the whole batch."""
    batch, active = len(done), int(np.sum(~done))
    size = compacted_size(active, batch)
    if size == batch:
        return None
    return np.sort(np.concatenate([np.flatnonzero(~done), np.flatnonzero(done)[:size - active]]))


def learner_results(spec: RunSpec, learners: LearnerState) -> list[dict]:
    """Per learner: k_s, seed, success, trials to success, and per trial: the return, whether
    it fell, and after the hand-over the mean forward velocity, the mean |a_5| and the
    policy's sigma at the trial's end."""
    book = jax.device_get(learners.book)
    out = []
    for i in range(spec.batch):
        n = int(book.trial[i])
        tts = int(book.trials_to_success[i])
        energy = {} if spec.k_e is None else {"k_e": spec.k_e[i]}  # a run without: its results as before
        out.append({
            "k_s": spec.k_s[i], **energy, "seed": spec.seeds[i], "succeeded": tts >= 0,
            "trials_to_success": tts if tts >= 0 else None, "trials": n,
            "returns": [float(x) for x in book.returns[i][:n]],
            "falls": [bool(x) for x in book.falls[i][:n]],
            "velocities": [float(x) for x in book.velocities[i][:n]],
            "mean_abs_a5": [float(x) for x in book.mean_abs_a5[i][:n]],
            "sigmas": [float(x) for x in book.sigmas[i][:n]],
        })
    return out


def _put_rows(rows: np.ndarray, whole: jax.Array, part: jax.Array) -> np.ndarray:
    whole = np.array(whole)  # on the host: ``part`` may live on fewer devices than ``whole``
    whole[rows] = np.asarray(part)
    return whole


def _gather_rows(tree: Any, rows: jax.Array) -> Any:
    return jax.tree.map(lambda x: x[rows], tree)


def _scatter_rows(tree: Any, rows: jax.Array, part: Any) -> Any:
    return jax.tree.map(lambda whole, p: whole.at[rows].set(p), tree, part)


# Compiled ahead of time, as the chunk is: the loop leaves their compilation for a new batch
# size out of its pace too.  Plain ``jax.jit``: ``xla.jit`` at import would start XLA, and a
# gather needs none of its options.
_take_rows_on_device = AheadOfTime(jax.jit(_gather_rows))
_put_rows_on_device = AheadOfTime(jax.jit(_scatter_rows))


def compile_seconds(chunk: AheadOfTime) -> float:
    """The tracing and compiling of ``chunk`` and of the one-device row gathers and writes so
    far (``AheadOfTime``); on several devices ``take_rows`` indexes leaf by leaf, uncompiled
    ahead, so there its compilation stays in the pace."""
    return chunk.compile_seconds + _take_rows_on_device.compile_seconds + _put_rows_on_device.compile_seconds


def take_rows(tree: Any, rows: np.ndarray) -> Any:
    """Rows ``rows`` of every leaf: one jitted gather on one device (a leaf at a time costs
    a dispatch each); over several, an index of each leaf where it lives."""
    if jax.local_device_count() == 1:
        return _take_rows_on_device(tree, jnp.asarray(rows))
    return jax.tree.map(lambda x: x[rows], tree)


def put_rows(tree: Any, rows: np.ndarray, part: Any) -> Any:
    """``tree`` with rows ``rows`` of every leaf replaced by ``part``'s: one jitted scatter on
    one device; over several, on the host (the whole tree comes back from the devices)."""
    if jax.local_device_count() == 1:
        return _put_rows_on_device(tree, jnp.asarray(rows), part)
    return jax.tree.map(functools.partial(_put_rows, rows), tree, part)


def run_until_done(sim: Simulation, task: Task, spec: RunSpec, state: RunState,
                   on_chunk: Callable[[RunState, dict], None] | None = None) -> RunState:
    """Python loop over jitted chunks until every learner has succeeded or used its budget.

    ``on_chunk(state, counts)`` after each chunk: which learners are done after it (``done``,
    a mask), the chunk's pace (``robot_steps_per_s``) and the compilation for it
    (``compile_s``), which the pace leaves out.  Several processes each run this loop on
    their own block of learners (``mjxcpg.training.runs.learn_block``), with no exchange."""
    steps = round(spec.chunk_seconds / task.dt)
    chunk = AheadOfTime(make_chunk(sim, task, steps))
    initial = sim.engine.init(sim.qpos0, spec.batch)
    done = done_mask(task, state.learners)
    while not done.all():
        start, compiled_before = time.perf_counter(), compile_seconds(chunk)
        rows = compacted_rows(done)
        if rows is None:
            state = chunk(shard_learners(state, spec.batch), shard_learners(initial, spec.batch))
        else:
            part = chunk(shard_learners(take_rows(state, rows), len(rows)),
                         shard_learners(take_rows(initial, rows), len(rows)))
            state = put_rows(state, rows, part)
        state = jax.block_until_ready(state)
        compile_s = compile_seconds(chunk) - compiled_before
        stepping_s = time.perf_counter() - start - compile_s
        counts = {"robot_steps_per_s": np.sum(~done) * steps * sim.engine.substeps / stepping_s,
                  "compile_s": compile_s}
        done = done_mask(task, state.learners)
        if on_chunk is not None:
            on_chunk(state, counts | {"done": done})
    return state
