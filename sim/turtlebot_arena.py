"""TurtleBot arena: drive a TurtleBot 2 to the commanded object (cube, sphere, cone or cylinder).

A 2 m × 2 m walled arena holds four primitive objects at random, non-overlapping places. The robot sees the
world only through a forward camera on its top deck and knows its odometry (x, y, sin θ, cos θ).

How the robot moves: kinematically. Each step integrates the unicycle model (forward speed, turn rate) over
`CONTROL_PERIOD_S` in `SUBSTEPS` slices. A slice whose translation would make the Kobuki's footprint (a circle
of `ROBOT_RADIUS_M`) touch a wall or an object is blocked; turning in place is always allowed, as it is for
the real round robot. What a blocked slice does is the world's `contact` rule: "stop" (the default) drops its
translation, so a robot driving into something at any angle stands still; "slide" keeps the part of it along
the obstacle's surface, as the round bumper glides along a wall or an object it meets at an angle (head-on it
still stops). This is exact, deterministic and much faster than simulating wheel contacts, and
the policy only ever commands base velocities anyway. PyBullet holds the scene (the TurtleBot 2 URDF follows
the odometry pose) and renders the onboard camera with its tiny renderer.

Success: the target's surface within `SUCCESS_CLEARANCE_M` of the bumper and its centre within
±`SUCCESS_BEARING_DEG` of the heading, for `SUCCESS_HOLD_STEPS` consecutive steps (rule "hold"; once reached
it stays reached) or at the last step (rule "final"). Episodes always run `max_steps` steps (no early
termination, so an intrinsic reward is never cut short by succeeding). The env's own reward is sparse: 1.0 on
the step the episode succeeds (for "final": the last step), else 0.
"""

import math
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import gymnasium
import numpy as np
import pybullet as p
from gymnasium import spaces
from pybullet_utils.bullet_client import BulletClient

from sim.domain import DomainShift, RoomRanges, room_and_ranges, sample_room
from sim.mirror import BodyMirror, MirroredWorld
from sim.textures import texture_file

ASSETS_DIR = Path(__file__).resolve().parent / "assets"
TURTLEBOT_URDF = ASSETS_DIR / "turtlebot" / "turtlebot.urdf"

ARENA_HALF_M = 1.0  # inner faces of the walls at x, y = ±1 m
WALL_HEIGHT_M = 0.45
WALL_THICKNESS_M = 0.05

ROBOT_RADIUS_M = 0.176  # the Kobuki base collision cylinder in turtlebot.urdf
ROBOT_BASE_Z_M = 0.0102  # base_link height when the wheels (r = 0.035 m at z = 0.025 m) touch the floor

SPEED_RANGE_M_S = (-0.1, 0.25)
TURN_RANGE_RAD_S = (-1.1, 1.1)
CONTROL_PERIOD_S = 0.2
SUBSTEPS = 4
DEFAULT_MAX_STEPS = 100  # the oracle needs at most ~45 steps (200 episodes); learned policies get slack

# Onboard camera on the top deck, in the base frame; the robot's own body stays out of its view.
CAMERA_MOUNT_M = (0.12, 0.0, 0.30)
CAMERA_PITCH_DEG = -20.0
CAMERA_FOV_DEG = 60.0
CAMERA_NEAR_M = 0.02
CAMERA_FAR_M = 4.0

SUCCESS_CLEARANCE_M = 0.35  # target surface within this distance of the robot's bumper ...
SUCCESS_BEARING_DEG = 20.0  # ... and its centre within this angle of the heading ...
SUCCESS_HOLD_STEPS = 5  # ... for this many consecutive steps ("hold" rule)

HEARD_MAX_CLEARANCE_M = 0.6  # an object "dominates the view" only at close range ...
HEARD_MAX_BEARING_DEG = 25.0  # ... near the view centre ...
HEARD_MIN_PIXEL_SHARE = 0.08  # ... and covering a large share of the image
HEARD_RIVAL_RATIO = 0.5  # a second object at least half as large (in pixels) makes the view ambiguous

START_CLEARANCE_M = 0.4  # the robot starts out of reach of every object
OBJECT_GAP_M = 2 * ROBOT_RADIUS_M + 0.1  # room for the robot to pass between any two objects
LAYOUT_ATTEMPTS = 1000
CONTACT_RULES = ("stop", "slide")

DEFAULT_FLOOR_RGB = (0.72, 0.68, 0.62)
WALL_RGB = (0.9, 0.9, 0.86)
DEFAULT_LIGHT_DIRECTION = (0.4, -0.3, 1.0)
DEFAULT_LIGHT_AMBIENT = 0.6
DEFAULT_LIGHT_DIFFUSE = 0.35
LIGHT_SPECULAR = 0.05


@dataclass(frozen=True)
class ObjectSpec:
    name: str
    footprint_radius_m: float  # for a cube: half its side
    height_m: float
    rgb: tuple[float, float, float]


OBJECTS = (
    ObjectSpec("cube", 0.1, 0.2, (0.85, 0.15, 0.12)),
    ObjectSpec("sphere", 0.11, 0.22, (0.15, 0.68, 0.2)),
    ObjectSpec("cone", 0.12, 0.3, (0.15, 0.3, 0.85)),
    ObjectSpec("cylinder", 0.09, 0.26, (0.92, 0.78, 0.1)),
)


@dataclass
class PlacedObject:
    spec: ObjectSpec
    xy: np.ndarray  # (2,)
    yaw: float
    body_id: int = -1

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance in the floor plane from each point (N, 2) to this object's footprint (0 inside)."""
        offset = np.atleast_2d(points) - self.xy
        if self.spec.name != "cube":
            return np.maximum(np.linalg.norm(offset, axis=1) - self.spec.footprint_radius_m, 0.0)
        cos_yaw, sin_yaw = math.cos(self.yaw), math.sin(self.yaw)
        local = np.stack(
            [
                offset[:, 0] * cos_yaw + offset[:, 1] * sin_yaw,
                -offset[:, 0] * sin_yaw + offset[:, 1] * cos_yaw,
            ],
            axis=1,
        )
        outside = np.maximum(np.abs(local) - self.spec.footprint_radius_m, 0.0)
        return np.linalg.norm(outside, axis=1)


def wall_clearance(points: np.ndarray) -> np.ndarray:
    """Distance from each point (N, 2) to the nearest wall face (negative outside the arena)."""
    return ARENA_HALF_M - np.abs(np.atleast_2d(points)).max(axis=1)


def wrap_angle(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def action_to_velocity(action: np.ndarray) -> tuple[float, float]:
    """Map an action in [-1, 1]² linearly onto (forward speed m/s, turn rate rad/s)."""
    clipped = np.clip(np.asarray(action, dtype=np.float64).reshape(2), -1.0, 1.0)
    speed = SPEED_RANGE_M_S[0] + (clipped[0] + 1.0) / 2.0 * (SPEED_RANGE_M_S[1] - SPEED_RANGE_M_S[0])
    turn = TURN_RANGE_RAD_S[0] + (clipped[1] + 1.0) / 2.0 * (TURN_RANGE_RAD_S[1] - TURN_RANGE_RAD_S[0])
    return float(speed), float(turn)


def velocity_to_action(speed: float, turn: float) -> np.ndarray:
    speed = float(np.clip(speed, *SPEED_RANGE_M_S))
    turn = float(np.clip(turn, *TURN_RANGE_RAD_S))
    a_speed = 2.0 * (speed - SPEED_RANGE_M_S[0]) / (SPEED_RANGE_M_S[1] - SPEED_RANGE_M_S[0]) - 1.0
    a_turn = 2.0 * (turn - TURN_RANGE_RAD_S[0]) / (TURN_RANGE_RAD_S[1] - TURN_RANGE_RAD_S[0]) - 1.0
    return np.array([a_speed, a_turn], dtype=np.float32)


STAND_STILL_ACTION = velocity_to_action(0.0, 0.0)  # the zero action drives forward at 0.075 m/s


class TurtleBotArenaEnv(MirroredWorld, gymnasium.Env):
    """Gymnasium env `varbot/TurtleBotArena-v0` (see the module docstring).

    Observation: {"image": uint8 (image_size, image_size, 3), "state": float32 (x, y, sin θ, cos θ)}.
    Info: intent, heard (the object filling the view up close, or None), success, in_reach (the success
    condition this step), hold_steps, blocked (a wall or object stopped the robot, or made it slide: see
    `contact`), target_clearance (m), target_bearing (rad).

    `heard_reach_m` is how close an object must be for the view to be named after it (the simulated person's
    answer, and so the VAR's positives): by default `HEARD_MAX_CLEARANCE_M`, wider than the success distance;
    `SUCCESS_CLEARANCE_M` names only views from where the task counts as done.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": int(1 / CONTROL_PERIOD_S),
    }
    intent_names: ClassVar[list[str]] = [spec.name for spec in OBJECTS]
    num_intents: ClassVar[int] = len(OBJECTS)

    def __init__(
        self,
        image_size: int = 96,
        success_rule: str = "hold",
        domain: DomainShift | RoomRanges | None = None,
        max_steps: int | None = None,
        render_mode: str | None = None,
        contact: str = "stop",
        heard_reach_m: float = HEARD_MAX_CLEARANCE_M,
    ) -> None:
        if not isinstance(image_size, int) or not 16 <= image_size <= 512:
            raise ValueError(f"image_size must be an int between 16 and 512 pixels, got {image_size!r}")
        if success_rule not in ("hold", "final"):
            raise ValueError(f"success_rule must be 'hold' or 'final', got {success_rule!r}")
        if max_steps is not None and (not isinstance(max_steps, int) or max_steps < 1):
            raise ValueError(f"max_steps must be a positive int or None, got {max_steps!r}")
        if contact not in CONTACT_RULES:
            raise ValueError(f"contact must be one of {CONTACT_RULES}, got {contact!r}")
        if not isinstance(heard_reach_m, int | float) or not 0.0 < heard_reach_m <= 2 * ARENA_HALF_M:
            raise ValueError(
                f"heard_reach_m must be a distance in metres above 0 and at most {2 * ARENA_HALF_M}, "
                f"got {heard_reach_m!r}"
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.image_size = image_size
        self.success_rule = success_rule
        self.contact = contact
        self.heard_reach_m = float(heard_reach_m)
        self.domain, self.room_ranges = room_and_ranges(domain)  # ranges: a new room every reset
        self.max_steps = max_steps or DEFAULT_MAX_STEPS
        self.render_mode = render_mode

        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = spaces.Dict(
            {
                "image": spaces.Box(0, 255, (image_size, image_size, 3), np.uint8),
                "state": spaces.Box(-np.inf, np.inf, (4,), np.float32),
            }
        )

        self._client = BulletClient(p.DIRECT)
        self._textures: dict[str, int] = {}
        self._robot_id = self._load_robot()
        self._floor_id, self._wall_ids = self._build_room()
        self._object_ids = self._create_objects()
        self.mirror = BodyMirror(self._client, self._robot_id)
        self._objects: list[PlacedObject] = []
        self._projection = self._client.computeProjectionMatrixFOV(
            CAMERA_FOV_DEG, 1.0, CAMERA_NEAR_M, CAMERA_FAR_M
        )
        self._pose = np.zeros(3)  # x, y, θ
        self._camera_offset = np.zeros(3)
        self._camera_angles_deg = np.zeros(2)  # yaw, pitch jitter
        self._intent = 0
        self._steps = 0
        self._hold = 0
        self._succeeded = False
        self._last_image: np.ndarray | None = None
        self._last_seg: np.ndarray | None = None
        self._wander_action = np.zeros(2)
        self._wander_left = 0
        self._wander_goal = 0
        self._wander_mode = "start"
        self._planner: _ArenaPlanner | None = None

    # ------------------------------------------------------------------ world building

    def _load_robot(self) -> int:
        robot = self._client.loadURDF(str(TURTLEBOT_URDF), [0, 0, ROBOT_BASE_Z_M], useFixedBase=True)
        # The camera sits above and ahead of the body, so the body never shows in it; its detailed meshes
        # would still cost ~6 ms per tiny-renderer frame, so they are made fully transparent (skipped).
        for link in range(-1, self._client.getNumJoints(robot)):
            self._client.changeVisualShape(robot, link, rgbaColor=[0, 0, 0, 0])
        return robot

    def _build_room(self) -> tuple[int, list[int]]:
        floor_rgb = self.domain.floor_rgb or DEFAULT_FLOOR_RGB
        floor = self._box([ARENA_HALF_M + WALL_THICKNESS_M] * 2 + [0.005], [0, 0, -0.005], floor_rgb)
        if self.domain.floor_texture:
            self._client.changeVisualShape(
                floor, -1, textureUniqueId=self._texture(self.domain.floor_texture, 16)
            )
        half_length = ARENA_HALF_M + WALL_THICKNESS_M
        walls = []
        for axis in (0, 1):
            for sign in (-1.0, 1.0):
                half = [half_length, half_length, WALL_HEIGHT_M / 2]
                half[axis] = WALL_THICKNESS_M / 2
                centre = [0.0, 0.0, WALL_HEIGHT_M / 2]
                centre[axis] = sign * (ARENA_HALF_M + WALL_THICKNESS_M / 2)
                walls.append(self._box(half, centre, WALL_RGB))
        return floor, walls

    def _box(self, half_extents: list[float], position: list[float], rgb: tuple[float, float, float]) -> int:
        visual = self._client.createVisualShape(p.GEOM_BOX, halfExtents=half_extents, rgbaColor=[*rgb, 1])
        return self._client.createMultiBody(0, -1, visual, basePosition=position)

    def _object_visual(self, spec: ObjectSpec) -> int:
        rgba = [*(self.domain.object_rgb or spec.rgb), 1.0]
        if spec.name == "cube":
            return self._client.createVisualShape(
                p.GEOM_BOX, halfExtents=[spec.footprint_radius_m] * 3, rgbaColor=rgba
            )
        if spec.name == "sphere":
            return self._client.createVisualShape(
                p.GEOM_SPHERE, radius=spec.footprint_radius_m, rgbaColor=rgba
            )
        if spec.name == "cylinder":
            return self._client.createVisualShape(
                p.GEOM_CYLINDER, radius=spec.footprint_radius_m, length=spec.height_m, rgbaColor=rgba
            )
        vertices, indices, normals, uvs = cone_mesh(spec.footprint_radius_m, spec.height_m)
        return self._client.createVisualShape(
            p.GEOM_MESH, vertices=vertices, indices=indices, normals=normals, uvs=uvs, rgbaColor=rgba
        )

    def _create_objects(self) -> list[int]:
        """One body per object, built once; each episode only moves them."""
        texture = self._texture(self.domain.object_texture, squares=4)
        bodies = []
        for spec in OBJECTS:
            body = self._client.createMultiBody(0, -1, self._object_visual(spec), basePosition=[0, 0, -1])
            if texture != -1:
                self._client.changeVisualShape(body, -1, textureUniqueId=texture)
            bodies.append(body)
        return bodies

    def _place_objects(self, layout: list[tuple[np.ndarray, float]]) -> None:
        self._objects = []
        for spec, body, (xy, yaw) in zip(OBJECTS, self._object_ids, layout, strict=True):
            position = [float(xy[0]), float(xy[1]), spec.height_m / 2]
            orientation = self._client.getQuaternionFromEuler([0, 0, yaw])
            self._client.resetBasePositionAndOrientation(body, position, orientation)
            self._objects.append(PlacedObject(spec, np.asarray(xy, dtype=np.float64), yaw, body))

    def _enter_room(self, room: DomainShift) -> None:
        """Recolour and retexture the floor and the objects for this episode's room (light: `_observe`)."""
        self.domain = room
        floor_texture = self._texture(room.floor_texture, squares=16)
        floor_rgba = [*(room.floor_rgb or DEFAULT_FLOOR_RGB), 1.0]
        self._client.changeVisualShape(
            self._floor_id, -1, rgbaColor=floor_rgba, textureUniqueId=floor_texture
        )
        object_texture = self._texture(room.object_texture, squares=4)
        for spec, body in zip(OBJECTS, self._object_ids, strict=True):
            rgba = [*(room.object_rgb or spec.rgb), 1.0]
            self._client.changeVisualShape(body, -1, rgbaColor=rgba, textureUniqueId=object_texture)

    def _texture(self, kind: str | None, squares: int) -> int:
        """A texture's id, loaded once per world; -1 (plain) for None."""
        if kind is None:
            return -1
        key = f"{kind}_{squares}"
        if key not in self._textures:
            self._textures[key] = self._client.loadTexture(str(texture_file(kind, squares=squares)))
        return self._textures[key]

    # ------------------------------------------------------------------ Gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        layout, start = self._sample_layout()
        jitter_rng = np.random.default_rng(int(self.np_random.integers(2**63)))
        intent = options.get("intent")
        if intent is None:
            intent = int(self.np_random.integers(self.num_intents))
        if not isinstance(intent, int | np.integer) or not 0 <= int(intent) < self.num_intents:
            raise ValueError(f"options['intent'] must be an int in 0..{self.num_intents - 1}, got {intent!r}")
        self._intent = int(intent)
        self._place_objects(layout)
        if self.room_ranges is not None:  # drawn after the task: same seed, same task as in a fixed room
            self._enter_room(sample_room(self.room_ranges, random.Random(int(jitter_rng.integers(2**63)))))
        self._sample_camera_jitter(jitter_rng)
        self._pose = np.asarray(start, dtype=np.float64)
        self._steps = 0
        self._hold = 0
        self._succeeded = False
        self._wander_left = 0
        self._wander_mode = "start"
        self._planner = None
        self._sync_robot_body()
        observation = self._observe()
        return observation, self._info(in_reach=self._target_in_reach(), blocked=False)

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        action = np.asarray(action, dtype=np.float32)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite numbers (forward, turn) in [-1, 1], got {action!r}")
        speed, turn = action_to_velocity(action)
        blocked = self._drive(speed, turn)
        self._steps += 1
        observation = self._observe()
        in_reach = self._target_in_reach()
        self._hold = self._hold + 1 if in_reach else 0
        truncated = self._steps >= self.max_steps
        reward = 0.0
        if self.success_rule == "hold" and not self._succeeded and self._hold >= SUCCESS_HOLD_STEPS:
            self._succeeded = True
            reward = 1.0
        elif self.success_rule == "final":
            self._succeeded = in_reach
            reward = 1.0 if truncated and in_reach else 0.0
        return observation, reward, False, truncated, self._info(in_reach=in_reach, blocked=blocked)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return None if self._last_image is None else self._last_image.copy()

    def close(self) -> None:
        if getattr(self, "_client", None) is not None:
            self._client.disconnect()
            self._client = None

    def arrange(
        self,
        robot_pose: tuple[float, float, float],
        object_xy: list[tuple[float, float]] | None = None,
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Hand-place the robot (x, y, heading) and optionally every object's centre; call after `reset`.

        For tests, demos and snapshot capture. Returns the new observation and info; the episode goes on.
        """
        if not self._objects:
            raise RuntimeError("call reset() before arrange()")
        if object_xy is not None:
            if len(object_xy) != len(OBJECTS):
                raise ValueError(
                    f"object_xy needs one (x, y) per object ({len(OBJECTS)}), got {len(object_xy)}"
                )
            for spec, xy in zip(OBJECTS, object_xy, strict=True):
                if wall_clearance(np.asarray(xy, dtype=np.float64))[0] < spec.footprint_radius_m * math.sqrt(
                    2
                ):
                    raise ValueError(
                        f"the {spec.name} at {tuple(xy)} would stick into a wall (|x|, |y| < 0.8 m)"
                    )
            self._place_objects(
                [
                    (np.asarray(xy, dtype=np.float64), obj.yaw)
                    for xy, obj in zip(object_xy, self._objects, strict=True)
                ]
            )
        x, y, heading = (float(v) for v in robot_pose)
        if self._collides(np.array([x, y])):
            raise ValueError(f"the robot at ({x:.2f}, {y:.2f}) would overlap a wall or an object")
        self._pose = np.array([x, y, wrap_angle(heading)])
        self._hold = 0
        self._planner = None
        self._sync_robot_body()
        observation = self._observe()
        return observation, self._info(in_reach=self._target_in_reach(), blocked=False)

    # ------------------------------------------------------------------ layout and motion

    def _sample_layout(self) -> tuple[list[tuple[np.ndarray, float]], np.ndarray]:
        rng = self.np_random
        for _ in range(LAYOUT_ATTEMPTS):
            layout: list[tuple[np.ndarray, float]] = []
            for spec in OBJECTS:
                margin = spec.footprint_radius_m * math.sqrt(2) + 0.05
                for _ in range(LAYOUT_ATTEMPTS):
                    xy = rng.uniform(-ARENA_HALF_M + margin, ARENA_HALF_M - margin, size=2)
                    far_enough = all(
                        np.linalg.norm(xy - other_xy)
                        >= spec.footprint_radius_m * math.sqrt(2)
                        + other.footprint_radius_m * math.sqrt(2)
                        + OBJECT_GAP_M
                        for other, (other_xy, _) in zip(OBJECTS, layout, strict=False)
                    )
                    if far_enough:
                        layout.append((xy, float(rng.uniform(-math.pi, math.pi))))
                        break
            if len(layout) < len(OBJECTS):
                continue
            placed = [PlacedObject(spec, xy, yaw) for spec, (xy, yaw) in zip(OBJECTS, layout, strict=True)]
            for _ in range(LAYOUT_ATTEMPTS):
                xy = rng.uniform(-ARENA_HALF_M + ROBOT_RADIUS_M, ARENA_HALF_M - ROBOT_RADIUS_M, size=2)
                if all(obj.clearance(xy)[0] - ROBOT_RADIUS_M >= START_CLEARANCE_M for obj in placed):
                    return layout, np.array([xy[0], xy[1], rng.uniform(-math.pi, math.pi)])
        raise RuntimeError("could not place the objects and the robot in the arena; this is a bug")

    def _collides(self, xy: np.ndarray) -> bool:
        return bool(self._clearance(np.atleast_2d(xy))[0] < ROBOT_RADIUS_M)

    def _drive(self, speed: float, turn: float) -> bool:
        """Integrate the unicycle model over one control period; return whether something stopped it."""
        dt = CONTROL_PERIOD_S / SUBSTEPS
        x, y, theta = self._pose
        blocked = False
        for _ in range(SUBSTEPS):
            mid_heading = theta + turn * dt / 2
            candidate = np.array(
                [x + speed * dt * math.cos(mid_heading), y + speed * dt * math.sin(mid_heading)]
            )
            theta = wrap_angle(theta + turn * dt)
            if speed == 0.0 or not self._collides(candidate):
                x, y = candidate
                continue
            blocked = True
            if self.contact == "slide":
                x, y = self._slide(np.array([x, y]), candidate)
        self._pose = np.array([x, y, theta])
        self._sync_robot_body()
        return blocked

    def _slide(self, here: np.ndarray, blocked_at: np.ndarray) -> np.ndarray:
        """Where a blocked slice ends under the "slide" rule: its motion less the part into the nearest
        obstacle; `here` if even that would touch something (a corner between two obstacles)."""
        motion = blocked_at - here
        normal = self._surface_normal(here)
        along = motion - min(float(motion @ normal), 0.0) * normal
        slid = here + along
        return here if self._collides(slid) else slid

    def _surface_normal(self, xy: np.ndarray) -> np.ndarray:
        """Unit vector pointing away from the nearest wall or object at `xy`: the gradient of the clearance,
        by central differences (one formula for walls, round objects and the cube's edges and corners)."""
        step = 1e-5
        offsets = np.array([[step, 0.0], [-step, 0.0], [0.0, step], [0.0, -step]])
        clearance = self._clearance(xy + offsets)
        gradient = np.array([clearance[0] - clearance[1], clearance[2] - clearance[3]])
        norm = float(np.linalg.norm(gradient))
        return gradient / norm if norm > 0.0 else gradient

    def _clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point (N, 2) to the nearest wall or object footprint."""
        return np.min([wall_clearance(points), *[obj.clearance(points) for obj in self._objects]], axis=0)

    def _sync_robot_body(self) -> None:
        x, y, theta = self._pose
        orientation = self._client.getQuaternionFromEuler([0, 0, theta])
        self._client.resetBasePositionAndOrientation(self._robot_id, [x, y, ROBOT_BASE_Z_M], orientation)

    # ------------------------------------------------------------------ geometry of the task

    def object_clearance(self, index: int) -> float:
        """Gap between the robot's bumper and object `index` in the floor plane (m)."""
        return float(self._objects[index].clearance(self._pose[:2])[0] - ROBOT_RADIUS_M)

    def object_bearing(self, index: int) -> float:
        """Angle from the robot's heading to object `index`'s centre (rad, positive to the left)."""
        dx, dy = self._objects[index].xy - self._pose[:2]
        return wrap_angle(math.atan2(dy, dx) - self._pose[2])

    def _target_in_reach(self) -> bool:
        near = self.object_clearance(self._intent) <= SUCCESS_CLEARANCE_M
        ahead = abs(self.object_bearing(self._intent)) <= math.radians(SUCCESS_BEARING_DEG)
        return bool(near and ahead)

    def object_pixel_shares(self) -> list[float]:
        """Share of the last camera view's pixels that shows each object, in `OBJECTS` order."""
        assert self._last_seg is not None
        ids, counts = np.unique(self._last_seg, return_counts=True)
        pixels = dict(zip(ids.tolist(), counts.tolist(), strict=True))
        return [pixels.get(obj.body_id, 0) / self._last_seg.size for obj in self._objects]

    def _heard(self) -> int | None:
        """The single object that dominates the camera view at close range, else None."""
        shares = self.object_pixel_shares()
        largest = int(np.argmax(shares))
        dominates = (
            shares[largest] >= HEARD_MIN_PIXEL_SHARE
            and self.object_clearance(largest) <= self.heard_reach_m
            and abs(self.object_bearing(largest)) <= math.radians(HEARD_MAX_BEARING_DEG)
        )
        rivals = [
            k
            for k, share in enumerate(shares)
            if k != largest and share >= HEARD_RIVAL_RATIO * shares[largest]
        ]
        return largest if dominates and not rivals else None

    def _info(self, *, in_reach: bool, blocked: bool) -> dict[str, Any]:
        return {
            "intent": self._intent,
            "heard": self._heard(),
            "success": self._succeeded,
            "in_reach": bool(in_reach),
            "hold_steps": self._hold,
            "blocked": blocked,
            "target_clearance": self.object_clearance(self._intent),
            "target_bearing": float(self.object_bearing(self._intent)),
        }

    # ------------------------------------------------------------------ camera

    def _sample_camera_jitter(self, rng: np.random.Generator) -> None:
        self._camera_offset = rng.uniform(-1.0, 1.0, size=3) * self.domain.camera_jitter_m
        self._camera_angles_deg = rng.uniform(-1.0, 1.0, size=2) * self.domain.camera_jitter_deg

    def _camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        x, y, theta = self._pose
        mount = np.asarray(CAMERA_MOUNT_M) + self._camera_offset
        cos_t, sin_t = math.cos(theta), math.sin(theta)
        eye = np.array(
            [x + mount[0] * cos_t - mount[1] * sin_t, y + mount[0] * sin_t + mount[1] * cos_t, mount[2]]
        )
        yaw = theta + math.radians(self._camera_angles_deg[0])
        pitch = math.radians(CAMERA_PITCH_DEG + self._camera_angles_deg[1])
        forward = np.array(
            [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
        )
        return eye, forward

    def _observe(self) -> dict[str, np.ndarray]:
        eye, forward = self._camera_pose()
        view = self._client.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), [0, 0, 1])
        _, _, rgba, _, seg = self._client.getCameraImage(
            self.image_size,
            self.image_size,
            view,
            self._projection,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=list(self.domain.light_direction or DEFAULT_LIGHT_DIRECTION),
            lightAmbientCoeff=self.domain.light_ambient
            if self.domain.light_ambient is not None
            else DEFAULT_LIGHT_AMBIENT,
            lightDiffuseCoeff=self.domain.light_diffuse
            if self.domain.light_diffuse is not None
            else DEFAULT_LIGHT_DIFFUSE,
            lightSpecularCoeff=LIGHT_SPECULAR,
            shadow=0,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(self.image_size, self.image_size, 4)[:, :, :3]
        self._last_image = np.ascontiguousarray(image)
        self._last_seg = np.asarray(seg).reshape(self.image_size, self.image_size)
        x, y, theta = self._pose
        state = np.array([x, y, math.sin(theta), math.cos(theta)], dtype=np.float32)
        return {"image": self._last_image.copy(), "state": state}

    # ------------------------------------------------------------------ scripted behaviours

    def oracle_action(self) -> np.ndarray:
        """Drive to the commanded object along a planned path, face it, and stay there (ground truth)."""
        if self._planner is None:
            self._planner = _ArenaPlanner(self._objects, self._intent)
        x, y, theta = self._pose
        clearance = self.object_clearance(self._intent)
        bearing = self.object_bearing(self._intent)
        if clearance <= SUCCESS_CLEARANCE_M - 0.08:
            turn = 4.0 * bearing
            speed = 0.0 if clearance <= 0.12 or abs(bearing) > math.radians(10) else 0.1
            return velocity_to_action(speed, turn)
        waypoint = self._planner.lookahead(np.array([x, y]))
        heading_error = wrap_angle(math.atan2(waypoint[1] - y, waypoint[0] - x) - theta)
        if clearance <= SUCCESS_CLEARANCE_M + 0.15:
            heading_error = bearing
        turn = 4.0 * heading_error
        speed = (
            SPEED_RANGE_M_S[1] * max(0.0, math.cos(heading_error)) ** 4 if abs(heading_error) < 0.7 else 0.0
        )
        return velocity_to_action(speed, turn)

    def random_view_step(
        self, rng: np.random.Generator
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        """Wander for view collection; returns what `step` returns.

        A curious robot: it either drives a random (speed, turn) for a few steps, or heads for a random object
        with a wobbly aim until it gets there or bumps into something, looks at it for a while, and moves on.
        This gives a good share of views where one object fills the camera up close.
        """
        if self._wander_left <= 0:
            self._choose_wander_segment(rng)
        self._wander_left -= 1
        action = self._wander_action
        if self._wander_mode == "approach":
            bearing = self.object_bearing(self._wander_goal) + rng.normal(0.0, 0.3)
            action = velocity_to_action(rng.uniform(0.08, 0.25) if abs(bearing) < 0.6 else 0.0, 3.0 * bearing)
        elif self._wander_mode == "linger":
            action = velocity_to_action(0.0, rng.normal(0.0, 0.3))
        result = self.step(action)
        arrived = self._wander_mode == "approach" and self.object_clearance(self._wander_goal) < 0.12
        if result[4]["blocked"] or arrived:
            self._wander_mode = "linger"
            self._wander_left = int(rng.integers(3, 10))
        return result

    def _choose_wander_segment(self, rng: np.random.Generator) -> None:
        if self._wander_mode != "random" and self._wander_mode != "start" and rng.random() < 0.7:
            # After lingering: back off while turning away.
            self._wander_mode = "random"
            self._wander_action = velocity_to_action(rng.uniform(-0.1, 0.05), rng.choice([-1.0, 1.0]) * 1.1)
            self._wander_left = int(rng.integers(2, 6))
        elif rng.random() < 0.6:
            self._wander_mode = "approach"
            self._wander_goal = int(rng.integers(len(self._objects)))
            self._wander_left = 60
        else:
            self._wander_mode = "random"
            self._wander_action = rng.uniform(-1.0, 1.0, size=2).astype(np.float32)
            self._wander_left = int(rng.integers(3, 12))


class _ArenaPlanner:
    """Shortest paths on a 4 cm grid to the ring of poses next to the target, around walls and objects."""

    CELL_M = 0.04
    SAFETY_M = 0.06  # planned paths keep the bumper this far from walls and other objects
    GOAL_CLEARANCE_M = (0.05, 0.2)

    def __init__(self, objects: list[PlacedObject], target: int) -> None:
        count = round(2 * ARENA_HALF_M / self.CELL_M)
        centres = -ARENA_HALF_M + self.CELL_M * (np.arange(count) + 0.5)
        grid_x, grid_y = np.meshgrid(centres, centres, indexing="ij")
        points = np.stack([grid_x.ravel(), grid_y.ravel()], axis=1)
        clearance = wall_clearance(points) - ROBOT_RADIUS_M
        for k, obj in enumerate(objects):
            if k != target:
                clearance = np.minimum(clearance, obj.clearance(points) - ROBOT_RADIUS_M)
        target_clearance = objects[target].clearance(points) - ROBOT_RADIUS_M
        clearance = np.minimum(clearance, target_clearance).reshape(count, count)
        # Cells near obstacles cost more, so paths keep their distance where there is room to.
        cost = 1.0 + 8.0 * np.clip(self.SAFETY_M - clearance, 0.0, None) / self.SAFETY_M
        cost[clearance < 0.0] = np.inf
        goal = (target_clearance.reshape(count, count) >= self.GOAL_CLEARANCE_M[0]) & (
            target_clearance.reshape(count, count) <= self.GOAL_CLEARANCE_M[1]
        )
        goal &= clearance >= 0.0
        self.centres = centres
        self.count = count
        self.distance = self._wavefront(cost, goal)

    @staticmethod
    def _wavefront(cost: np.ndarray, goal: np.ndarray) -> np.ndarray:
        distance = np.where(goal, 0.0, np.inf)
        steps = [(dx, dy, math.hypot(dx, dy)) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]
        while True:
            padded = np.pad(distance, 1, constant_values=np.inf)
            best = distance.copy()
            rows, cols = distance.shape
            for dx, dy, length in steps:
                neighbour = padded[1 + dx : 1 + dx + rows, 1 + dy : 1 + dy + cols]
                best = np.minimum(best, neighbour + length * cost)
            if np.array_equal(best, distance):
                return distance
            distance = best

    def _cell(self, xy: np.ndarray) -> tuple[int, int]:
        index = np.clip(((xy + ARENA_HALF_M) / self.CELL_M).astype(int), 0, self.count - 1)
        return int(index[0]), int(index[1])

    def lookahead(self, xy: np.ndarray, cells: int = 5) -> np.ndarray:
        """A point a few cells down the cost-to-go from `xy` (from the nearest planned cell if need be)."""
        i, j = self._cell(xy)
        if not np.isfinite(self.distance[i, j]):
            finite = np.argwhere(np.isfinite(self.distance))
            if len(finite) == 0:
                return xy
            centres = self.centres[finite]
            i, j = finite[int(np.argmin(np.linalg.norm(centres - xy, axis=1)))]
        for _ in range(cells):
            window = self.distance[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2]
            di, dj = np.unravel_index(int(np.argmin(window)), window.shape)
            next_i, next_j = max(i - 1, 0) + int(di), max(j - 1, 0) + int(dj)
            if (next_i, next_j) == (i, j):
                break
            i, j = next_i, next_j
        return np.array([self.centres[i], self.centres[j]])


def cone_mesh(radius: float, height: float, segments: int = 24) -> tuple[list, list, list, list]:
    """A cone centred on its half height: side triangles with slanted normals plus a base disc."""
    vertices, normals, uvs, indices = [], [], [], []
    slope = radius / height
    half = height / 2
    for i in range(segments):
        a0, a1 = 2 * math.pi * i / segments, 2 * math.pi * (i + 1) / segments
        mid = (a0 + a1) / 2
        base = len(vertices)
        for angle in (a0, a1):
            vertices.append([radius * math.cos(angle), radius * math.sin(angle), -half])
            normal = np.array([math.cos(angle), math.sin(angle), slope])
            normals.append((normal / np.linalg.norm(normal)).tolist())
            uvs.append([angle / (2 * math.pi), 0.0])
        vertices.append([0.0, 0.0, half])
        apex_normal = np.array([math.cos(mid), math.sin(mid), slope])
        normals.append((apex_normal / np.linalg.norm(apex_normal)).tolist())
        uvs.append([mid / (2 * math.pi), 1.0])
        indices += [base, base + 1, base + 2]
    centre = len(vertices)
    vertices.append([0.0, 0.0, -half])
    normals.append([0.0, 0.0, -1.0])
    uvs.append([0.5, 0.5])
    for i in range(segments):
        angle = 2 * math.pi * i / segments
        vertices.append([radius * math.cos(angle), radius * math.sin(angle), -half])
        normals.append([0.0, 0.0, -1.0])
        uvs.append([0.5 + 0.5 * math.cos(angle), 0.5 + 0.5 * math.sin(angle)])
    for i in range(segments):
        indices += [centre, centre + 1 + (i + 1) % segments, centre + 1 + i]
    return vertices, indices, normals, uvs
