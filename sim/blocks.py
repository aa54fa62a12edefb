"""The block task shared by the arm worlds (the reference's Kuka task, exactly as DESIGN.md lists it).

Four identical red blocks lie 0.1 m apart in a row along y at a random place on a table; an arm moves its
gripper target in the table plane; a fixed camera looks at the table from the far side. Intent k = "slot k",
the k-th block from the left as the camera sees it (y grows to the right in the image).

`info["heard"]` follows the reference's data collection: a vertical ray from the gripper down to the table;
if it hits block k, a person would say command k about this view, otherwise (table, nothing) it is `None`.
A single ray hits at most one block, so "several candidates" cannot happen in this world.

Success rules (`success_rule`):
- "final": the ray hits the target block at the last step (the reference's test). False before the last step.
- "hold": the ray hit the target block for at least `hold_steps` consecutive steps (sticky once reached).
"""

import random
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pybullet as p
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

from sim.arm import STEP_M, WORKSPACE_X_M, WORKSPACE_Y_M
from sim.bullet_arm import BulletArm, configure_physics
from sim.camera import Lighting, TableCamera
from sim.domain import DomainShift, RoomRanges, room_and_ranges, sample_room
from sim.mirror import BodyMirror, MirroredWorld
from sim.textures import texture_file

TABLE_TEXTURE = pybullet_data.getDataPath() + "/table/table.png"  # table.urdf's own look

NUM_INTENTS = 4
INTENT_NAMES = [f"slot {k}" for k in range(NUM_INTENTS)]
EPISODE_STEPS = 100
SUCCESS_RULES = ("final", "hold")
DEFAULT_HOLD_STEPS = 50

TABLE_POSITION_M = (0.5, 0.0, -0.75)
TABLE_TOP_Z_M = -0.125  # table.urdf's top plate (0.6 m + 0.025 m half thickness) lowered by 0.75 m
BLOCK_SIZE_M = (0.1143, 0.0381, 0.0381)
BLOCK_RGBA = (1.0, 0.0, 0.0, 1.0)
BLOCK_SPACING_M = 0.1
ROW_X_RANGE_M = (0.50, 0.70)  # row origin = centre of slot 0
ROW_Y_RANGE_M = (-0.20, -0.10)
GRIPPER_START_MARGIN_M = 0.05  # the gripper starts anywhere in the workspace shrunk by this margin
START_X_M = (WORKSPACE_X_M[0] + GRIPPER_START_MARGIN_M, WORKSPACE_X_M[1] - GRIPPER_START_MARGIN_M)
START_Y_M = (WORKSPACE_Y_M[0] + GRIPPER_START_MARGIN_M, WORKSPACE_Y_M[1] - GRIPPER_START_MARGIN_M)
START_STRIPS = 5  # strips across the table, 0.1 m wide in y, for a trainer that chooses where episodes start
START_STRIP_WIDTH_M = (START_Y_M[1] - START_Y_M[0]) / START_STRIPS


class BlocksEnv(MirroredWorld, gym.Env[dict, np.ndarray]):
    """Gymnasium env of the block task; subclasses choose the arm."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 15}
    arm_class: ClassVar[type[BulletArm]]
    num_intents = NUM_INTENTS
    intent_names = INTENT_NAMES

    def __init__(
        self,
        image_size: int = 96,
        success_rule: str = "final",
        domain: DomainShift | RoomRanges | None = None,
        max_steps: int | None = None,
        hold_steps: int = DEFAULT_HOLD_STEPS,
        render_images: bool = True,
        visual_detail: str = "fast",
        render_mode: str | None = None,
    ) -> None:
        _check_options(success_rule, max_steps, hold_steps, render_mode)
        self.success_rule = success_rule
        self.max_steps = EPISODE_STEPS if max_steps is None else int(max_steps)
        self.hold_steps = int(hold_steps)
        self.domain, self.room_ranges = room_and_ranges(domain)  # ranges: a new room every reset
        self.render_images = render_images  # False: observations carry a black image (fast ground-truth runs)
        self.render_mode = render_mode

        self.client = BulletClient(p.DIRECT)
        configure_physics(self.client)
        self.table = self.client.loadURDF(
            pybullet_data.getDataPath() + "/table/table.urdf", list(TABLE_POSITION_M), useFixedBase=True
        )
        self.blocks = _make_blocks(self.client)
        self.camera = TableCamera(image_size, lighting=_lighting(self.domain))
        self.arm = self.arm_class(self.client, camera=self._render, visual_detail=visual_detail)
        self.mirror = BodyMirror(self.client, self.arm.body)
        self._textures: dict[str, int] = {}
        self._apply_appearance()

        self.observation_space = gym.spaces.Dict(
            {
                "image": gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8),
                "state": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.intent = 0
        self.row_origin = np.zeros(2)
        self.steps = 0
        self.hold_streak = 0
        self.best_streak = 0

    # --- Gymnasium API ---------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        options = dict(options or {})
        self.intent = self._pick_intent(options.pop("intent", None))
        strip = _start_strip_option(options.pop("start_strip", None))
        if options:
            raise ValueError(
                f"unknown reset options {sorted(options)}; the options are 'intent' and 'start_strip'"
            )
        self.row_origin = self.np_random.uniform(
            [ROW_X_RANGE_M[0], ROW_Y_RANGE_M[0]], [ROW_X_RANGE_M[1], ROW_Y_RANGE_M[1]]
        )
        for slot, block in enumerate(self.blocks):
            self.client.resetBasePositionAndOrientation(block, self.slot_position(slot), [0, 0, 0, 1])
        start = self.np_random.uniform([START_X_M[0], START_Y_M[0]], [START_X_M[1], START_Y_M[1]])
        if strip is not None:  # the same draw, squeezed into the strip: the rest of the episode's draws stay
            low, high = start_strip_bounds(strip)
            start[1] = low + (start[1] - START_Y_M[0]) / (START_Y_M[1] - START_Y_M[0]) * (high - low)
        self.arm.reset_to(*start)
        if self.room_ranges is not None:  # drawn after the task: same seed, same task as in a fixed room
            self._enter_room(
                sample_room(self.room_ranges, random.Random(int(self.np_random.integers(2**63))))
            )
        if self.domain.camera_jitter_m > 0 or self.domain.camera_jitter_deg > 0:
            self.camera.jitter(self.np_random, self.domain.camera_jitter_m, self.domain.camera_jitter_deg)
        self.steps = self.hold_streak = self.best_streak = 0
        heard = self.heard()
        return self._observe(), self._info(heard)

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite numbers (dx, dy) in [-1, 1], got {action!r}")
        dx, dy = np.clip(action, -1.0, 1.0) * STEP_M
        return self._advance(float(dx), float(dy))

    def _advance(self, dx_m: float, dy_m: float) -> tuple[dict, float, bool, bool, dict]:
        self.arm.move_target(dx_m, dy_m)
        self.steps += 1
        heard = self.heard()
        self._count_hold(heard)
        reward = (
            1.0 if heard == self.intent else 0.0
        )  # the sparse task reward (baselines); VAR does not use it
        truncated = self.steps >= self.max_steps
        return self._observe(), reward, False, truncated, self._info(heard)

    def render(self) -> np.ndarray:
        return self._render()

    def render_as(self, room: DomainShift) -> np.ndarray:
        """The current view as `room` would show it: the same scene from the same camera, in the room's
        colours, textures and light (its camera jitter is not drawn). The episode's own room is back after."""
        own = self.domain
        self._enter_room(room)
        try:
            return self._render()
        finally:
            self._enter_room(own)

    def close(self) -> None:
        if self.client is not None and self.client.isConnected():
            self.client.disconnect()

    # --- ground truth ----------------------------------------------------------------------------------
    def slot_position(self, slot: int) -> list[float]:
        x, y = self.row_origin
        return [float(x), float(y + slot * BLOCK_SPACING_M), TABLE_TOP_Z_M + BLOCK_SIZE_M[2] / 2]

    def heard(self) -> int | None:
        """The slot of the block right under the gripper, `None` over the bare table."""
        hit = self.arm.body_under_gripper(down_to_z=TABLE_TOP_Z_M - 0.05)
        return self.blocks.index(hit) if hit in self.blocks else None

    @property
    def success(self) -> bool:
        if self.success_rule == "final":
            return self.steps >= self.max_steps and self.hold_streak > 0
        return self.best_streak >= self.hold_steps

    def oracle_action(self) -> np.ndarray:
        """Scripted controller with ground truth: move the gripper target straight to the target block."""
        goal = np.asarray(self.slot_position(self.intent)[:2])
        offset = (goal - np.asarray(self.arm.target_xy)) / STEP_M
        return np.clip(offset, -1.0, 1.0).astype(np.float32)

    def random_view_step(self, rng: np.random.Generator) -> tuple[dict, float, bool, bool, dict]:
        """One step of exploration as the reference collects triplets; returns what `step` returns.

        The gripper target jumps by up to ±0.3 m in x and ±0.4 m in y (clipped to the workspace).
        """
        return self._advance(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.4, 0.4)))

    # --- internals -------------------------------------------------------------------------------------
    def _pick_intent(self, intent: Any) -> int:
        if intent is None:
            return int(self.np_random.integers(NUM_INTENTS))
        if not _is_index(intent, NUM_INTENTS):
            raise ValueError(f"options['intent'] must be an int in 0..{NUM_INTENTS - 1}, got {intent!r}")
        return int(intent)

    def _count_hold(self, heard: int | None) -> None:
        self.hold_streak = self.hold_streak + 1 if heard == self.intent else 0
        self.best_streak = max(self.best_streak, self.hold_streak)

    def _render(self) -> np.ndarray:
        return self.camera.render(self.client)

    def _observe(self) -> dict:
        size = self.camera.image_size
        image = self._render() if self.render_images else np.zeros((size, size, 3), np.uint8)
        return {"image": image, "state": np.asarray(self.arm.gripper_xy(), dtype=np.float32)}

    def _info(self, heard: int | None) -> dict:
        return {
            "intent": self.intent,
            "heard": heard,
            "success": self.success,
            "on_target": heard == self.intent,
            "hold_streak": self.hold_streak,
            "target_xy": self.arm.target_xy,
        }

    def _enter_room(self, room: DomainShift) -> None:
        self.domain = room
        self.camera.lighting = _lighting(room)
        self._apply_appearance()

    def _apply_appearance(self) -> None:
        """Colour and texture the blocks and the table as the room says (anything else: the world's own)."""
        shift = self.domain
        block_rgba = [*shift.object_rgb, 1.0] if shift.object_rgb is not None else list(BLOCK_RGBA)
        block_texture = self._texture(shift.object_texture) if shift.object_texture else -1  # -1: plain
        for block in self.blocks:
            self.client.changeVisualShape(block, -1, rgbaColor=block_rgba, textureUniqueId=block_texture)
        table_rgba = [*shift.floor_rgb, 1.0] if shift.floor_rgb is not None else [1.0, 1.0, 1.0, 1.0]
        table_texture = self._texture(shift.floor_texture or "table", squares=12)
        self.client.changeVisualShape(self.table, -1, rgbaColor=table_rgba, textureUniqueId=table_texture)

    def _texture(self, kind: str, squares: int = 2) -> int:
        """A texture's id, loaded once per world ("table": the table's own)."""
        key = f"{kind}_{squares}"
        if key not in self._textures:
            path = TABLE_TEXTURE if kind == "table" else str(texture_file(kind, squares))
            self._textures[key] = self.client.loadTexture(path)
        return self._textures[key]


def start_strip_bounds(strip: int) -> tuple[float, float]:
    """The y range (metres) of one of the `START_STRIPS` strips the gripper's starts are drawn from."""
    low = START_Y_M[0] + strip * START_STRIP_WIDTH_M
    return low, low + START_STRIP_WIDTH_M


def start_strip_of(y_m: np.ndarray) -> np.ndarray:
    """Which start strip each gripper y (metres) lies in (clipped to the first and last)."""
    offsets = np.asarray(y_m, dtype=np.float64) - START_Y_M[0]
    strips = np.floor(offsets / START_STRIP_WIDTH_M).astype(np.int64)
    return np.clip(strips, 0, START_STRIPS - 1)


def _is_index(value: Any, count: int) -> bool:
    """An int (not a bool) in 0..count-1: what the reset options 'intent' and 'start_strip' take."""
    return not isinstance(value, bool) and isinstance(value, int | np.integer) and 0 <= value < count


def _start_strip_option(strip: Any) -> int | None:
    if strip is None:
        return None
    if not _is_index(strip, START_STRIPS):
        raise ValueError(
            f"options['start_strip'] must be an int in 0..{START_STRIPS - 1} (a strip of the table in y, "
            f"from {START_Y_M[0]:.2f} to {START_Y_M[1]:.2f} m), got {strip!r}"
        )
    return int(strip)


def _make_blocks(client: BulletClient) -> list[int]:
    """Four static blocks (nothing ever pushes them; their collision boxes stop the gripper ray)."""
    half = [s / 2 for s in BLOCK_SIZE_M]
    visual = client.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=list(BLOCK_RGBA))
    collision = client.createCollisionShape(p.GEOM_BOX, halfExtents=half)
    return [
        client.createMultiBody(
            0, collision, visual, [0.6, -0.15 + BLOCK_SPACING_M * k, TABLE_TOP_Z_M + half[2]]
        )
        for k in range(NUM_INTENTS)
    ]


def _lighting(shift: DomainShift) -> Lighting:
    return Lighting(shift.light_direction, shift.light_ambient, shift.light_diffuse)


def _check_options(
    success_rule: str, max_steps: int | None, hold_steps: int, render_mode: str | None
) -> None:
    if success_rule not in SUCCESS_RULES:
        raise ValueError(f"success_rule must be one of {SUCCESS_RULES}, got {success_rule!r}")
    if max_steps is not None and max_steps < 1:
        raise ValueError(
            f"max_steps must be a positive number of steps (or None for {EPISODE_STEPS}), got {max_steps}"
        )
    limit = EPISODE_STEPS if max_steps is None else max_steps
    if success_rule == "hold" and not 1 <= hold_steps <= limit:
        raise ValueError(f"hold_steps must be between 1 and the episode length {limit}, got {hold_steps}")
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
