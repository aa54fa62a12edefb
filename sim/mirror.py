"""A world's pose, for a viewer that mirrors it: the robot's base pose, its joint values by name and the other
bodies' poses, as plain JSON-able data read from the world's PyBullet client (a few cheap queries).

`mirror_state()` on every simulated world returns it; `BodyMirror.apply` puts it into another instance of the
same world (same bodies, created in the same order), which is how the scene shows a training run's env 0.

    {"base": [[x, y, z], [qx, qy, qz, qw]],
     "joints": {"J0": 0.1, ...},                       # every revolute and prismatic joint of the robot
     "bodies": [[body, link, [x, y, z], [qx, qy, qz, qw]], ...]}   # every other drawn (body, link)
"""

from typing import Any

import pybullet as p

MOVABLE_JOINTS = (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC)


class BodyMirror:
    """Reads (and writes) the pose of one world: its robot body and every other body with a visual shape."""

    def __init__(self, client: Any, robot: int) -> None:
        self.client = client
        self.robot = robot
        joints = [client.getJointInfo(robot, j) for j in range(client.getNumJoints(robot))]
        movable = [info for info in joints if info[2] in MOVABLE_JOINTS]
        self.joint_names = [info[1].decode() for info in movable]
        self.joint_indices = [info[0] for info in movable]
        self._links: list[tuple[int, int]] | None = None  # found on first use: after every body exists

    @property
    def links(self) -> list[tuple[int, int]]:
        """(body, link) of every visual shape of the other bodies; link -1 is a body's base."""
        if self._links is None:
            bodies = [self.client.getBodyUniqueId(i) for i in range(self.client.getNumBodies())]
            found = {
                (body, data[1])
                for body in bodies
                if body != self.robot
                for data in self.client.getVisualShapeData(body)
            }
            self._links = sorted(found)
        return self._links

    def state(self) -> dict[str, Any]:
        position, orientation = self.client.getBasePositionAndOrientation(self.robot)
        values = [s[0] for s in self.client.getJointStates(self.robot, self.joint_indices)]
        return {
            "base": [list(position), list(orientation)],
            "joints": dict(zip(self.joint_names, values, strict=True)),
            "bodies": [[body, link, *self.link_pose(body, link)] for body, link in self.links],
        }

    def link_pose(self, body: int, link: int) -> tuple[list[float], list[float]]:
        """World position and orientation (x, y, z, w) of a body's base (link -1) or one of its links."""
        if link < 0:
            position, orientation = self.client.getBasePositionAndOrientation(body)
        else:
            position, orientation = self.client.getLinkState(body, link)[4:6]
        return list(position), list(orientation)

    def apply(self, state: dict[str, Any]) -> None:
        """Pose this world as `state` says. Joints and bodies this world lacks are skipped; links of other
        bodies follow their base (in our worlds no other body has a moving link)."""
        base_position, base_orientation = state["base"]
        self.client.resetBasePositionAndOrientation(self.robot, base_position, base_orientation)
        index_of = dict(zip(self.joint_names, self.joint_indices, strict=True))
        for name, value in state["joints"].items():
            if name in index_of:
                self.client.resetJointState(self.robot, index_of[name], float(value))
        known = {body for body, _link in self.links}
        for body, link, position, orientation in state["bodies"]:
            if link == -1 and body in known:
                self.client.resetBasePositionAndOrientation(body, position, orientation)


class MirroredWorld:
    """Mixin of the simulated worlds: `mirror_state()` for viewers (the scene follows training with it)."""

    mirror: BodyMirror

    def mirror_state(self) -> dict[str, Any]:
        """The robot's base pose and joint values and the other bodies' poses (see `sim.mirror`)."""
        return self.mirror.state()
