"""Robot descriptions: one folder per robot, its MJCF beside a module of its names, home pose,
leg length and gait constants.  The bottom layer: it imports nothing else of mjxcpg.

``PLATFORMS`` names the robots a run, a walk or an evaluation may choose (the ``platform``
key of a config, ``--platform`` on the command line).
"""

from mjxcpg.robots.child import CHILD
from mjxcpg.robots.description import RobotDescription
from mjxcpg.robots.qrio import QRIO

PLATFORMS: dict[str, RobotDescription] = {robot.name: robot for robot in (QRIO, CHILD)}
DEFAULT_PLATFORM = QRIO.name


def platform(name: str) -> RobotDescription:
    """The robot called ``name``; a one-line ``ValueError`` naming the known ones otherwise."""
    if name not in PLATFORMS:
        raise ValueError(f"unknown platform {name!r}; choose one of {', '.join(PLATFORMS)}")
    return PLATFORMS[name]
