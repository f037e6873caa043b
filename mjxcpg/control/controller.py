"""The CPG walking controller for one robot: reflexes (eq 9), the CPG, leg targets, IK.

``control_step`` maps the robot's observation and the propulsive feedback a_5 (and, from a
two-output policy, a learned stepping feedback) to servo targets and the controller's next
state (``ControllerState``: the CPG's, and the slope reflex's integral).  It knows nothing of
the engine that runs the robot.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxcpg.control import cpg, ik
from mjxcpg.physics.model import Layout, Observation
from mjxcpg.robots.description import RobotDescription
from mjxcpg.robots.qrio import QRIO


@dataclasses.dataclass(frozen=True)
class ControllerParams:
    """Controller constants.  CPG amplitudes and reflex gains are the paper's; the defaults of
    the robot-specific ones (time constants, A_x, A_z, Z_0, K) are QRIO's gait (``of``).

    ``vsr_sign`` fixes the sign convention of theta_roll in eq (9), which the paper does not
    print: +1 uses the right-handed roll about the forward axis (left side up is positive).
    """

    cpg: cpg.CPGParams = cpg.CPGParams()
    amp_x: float = QRIO.gait.amp_x  # A_x (m), eqs 6-7
    amp_z: float = QRIO.gait.amp_z  # A_z (m), eqs 4-5
    x0: float = 0.0                 # X_0 (m): ankles under the hips
    z0: float = QRIO.gait.z0        # Z_0 (m): hip-to-ankle leg length
    h_er: float = 0.4               # extensor response gain, eq 9
    h_vsr: float = 0.3              # vestibulo-spinal reflex gain, eq 9 (paper: 1.8; see docs)
    vsr_sign: float = -1.0
    control_dt: float = 0.008       # control period (s)
    cpg_substeps: int = 8           # Euler steps of the CPG per control period
    hand_gain: float = QRIO.gait.hand_gain  # K (s) of the hand-designed a_5 = K d(theta_roll)/dt
    hand_fade_seconds: float = 0.0  # the hand-designed feedback's fade-out over a walk's start (s); 0: off
    h_heading: float = 0.0          # heading reflex gain (rad of turn per step per rad of heading); 0: off
    max_turn: float = 0.3           # the heading reflex's turn limit (rad per step), inside the hips' +-0.5
    heading_command: float = 0.0    # the heading the reflex steers to (rad, positive to the left)
    slope_reflex_s: float = 0.0     # the slope reflex's time constant (s); 0: off
    max_ankle_pitch: float = 0.2    # the slope reflex's limit (rad) on its ankle pitch offset
    slope_posture: float = 0.0      # of an incline, the pelvis turned toward upright (0: tilted with the floor)

    @classmethod
    def of(cls, robot: RobotDescription, **overrides) -> "ControllerParams":
        """The default controller with ``robot``'s gait constants (``RobotDescription.gait``)."""
        gait = robot.gait
        cpg_params = dataclasses.replace(cpg.CPGParams(), tau=gait.tau, tau_adapt=gait.tau_adapt)
        return cls(**{"cpg": cpg_params, "amp_x": gait.amp_x, "amp_z": gait.amp_z, "z0": gait.z0,
                      "hand_gain": gait.hand_gain, **overrides})


class ControllerState(NamedTuple):
    """What the controller carries from one control period to the next."""

    cpg: cpg.CPGState
    ankle_pitch: jax.Array  # the slope reflex's offset of both ankles' pitch targets (rad)


def init_state() -> ControllerState:
    """The state every walk and trial starts from: the CPG's start, no ankle offset."""
    return ControllerState(cpg=cpg.init_state(), ankle_pitch=jnp.float32(0.0))


def reflex_feedback(params: ControllerParams, layout: Layout, obs: Observation) -> jax.Array:
    """Eq (9): a_1 = h_ER (f_z^r - f_z^l) / mg + h_VSR theta_roll."""
    extensor_response = params.h_er * (obs.force_right - obs.force_left) / layout.weight
    vestibulospinal_reflex = params.h_vsr * params.vsr_sign * obs.roll
    return extensor_response + vestibulospinal_reflex


def roll_rate_feedback(obs: Observation, gain: jax.Array) -> jax.Array:
    """a_5 = gain d(theta_roll)/dt, the form of the hand-designed feedback with any gain."""
    return gain * obs.gyro[0]


def hand_feedback(params: ControllerParams, obs: Observation) -> jax.Array:
    """The hand-designed propulsive feedback that starts every trial: a_5 = K d(theta_roll)/dt.

    Roll rate is in phase with the lateral weight shift, so feeding it to the quad-element
    oscillator pulls the swing leg forward while the body rolls onto the stance leg.
    """
    return roll_rate_feedback(obs, params.hand_gain)


def hand_fade(params: ControllerParams, obs: Observation, step: jax.Array) -> jax.Array:
    """The hand-designed start's fade-out: ``hand_feedback`` weighted 1 - t / hand_fade_seconds
    (t = ``step`` control periods from standing, weight 0 from then on), added to a_5 after
    the hand-over.

    Not in the paper.  A policy that takes over within the first second meets the CPG before
    its stepping and propulsive oscillators have locked in phase; the hand-designed gain
    locks them the forward way, while the learned policies' weaker roll-rate gain lets some
    lock backward, and the robot walks backward and often falls (docs/learning.md).
    """
    weight = jnp.clip(1.0 - step * params.control_dt / params.hand_fade_seconds, 0.0, 1.0)
    return weight * hand_feedback(params, obs)


def split_feedback(action: jax.Array) -> tuple[jax.Array, jax.Array | None]:
    """A feedback's (a_5, learned stepping feedback): ``action`` is a_5 alone (shape (), the
    paper's; stepping None) or the pair (shape (2,), a policy with ``LearnerParams.outputs`` = 2)."""
    action = jnp.asarray(action)
    return (action, None) if action.ndim == 0 else (action[0], action[1])


def after_hand_start(params: ControllerParams, obs: Observation, action: jax.Array, step: jax.Array,
                     hand_steps: jax.Array | int) -> jax.Array:
    """The feedback that drives the CPG when ``action`` (a_5, or a_5 and the stepping
    feedback: ``split_feedback``) acts after the hand-designed start: the hand-designed a_5
    and no stepping feedback for the first ``hand_steps`` control periods (``step`` counts them
    from standing), ``action`` after, plus the ``hand_fade`` on a_5 if ``hand_fade_seconds`` > 0."""
    a5, stepping = split_feedback(action)
    if params.hand_fade_seconds:
        a5 = a5 + hand_fade(params, obs, step)
    if not (isinstance(hand_steps, int) and hand_steps == 0):
        a5 = jnp.where(step < hand_steps, hand_feedback(params, obs), a5)
        if stepping is not None:
            stepping = jnp.where(step < hand_steps, 0.0, stepping)
    return a5 if stepping is None else jnp.stack([a5, stepping])


def heading_reflex(params: ControllerParams, obs: Observation) -> jax.Array:
    """The heading reflex: the turn of each step, -h_heading times the heading error (the
    pelvis' yaw less ``heading_command``), within +-max_turn (rad; ``joint_targets`` makes
    it a turn).

    Not in the paper, whose robot walks a few metres: with no sense of its heading, a gait
    whose steps turn a little accumulates it without bound.  0 by default.
    """
    error = obs.heading - params.heading_command
    return jnp.clip(-params.h_heading * error, -params.max_turn, params.max_turn)


def slope_reflex(params: ControllerParams, ankle_pitch: jax.Array, obs: Observation) -> jax.Array:
    """The slope reflex: d(ankle pitch offset)/dt = theta_pitch / slope_reflex_s, within
    +-max_ankle_pitch, added to both ankles' pitch targets.

    The inverse kinematics keeps the soles parallel to the pelvis, so on an incline the
    robot walks pitched with the floor (back uphill, forward downhill).  Integrating the
    pelvis pitch into the ankles turns the soles against it until the pelvis is level and
    the soles lie on the floor, over a few seconds (slower than a step, so the pitch of
    each step averages out).  Not in the paper; off (the offset stays 0) by default: on the
    hand-designed gait it widens the uphill range but narrows the downhill one.
    """
    if params.slope_reflex_s == 0.0:
        return ankle_pitch
    rate = obs.pitch / params.slope_reflex_s
    return jnp.clip(ankle_pitch + params.control_dt * rate, -params.max_ankle_pitch, params.max_ankle_pitch)


def posture_ankle_pitch(params: ControllerParams, layout: Layout) -> float:
    """The slope posture: on an incline of angle s, both ankles held pitched by -slope_posture
    x s, so that a robot standing with its soles flat on the floor has its pelvis turned by
    slope_posture x s from tilted-with-the-floor toward upright (``sim.standing_qpos`` starts it
    so).  A robot reads s from its IMU at rest; here it is the floor's (``Layout.slope_tan``).

    Tilted with the floor, the robot leans back uphill by the slope and falls backward from
    +5 degrees before its gait settles; upright, it falls forward downhill from -4; halfway
    (0.5) walks both ways (docs/evaluation.md).  Not in the paper; 0 by default.
    """
    return -params.slope_posture * math.atan(layout.slope_tan)


def joint_targets(params: ControllerParams, layout: Layout, q: jax.Array,
                  turn: jax.Array | float = 0.0, ankle_pitch: jax.Array | float = 0.0) -> jax.Array:
    """Eqs (4)-(7) and inverse kinematics: neuron outputs to the servo targets (nu,), a turn
    of ``turn`` (rad) per step, and both ankles pitched by ``ankle_pitch`` (rad; the slope reflex).

    A turn yaws each leg's hip by ``turn`` times its lift (q1 - q2 for the left leg, q2 - q1
    for the right, within [0, 1]): the swing foot lands yawed by ``turn``, and as it takes
    the weight and its lift returns to 0 the pelvis yaws after it.  The same yaw of both
    hips at once would turn the pelvis only while it changes.
    """
    targets = cpg.leg_targets(q, params.x0, params.z0, params.amp_x, params.amp_z)
    left = ik.leg_joint_angles(targets.left_x, targets.left_z, layout.geometry)
    right = ik.leg_joint_angles(targets.right_x, targets.right_z, layout.geometry)
    stepping = q[0] - q[1]
    left = left.at[0].set(turn * jnp.clip(stepping, 0.0, 1.0)).at[4].add(ankle_pitch)
    right = right.at[0].set(turn * jnp.clip(-stepping, 0.0, 1.0)).at[4].add(ankle_pitch)
    ctrl = jnp.asarray(layout.ctrl_home, dtype=left.dtype)
    ctrl = ctrl.at[jnp.array(layout.left_leg_ctrl)].set(left)
    return ctrl.at[jnp.array(layout.right_leg_ctrl)].set(right)


def control_step(params: ControllerParams, layout: Layout, state: ControllerState,
                 obs: Observation, action: jax.Array,
                 propulsion_offset: jax.Array | float = 0.0) -> tuple[ControllerState, jax.Array]:
    """One control period: reflexes and a_5 drive the CPG; its outputs become servo targets.

    ``action`` is a_5, or a_5 and a learned stepping feedback (``split_feedback``), which is
    added to eq (9)'s a_1 and so enters neurons 1-4 as a_1 does (eq 8).

    ``propulsion_offset`` offsets the target of (q5 - q6) in eqs (6)-(7), not the CPG
    itself (the return map's perturbation): p_x^l = X_0 - A_x (q5 - q6 + offset) and
    p_x^r = X_0 + A_x (q5 - q6 + offset), so the legs' fore-aft tip offset (right minus
    left) changes by 2 A_x offset.
    """
    a5, stepping = split_feedback(action)
    a1 = reflex_feedback(params, layout, obs)
    if stepping is not None:
        a1 = a1 + stepping
    feedback = cpg.feedback_vector(a1, a5)
    cpg_state = cpg.integrate(params.cpg, state.cpg, feedback, params.control_dt, params.cpg_substeps)
    ankle_pitch = slope_reflex(params, state.ankle_pitch, obs)
    q = cpg.output(cpg_state).at[4].add(propulsion_offset)
    ctrl = joint_targets(params, layout, q, heading_reflex(params, obs),
                         ankle_pitch + posture_ankle_pitch(params, layout))
    return ControllerState(cpg_state, ankle_pitch), ctrl
