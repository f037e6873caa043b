"""A child-sized humanoid: about 1.2 m tall, 27.8 kg, 0.48 m legs (``child.xml``, beside this
module), with proportions of its own (unequal thigh and shin, narrower hips and feet relative
to its legs than QRIO's).

Its gait constants are QRIO's carried over by dynamic similarity (``RobotDescription.gait``).
"""

from mjxcpg.robots.description import RobotDescription, leg_names

CHILD = RobotDescription(
    name="child",
    package=__name__,
    mjcf="child.xml",
    floor="floor",
    pelvis="pelvis",
    gyro="imu_gyro",
    orientation="imu_quat",
    left=leg_names("l"),
    right=leg_names("r"),
    # Arms slightly away from the body, elbows a little bent, as QRIO's.
    home_pose=(("l_shoulder_roll", 0.15), ("l_elbow", -0.3), ("r_shoulder_roll", -0.15), ("r_elbow", -0.3)),
    leg_length=0.48,
)
