"""A simulated world as the 3D view shows it: the ground, the robot (its display URDF, posed from the
simulation's joints), boxes and spheres for every other body, and where the camera starts."""

import viser
from viser.extras import ViserUrdf

from scene.world import DISPLAY_URDFS, BodyShape, SimWorld, wxyz

BODIES_EVERY = 10  # frames between moves of the other bodies: they move only when the robot pushes them


class WorldView:
    def __init__(self, server: viser.ViserServer) -> None:
        self.server = server
        self.urdf: ViserUrdf | None = None
        self.shapes: list[BodyShape] = []

    def build(self, world: SimWorld) -> None:
        """Replace whatever the scene showed with `world` (the sphere is placed again afterwards)."""
        scene = self.server.scene
        scene.reset()
        scene.add_grid("/ground", width=4, height=4, cell_size=0.25, position=(0, 0, -0.13))
        scene.add_frame("/robot", show_axes=False)
        self.urdf = ViserUrdf(self.server, DISPLAY_URDFS[world.world], root_node_name="/robot")
        self.shapes = world.other_shapes()
        for index, shape in enumerate(self.shapes):
            colour = tuple(int(255 * c) for c in shape.rgba[:3])
            self._place_body(world, shape.body, shape.link)
            path = f"/world/body{shape.body}_{shape.link}/shape{index}"
            if shape.kind == "sphere":
                scene.add_icosphere(path, radius=shape.size[0], color=colour, position=shape.local_position)
            else:
                scene.add_box(
                    path,
                    dimensions=shape.size,
                    color=colour,
                    position=shape.local_position,
                    wxyz=wxyz(shape.local_orientation),
                )
        arena = world.world == "turtlebot"
        self.server.initial_camera.position = (3.5, -4.5, 3.5) if arena else (2.2, -1.6, 1.4)
        self.server.initial_camera.look_at = (0, -1.0, 0.3) if arena else (0.4, -0.4, 0.1)

    def pose_robot(self, world: SimWorld, frame: int) -> None:
        """The robot as the simulation has it now; the other bodies too on every `BODIES_EVERY`th frame."""
        if self.urdf is None:
            return
        position, orientation = world.robot_base()
        with self.server.atomic():
            self.server.scene.add_frame("/robot", position=position, wxyz=orientation, show_axes=False)
            self.urdf.update_cfg(world.joint_values(self.urdf.get_actuated_joint_names()))
            if frame % BODIES_EVERY == 0 or frame < 2:
                self.move_bodies(world)

    def move_bodies(self, world: SimWorld) -> None:
        for body, link in {(s.body, s.link) for s in self.shapes}:
            self._place_body(world, body, link)

    def _place_body(self, world: SimWorld, body: int, link: int) -> None:
        position, orientation = world.link_pose(body, link)
        self.server.scene.add_frame(
            f"/world/body{body}_{link}",
            position=tuple(position),
            wxyz=wxyz(orientation),
            show_axes=False,
        )
