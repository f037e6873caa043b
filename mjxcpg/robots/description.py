"""What the rest of mjxcpg needs to know about a biped beyond its MJCF: the names of the bodies,
geoms, joints and sensors it reads, the arms' home pose, the leg length, and the gait constants.

The gait constants (CPG time constants, the leg-tip amplitudes A_x and A_z, the leg length
Z_0, the reward's height h') were tuned for QRIO by Endo et al.; another robot gets them by
dynamic similarity (``scaled_gait``): lengths scale with the leg length L, times with
sqrt(L / g).  The controller's reflex gains are dimensionless (the extensor response divides
by the robot's weight) and stay as they are.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
from importlib.resources.abc import Traversable
from typing import NamedTuple


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


# The robot the published constants belong to: QRIO's hip-to-ankle length (thigh + shin) and
# the paper's numbers (Velocity Control and Experiments sections, and h' of eq 27).
REFERENCE_LEG_LENGTH = 0.24
REFERENCE_GRAVITY = 9.81
REFERENCE_GAIT = GaitConstants(tau=0.105, tau_adapt=0.132, amp_x=0.015, amp_z=0.005, z0=0.215, h_ref=0.272)


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
                         z0=reference.z0 * length, h_ref=reference.h_ref * length)


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


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A biped: its MJCF and what the controller, estimator and engines look up in it."""

    name: str
    package: str                          # Python package that holds the MJCF (package data)
    mjcf: str                             # the MJCF's file name in that package
    floor: str                            # plane geom, tilted for slopes
    pelvis: str                           # body pushed by the evaluations' pelvis force
    gyro: str                             # sensor: the pelvis' angular velocity (its own frame)
    orientation: str                      # sensor: the pelvis' orientation quaternion
    left: LegNames
    right: LegNames
    home_pose: tuple[tuple[str, float], ...]  # servo targets (rad) of joints the CPG does not move
    leg_length: float                     # hip to ankle with the leg straight (m): thigh + shin
    gravity: float = REFERENCE_GRAVITY

    @property
    def legs(self) -> tuple[LegNames, LegNames]:
        return self.left, self.right

    @property
    def gait(self) -> GaitConstants:
        return scaled_gait(self.leg_length, self.gravity)

    def mjcf_resource(self) -> Traversable:
        return importlib.resources.files(self.package) / self.mjcf


def leg_names(side: str) -> LegNames:
    """The names of a leg in the convention both of this project's models follow: the side's
    prefix ("l" or "r") and an underscore before the part's name."""
    return LegNames(joints=tuple(f"{side}_{j}" for j in LEG_JOINTS), hip=f"{side}_hip", shin=f"{side}_shin",
                    ankle=f"{side}_ankle", sole=f"{side}_sole", force=f"{side}_sole_force")
