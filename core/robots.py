"""Which simulated world serves each robot kind: the one rule the API, the worker and the scene share."""

from collections.abc import Mapping
from enum import StrEnum
from typing import Any


class RobotKind(StrEnum):
    KUKA_SIM = "kuka-sim"
    TURTLEBOT_SIM = "turtlebot-sim"
    KINOVA_SIM = "kinova-sim"
    KINOVA_REAL = "kinova-real"

    @property
    def simulated(self) -> bool:
        return self.value.endswith("-sim")


# The real arm's world is its simulated twin: where its policy is trained and evaluated.
WORLD_OF_KIND: dict[RobotKind, str] = {
    RobotKind.KUKA_SIM: "kuka",
    RobotKind.TURTLEBOT_SIM: "turtlebot",
    RobotKind.KINOVA_SIM: "kinova",
    RobotKind.KINOVA_REAL: "kinova",
}


def world_of_kind(kind: str) -> str:
    """The simulated world name ("kuka", "turtlebot", "kinova") for a robot kind, or a ValueError naming the
    known kinds."""
    try:
        return WORLD_OF_KIND[RobotKind(kind)]
    except ValueError:
        known = ", ".join(k.value for k in RobotKind)
        raise ValueError(f"no simulated world for robot kind {kind!r}; known kinds: {known}") from None


def worker_drives(kind: str, settings: Mapping[str, Any]) -> bool:
    """Whether the robot worker moves this robot (captures its views, tries commands with it): every simulated
    robot, and a real Kinova arm whose settings say where it is (`arm_ip`, see worker/real_arm.py)."""
    robot_kind = RobotKind(kind)
    return robot_kind.simulated or (robot_kind is RobotKind.KINOVA_REAL and bool(settings.get("arm_ip")))


def runs_on_robot_worker(kind: str) -> bool:
    """Whether this robot's training runs are taken by the robot worker rather than a training worker: a real
    arm's policy stage drives the arm itself (worker/real_arm.py), so its runs must run where the arm, its
    camera and Kinova's wheel are (the robot worker next to it); a simulated robot's runs go to any training
    worker."""
    return RobotKind(kind) is RobotKind.KINOVA_REAL
