"""A child-sized humanoid: about 1.2 m tall, 27.8 kg, 0.48 m legs (``child.xml``, beside this
module), with proportions of its own: unequal thigh and shin, a longer trunk, longer feet,
heavier legs, and half the mass dynamic similarity would give.  Its MJCF's names follow
QRIO's convention (``RobotDescription``'s defaults).

Its gait constants are QRIO's carried over by dynamic similarity (``RobotDescription.gait``).
"""

from mjxcpg.robots.description import RobotDescription

CHILD = RobotDescription(
    name="child",
    package=__name__,
    mjcf="child.xml",
    # Arms slightly away from the body, elbows a little bent, as QRIO's.
    home_pose=(("l_shoulder_roll", 0.15), ("l_elbow", -0.3), ("r_shoulder_roll", -0.15), ("r_elbow", -0.3)),
    leg_length=0.48,
)
