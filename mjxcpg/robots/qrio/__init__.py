"""QRIO-class humanoid: about 0.58 m tall, 6.7 kg, 0.24 m legs (``qrio.xml``, beside this module).

The robot of Endo et al. (2005): its gait constants are the published ones
(``description.REFERENCE_GAIT``), so ``QRIO.gait`` is them unchanged.
"""

from mjxcpg.robots.description import RobotDescription

QRIO = RobotDescription(
    name="qrio",
    package=__name__,
    mjcf="qrio.xml",
    # Arms slightly away from the body, elbows a little bent.
    home_pose=(("l_shoulder_roll", 0.15), ("l_elbow", -0.3), ("r_shoulder_roll", -0.15), ("r_elbow", -0.3)),
    leg_length=0.24,
)
