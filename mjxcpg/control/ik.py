"""Leg inverse kinematics: leg-tip (ankle) targets in the sagittal plane to joint angles.

The leg tip is the ankle joint centre, given relative to the hip (where the hip yaw, roll and
pitch axes meet) in the pelvis frame: ``x`` forward, ``z`` the leg length downward.  The
legs stay in their sagittal planes (hip yaw, hip roll and ankle roll are zero) and the sole
is kept parallel to the pelvis' horizontal plane, so to the floor while the pelvis is level.

Joint conventions (``mjxcpg/robots/qrio/qrio.xml``): pitch axes are +y, so a positive hip pitch swings
the foot backward, a positive knee flexes it, and zero everywhere is a straight leg.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxcpg.robots.description import LegGeometry


def leg_joint_angles(x: jax.Array, z: jax.Array, geometry: LegGeometry = LegGeometry()) -> jax.Array:
    """(hip yaw, hip roll, hip pitch, knee, ankle pitch, ankle roll) for an ankle at (x, -z).

    Targets beyond the leg's reach are pulled back onto its workspace boundary.
    """
    l1, l2 = geometry.thigh, geometry.shin
    reach_sq = jnp.clip(x * x + z * z, (l1 - l2) ** 2 + 1e-8, (l1 + l2) ** 2 * (1 - 1e-6))
    cos_knee = (reach_sq - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    knee = jnp.arccos(jnp.clip(cos_knee, -1.0, 1.0))
    leg_direction = jnp.arctan2(-x, z)          # angle of hip->ankle from straight down
    knee_offset = jnp.arctan2(l2 * jnp.sin(knee), l1 + l2 * jnp.cos(knee))
    hip_pitch = leg_direction - knee_offset
    ankle_pitch = -(hip_pitch + knee)           # sole level
    zero = jnp.zeros_like(knee)
    return jnp.stack([zero, zero, hip_pitch, knee, ankle_pitch, zero])


def ankle_position(angles: jax.Array, geometry: LegGeometry = LegGeometry()) -> jax.Array:
    """Forward kinematics of ``leg_joint_angles`` in the sagittal plane: (x, z) with z down."""
    hip_pitch, knee = angles[2], angles[3]
    x = -geometry.thigh * jnp.sin(hip_pitch) - geometry.shin * jnp.sin(hip_pitch + knee)
    z = geometry.thigh * jnp.cos(hip_pitch) + geometry.shin * jnp.cos(hip_pitch + knee)
    return jnp.stack([x, z])
