"""The embedding sphere: where the household's clips (f_S) and snapshots (f_I) land under the active VAR, each
snapshot coloured by the command it is closest to, and the markers for the current frame and the goal."""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import viser

from scene.household import HouseholdView, clip_audio, snapshot_images
from scene.world import SPHERE_PLACE_DEFAULT, SPHERE_PLACES

if TYPE_CHECKING:
    from scene.brain import Brain

PALETTE = [
    (230, 57, 70),
    (42, 157, 143),
    (69, 123, 157),
    (244, 162, 97),
    (131, 56, 236),
    (255, 183, 3),
    (29, 53, 87),
    (106, 153, 78),
]
UNASSIGNED = (150, 150, 150)
CURRENT_COLOUR = (255, 255, 255)  # the marker of what the robot sees now
GOAL_COLOUR = (255, 200, 0)  # the marker of the command being carried out


@dataclass
class SphereData:
    """Points on the sphere for one model version."""

    model_id: int
    snapshot_points: np.ndarray  # (N, 3)
    snapshot_commands: list[str | None]
    clip_points: dict[int, np.ndarray]

    def is_stale(self, model_id: int | None, view: HouseholdView) -> bool:
        """True when the model, the clips or the number of snapshots changed since these points."""
        return (
            self.model_id != model_id
            or set(self.clip_points) != {c.id for c in view.clips}
            or len(self.snapshot_commands) != len(view.snapshot_ids)
        )


def sphere_for(view: HouseholdView, brain: "Brain", model_id: int | None) -> SphereData:
    """Stored embeddings where a worker wrote them; the rest computed here with the active VAR."""
    clip_points = {c.id: view.clip_vectors[c.id] for c in view.clips if c.id in view.clip_vectors}
    missing_clips = [c.id for c in view.clips if c.id not in clip_points]
    if missing_clips:
        audio = clip_audio(missing_clips)
        ids = [i for i in missing_clips if i in audio]
        for clip_id, vector in zip(ids, brain.embed_clip_bytes([audio[i] for i in ids]), strict=True):
            if vector is not None:
                clip_points[clip_id] = vector
    stored = [view.snapshot_vectors[i] for i in view.snapshot_ids if i in view.snapshot_vectors]
    missing_snapshots = [i for i in view.snapshot_ids if i not in view.snapshot_vectors]
    images = snapshot_images(missing_snapshots)
    size = brain.image_size
    usable = [img for img in images.values() if img.shape[:2] == (size, size)]
    computed = list(brain.embed_images(np.stack(usable))) if usable else []
    points = np.asarray(stored + computed, dtype=np.float32).reshape(-1, 3)
    return SphereData(
        model_id=model_id or 0,
        snapshot_points=points,
        snapshot_commands=nearest_commands(points, clip_points, view),
        clip_points=clip_points,
    )


def nearest_commands(
    points: np.ndarray, clip_points: dict[int, np.ndarray], view: HouseholdView
) -> list[str | None]:
    """Each snapshot joins the command whose clips' mean direction it is closest to (its cluster)."""
    command_of = {c.id: c.command for c in view.clips}
    commands = sorted({command_of[i] for i in clip_points})
    if not commands or len(points) == 0:
        return [None] * len(points)
    centres = np.stack(
        [np.mean([clip_points[i] for i in clip_points if command_of[i] == c], axis=0) for c in commands]
    )
    centres /= np.linalg.norm(centres, axis=1, keepdims=True) + 1e-9
    nearest = np.argmax(points @ centres.T, axis=1)
    return [commands[k] for k in nearest]


def reward(image_embedding: np.ndarray, goal_embedding: np.ndarray) -> float:
    """The intrinsic reward r = f_I(I_t) · f_S(S_goal): how close the current frame lands to the goal."""
    return float(np.dot(image_embedding, goal_embedding))


def colour_of(command: str | None, commands: list[str]) -> tuple[int, int, int]:
    if command is None or command not in commands:
        return UNASSIGNED
    return PALETTE[commands.index(command) % len(PALETTE)]


def command_title(command: str) -> str:
    return command.split(":", 1)[1] if command.startswith("name:") else f"recording {command.split(':')[1]}"


class SphereView:
    """The sphere in the 3D view, floating beside a world: its surface, the points, the command labels and
    the markers of the current frame and the goal. `place()` again after the scene was reset."""

    def __init__(self, scene: viser.SceneApi) -> None:
        self.scene = scene
        self.radius = SPHERE_PLACE_DEFAULT[1]
        self.current_marker: viser.IcosphereHandle | None = None
        self.goal_marker: viser.IcosphereHandle | None = None
        self.drawn: SphereData | None = None  # the points now on show

    def place(self, world: str) -> None:
        centre, self.radius = SPHERE_PLACES.get(world, SPHERE_PLACE_DEFAULT)
        radius = self.radius
        self.scene.add_frame("/sphere", position=centre, show_axes=False)
        self.scene.add_icosphere(
            "/sphere/surface",
            radius=radius,
            color=(170, 185, 205),
            opacity=0.25,
            subdivisions=4,
            cast_shadow=False,
        )
        self.scene.add_label("/sphere/title", "embedding sphere", position=(0.0, 0.0, radius * 1.25))
        self.current_marker = self.scene.add_icosphere(
            "/sphere/current", radius=radius * 0.06, color=CURRENT_COLOUR, visible=False
        )
        self.goal_marker = self.scene.add_icosphere(
            "/sphere/goal", radius=radius * 0.08, color=GOAL_COLOUR, visible=False
        )

    def draw(self, sphere: SphereData | None, view: HouseholdView) -> None:
        """Snapshots (circles) and clips (diamonds) in their commands' colours, and each command's name."""
        self.drawn = sphere
        radius = self.radius
        commands = view.commands
        if sphere is None or len(sphere.snapshot_points) == 0:
            self._no_points("/sphere/snapshots")
        else:
            colours = np.array([colour_of(c, commands) for c in sphere.snapshot_commands], dtype=np.uint8)
            self.scene.add_point_cloud(
                "/sphere/snapshots",
                sphere.snapshot_points * radius,
                colors=colours,
                point_size=radius * 0.05,
                point_shape="circle",
            )
        if sphere is None or not sphere.clip_points:
            self._no_points("/sphere/clips")
            return
        command_of = {c.id: c.command for c in view.clips}
        ids = list(sphere.clip_points)
        points = np.stack([sphere.clip_points[i] for i in ids]) * radius * 1.04
        colours = np.array([colour_of(command_of.get(i), commands) for i in ids], dtype=np.uint8)
        self.scene.add_point_cloud(
            "/sphere/clips", points, colors=colours, point_size=radius * 0.12, point_shape="diamond"
        )
        for command in commands:
            members = [sphere.clip_points[i] for i in ids if command_of.get(i) == command]
            if members:
                centre = np.mean(members, axis=0)
                centre = centre / (np.linalg.norm(centre) + 1e-9) * radius * 1.18
                label = f"/sphere/commands/{abs(hash(command))}"
                self.scene.add_label(label, command_title(command), position=tuple(centre))

    def _no_points(self, name: str) -> None:
        self.scene.add_point_cloud(name, np.zeros((0, 3)), colors=(0, 0, 0), point_size=0.02)

    def show_markers(self, current: np.ndarray | None, goal: np.ndarray | None) -> None:
        """Where the current frame and the goal land; a marker without a point is hidden."""
        if self.current_marker is None or self.goal_marker is None:
            return
        if current is not None:
            self.current_marker.position = tuple(current * self.radius * 1.02)
        self.current_marker.visible = current is not None
        if goal is not None:
            self.goal_marker.position = tuple(goal * self.radius * 1.06)
        self.goal_marker.visible = goal is not None
