"""The simulated world behind the scene: a Gymnasium env of `sim/`, and what the 3D view needs to mirror it
(the robot's base pose and joint angles, the other bodies' shapes and poses) read from its PyBullet client."""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pybullet
import pybullet_data

import sim
from sim.mirror import BodyMirror

_ASSETS = Path(sim.__file__).resolve().parent / "assets"
DISPLAY_URDFS = {
    "kuka": Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf",
    "kinova": _ASSETS / "kinova_gen3" / "gen3_7dof.urdf",
    "turtlebot": _ASSETS / "turtlebot" / "turtlebot.urdf",
}
# Where the embedding sphere floats, beside each world, and its drawn radius in metres.
SPHERE_PLACES = {"kuka": ((0.55, -1.0, 0.25), 0.35), "kinova": ((0.55, -1.0, 0.25), 0.35)}
SPHERE_PLACE_DEFAULT = ((0.0, -3.2, 1.0), 0.8)


@dataclass
class BodyShape:
    """One visual shape of a non-robot body, drawn as a box or a sphere."""

    body: int
    link: int
    kind: str  # "box" | "sphere"
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    local_position: tuple[float, float, float]
    local_orientation: tuple[float, float, float, float]  # x, y, z, w


def wxyz(xyzw: Any) -> tuple[float, float, float, float]:
    x, y, z, w = xyzw
    return (float(w), float(x), float(y), float(z))


class SimWorld:
    """A running env plus read access to its PyBullet bodies."""

    def __init__(self, world: str, image_size: int = 96, seed: int = 0) -> None:
        self.world = world
        self.env = gymnasium.make(sim.world_id(world), image_size=image_size)
        self.rng = np.random.default_rng(seed)
        self.observation, self.info = self.env.reset(seed=seed)
        self.mirror: BodyMirror = self.env.unwrapped.mirror
        self.client, self.robot = self.mirror.client, self.mirror.robot
        self._revolute = self.mirror.joint_indices
        self._joint_by_name = {
            self.client.getJointInfo(self.robot, j)[1].decode(): j
            for j in range(self.client.getNumJoints(self.robot))
        }

    @property
    def intent_names(self) -> list[str]:
        return list(self.env.unwrapped.intent_names)

    @property
    def image(self) -> np.ndarray:
        return self.observation["image"]

    @property
    def state(self) -> np.ndarray:
        return np.asarray(self.observation["state"], dtype=np.float32)

    def reset(self) -> None:
        self.observation, self.info = self.env.reset(seed=int(self.rng.integers(2**31 - 1)))

    def step(self, action: np.ndarray) -> bool:
        """One env step; True when the episode ended."""
        self.observation, _, terminated, truncated, self.info = self.env.step(action)
        return bool(terminated or truncated)

    def explore_step(self) -> bool:
        """The robot moves at random as in snapshot capture (sim.explore)."""
        self.observation, _, terminated, truncated, self.info = self.env.unwrapped.random_view_step(self.rng)
        ended = bool(terminated or truncated)
        if ended:
            self.reset()
        return ended

    def robot_base(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        position, orientation = self.client.getBasePositionAndOrientation(self.robot)
        return tuple(float(v) for v in position), wxyz(orientation)  # type: ignore[return-value]

    def joint_values(self, names: tuple[str, ...]) -> np.ndarray:
        """Angles for the display URDF's actuated joints: by name when the simulated body has them (Kinova,
        TurtleBot), else in order of the simulated body's movable joints (Kuka: SDF model vs display URDF)."""
        if all(name in self._joint_by_name for name in names):
            indices = [self._joint_by_name[name] for name in names]
        else:
            indices = self._revolute[: len(names)]
        values = [self.client.getJointState(self.robot, j)[0] for j in indices]
        values += [0.0] * (len(names) - len(values))
        return np.asarray(values, dtype=np.float64)

    def other_shapes(self) -> list[BodyShape]:
        """Boxes and spheres standing in for every other body (table, blocks, room, objects)."""
        shapes, meshes_seen = [], set()
        for index in range(self.client.getNumBodies()):
            body = self.client.getBodyUniqueId(index)
            if body == self.robot:
                continue
            for data in self.client.getVisualShapeData(body):
                if data[2] == pybullet.GEOM_MESH:  # one bounding box per link, however many mesh parts
                    if (body, data[1]) in meshes_seen:
                        continue
                    meshes_seen.add((body, data[1]))
                shape = _shape_of(self.client, body, data)
                if shape is not None:
                    shapes.append(shape)
        return shapes

    def link_pose(self, body: int, link: int) -> tuple[np.ndarray, np.ndarray]:
        position, orientation = self.mirror.link_pose(body, link)
        return np.asarray(position), np.asarray(orientation)

    def follow(self, state: dict[str, Any]) -> None:
        """Pose the robot and the bodies as another instance of this world is (its `mirror_state()`). The
        env's own bookkeeping is not touched: `reset()` before stepping it again."""
        self.mirror.apply(state)

    def close(self) -> None:
        self.env.close()


def _shape_of(client: Any, body: int, data: tuple) -> BodyShape | None:
    link, geometry, dimensions, _mesh_file, position, orientation, rgba = (
        data[1],
        data[2],
        data[3],
        data[4],
        data[5],
        data[6],
        data[7],
    )
    if rgba[3] <= 0.01:
        return None
    if geometry == pybullet.GEOM_BOX:
        size = tuple(float(v) for v in dimensions[:3])
        kind = "box"
    elif geometry == pybullet.GEOM_SPHERE:
        size = (float(dimensions[0]),) * 3
        kind = "sphere"
    elif geometry in (pybullet.GEOM_CYLINDER, pybullet.GEOM_CAPSULE):
        height, radius = float(dimensions[0]), float(dimensions[1])
        size, kind = (2 * radius, 2 * radius, height), "box"
    elif geometry == pybullet.GEOM_MESH:
        low, high = client.getAABB(body, link)  # meshes are drawn as their world-aligned bounding box
        centre = [(a + b) / 2 for a, b in zip(low, high, strict=True)]
        base, base_orientation = (
            client.getBasePositionAndOrientation(body) if link < 0 else client.getLinkState(body, link)[4:6]
        )
        inverse_position, inverse_orientation = client.invertTransform(base, base_orientation)
        local, local_orientation = client.multiplyTransforms(
            inverse_position, inverse_orientation, centre, [0, 0, 0, 1]
        )
        size = tuple(float(b - a) for a, b in zip(low, high, strict=True))
        return BodyShape(body, link, "box", size, tuple(rgba), tuple(local), tuple(local_orientation))  # type: ignore[arg-type]
    else:
        return None
    return BodyShape(body, link, kind, size, tuple(rgba), tuple(position), tuple(orientation))  # type: ignore[arg-type]
