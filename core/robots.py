"""Which simulated world serves each robot kind: the one rule the API, the worker and the scene share."""

from enum import StrEnum


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
