"""What the rest of mjxcpg needs to know about a biped beyond its MJCF: the names of the bodies,
geoms, joints and sensors it reads, the arms' home pose, the leg length, and the gait constants.

The gait constants (CPG time constants, the leg-tip amplitudes A_x and A_z, the leg length
Z_0, the reward's height h', the hand-designed feedback's gain K, the fall height) were tuned
for QRIO; another robot gets them by dynamic similarity (``scaled_gait``): lengths scale with
the leg length L, times with sqrt(L / g).  The controller's reflex gains are dimensionless
(the extensor response divides by the robot's weight) and stay as they are.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import NamedTuple

import numpy as np


class LegGeometry(NamedTuple):
    """Link lengths of the sagittal leg (m): hip pitch axis to knee, knee to ankle."""

    thigh: float = 0.12
    shin: float = 0.12


@dataclasses.dataclass(frozen=True)
class GaitConstants:
    """The robot-specific numbers of the CPG gait (eqs 1-7) and of the reward (eq 27)."""

    tau: float          # CPG membrane time constant (s), eq 1
    tau_adapt: float    # CPG adaptation time constant (s), eq 2
    amp_x: float        # A_x (m), fore-aft leg-tip amplitude, eqs 6-7
    amp_z: float        # A_z (m), leg-length amplitude, eqs 4-5
    z0: float           # Z_0 (m), hip-to-ankle leg length while stepping
    h_ref: float        # h' (m), the pelvis height the reward asks for, eq 27
    hand_gain: float    # K (s) of the hand-designed a_5 = K d(theta_roll)/dt: a_5 is
    #                     dimensionless and a roll rate is 1 / time, so K is a time
    fall_height: float  # pelvis height (m) below which the robot has fallen


# The robot the published constants belong to: QRIO's hip-to-ankle length (thigh + shin) and
# the paper's numbers (Velocity Control and Experiments sections, and h' of eq 27); K and the
# fall height are this project's choices for it (docs/model.md).
REFERENCE_LEG_LENGTH = 0.24
REFERENCE_GRAVITY = 9.81
REFERENCE_GAIT = GaitConstants(tau=0.105, tau_adapt=0.132, amp_x=0.015, amp_z=0.005, z0=0.215, h_ref=0.272,
                               hand_gain=1.0, fall_height=0.20)


def scaled_gait(leg_length: float, gravity: float = REFERENCE_GRAVITY,
                reference: GaitConstants = REFERENCE_GAIT) -> GaitConstants:
    """The reference gait carried over to a leg of ``leg_length`` under ``gravity``.

    Dynamic similarity (equal Froude number): every length is multiplied by
    s = L / L_ref and every time by sqrt(s g_ref / g), the ratio of the pendulum times
    sqrt(L / g).  For the reference leg both factors are exactly 1, so the reference
    constants come back unchanged, bit for bit.
    """
    length = leg_length / REFERENCE_LEG_LENGTH
    time = math.sqrt(length * REFERENCE_GRAVITY / gravity)
    return GaitConstants(tau=reference.tau * time, tau_adapt=reference.tau_adapt * time,
                         amp_x=reference.amp_x * length, amp_z=reference.amp_z * length,
                         z0=reference.z0 * length, h_ref=reference.h_ref * length,
                         hand_gain=reference.hand_gain * time, fall_height=reference.fall_height * length)


class LegNames(NamedTuple):
    """MJCF names of one leg."""

    joints: tuple[str, ...]  # hip yaw, hip roll, hip pitch, knee, ankle pitch, ankle roll;
    #                          each driven by the position servo of the same name
    hip: str                 # body whose origin is the hip (where the hip axes meet)
    shin: str                # body whose origin is the knee
    ankle: str               # body whose origin is the ankle (the leg tip)
    sole: str                # box geom under the foot, unrotated, on the last leg body
    force: str               # sensor: the sole's vertical contact force


# The order in which every leg's joints are listed, and the inverse kinematics' output order.
LEG_JOINTS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")


def leg_names(side: str) -> LegNames:
    """The names of a leg in the convention both of this project's models follow: the side's
    prefix ("l" or "r") and an underscore before the part's name."""
    return LegNames(joints=tuple(f"{side}_{j}" for j in LEG_JOINTS), hip=f"{side}_hip", shin=f"{side}_shin",
                    ankle=f"{side}_ankle", sole=f"{side}_sole", force=f"{side}_sole_force")


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A biped: its MJCF and what the controller, estimator and engines look up in it."""

    name: str
    package: str | None                   # Python package that holds the MJCF (package data)
    mjcf: str                             # the MJCF's file name in that package; a path if package is None
    home_pose: tuple[tuple[str, float], ...]  # servo targets (rad) of joints the CPG does not move
    leg_length: float                     # hip to ankle with the leg straight (m): thigh + shin
    # The names below default to the convention both of this project's models follow.
    floor: str = "floor"                  # plane geom, tilted for slopes
    pelvis: str = "pelvis"                # body pushed by the evaluations' pelvis force
    gyro: str = "imu_gyro"                # sensor: the pelvis' angular velocity (its own frame)
    orientation: str = "imu_quat"         # sensor: the pelvis' orientation quaternion
    left: LegNames = leg_names("l")
    right: LegNames = leg_names("r")
    gravity: float = REFERENCE_GRAVITY

    @property
    def legs(self) -> tuple[LegNames, LegNames]:
        return self.left, self.right

    @property
    def gait(self) -> GaitConstants:
        return scaled_gait(self.leg_length, self.gravity)

    def mjcf_resource(self) -> Traversable:
        return importlib.resources.files(self.package) / self.mjcf if self.package else Path(self.mjcf)


def scaled_mjcf(source: Path, length: float, mass: float) -> str:
    """The MJCF at ``source`` with every length times ``length`` and every mass times ``mass``,
    the floor plane apart: servo stiffness and torque limits follow the torque scale m g L,
    joint damping m g L times the time scale sqrt(L), the armature m L^2, so that every
    servo's natural frequency is sqrt(g / L) times the original's and its damping ratio the
    original's.  With ``mass`` = ``length`` ** 3 the robot is dynamically similar to the
    original (``scaled_gait``), up to the physics step and the contacts' time constants,
    which stay as they are."""
    import mujoco  # here, not at import: mjxcpg's render command sets MuJoCo's OpenGL first

    spec = mujoco.MjSpec.from_file(str(source))
    torque, time = mass * length, math.sqrt(length)
    for body in spec.bodies[1:]:
        body.pos = np.asarray(body.pos) * length
    for geom in spec.geoms:
        if geom.type != mujoco.mjtGeom.mjGEOM_PLANE:
            geom.size, geom.pos = np.asarray(geom.size) * length, np.asarray(geom.pos) * length
            geom.mass *= mass
            if not np.isnan(geom.fromto).any():
                geom.fromto = np.asarray(geom.fromto) * length
    for site in spec.sites:
        site.size, site.pos = np.asarray(site.size) * length, np.asarray(site.pos) * length
    for joint in spec.joints:
        joint.damping, joint.armature = joint.damping * torque * time, joint.armature * mass * length ** 2
    for actuator in spec.actuators:
        actuator.gainprm[0] *= torque
        actuator.biasprm[1] *= torque
        actuator.forcerange = np.asarray(actuator.forcerange) * torque
    return spec.to_xml()
