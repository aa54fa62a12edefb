"""Random exploration views for VAR triplet collection and snapshot capture, and views around the blocks'
ends for sharpening a base model's VAR (simulation only: placed with the simulator's ground truth)."""

from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np

from sim import has_blocks, world_id
from sim.domain import DomainShift, RoomRanges


def random_views(
    world: str,
    count: int,
    seed: int,
    image_size: int = 96,
    domain: DomainShift | RoomRanges | None = None,
    world_options: dict[str, Any] | None = None,
) -> Iterator[tuple[np.ndarray, int | None, np.ndarray]]:
    """Yield `count` views `(image, heard, state)` while the robot moves at random as the reference does.

    The arms' gripper target jumps to random places in the workspace; the TurtleBot wanders. Each world's env
    provides `random_view_step(rng)`, which returns what `step` returns. A new scene (block row, object
    layout, and with `RoomRanges` a room) is drawn whenever an episode ends. `world_options` go to the world's
    constructor (e.g. the TurtleBot's `heard_reach_m`). The same arguments give the same views.
    """
    if count < 0:
        raise ValueError(f"count must be zero or more views, got {count}")
    env = gym.make(world_id(world), image_size=image_size, domain=domain, **(world_options or {}))
    rng = np.random.default_rng(seed)
    try:
        observation, info = env.reset(seed=seed)
        for produced in range(count):
            yield observation["image"], info["heard"], observation["state"]
            if produced == count - 1:
                break
            observation, _, terminated, truncated, info = env.unwrapped.random_view_step(rng)
            if terminated or truncated:
                observation, info = env.reset(seed=int(rng.integers(2**31 - 1)))
    finally:
        env.close()


SETTLE_STEPS = 40  # at most this many physics steps for the gripper to reach a placed position
SETTLED_M = 0.001


def block_end_views(
    world: str,
    count: int,
    seed: int,
    image_size: int = 96,
    domain: DomainShift | RoomRanges | None = None,
    past_centre_m: tuple[float, float] = (0.03, 0.11),
    across_m: float = 0.025,
    centre_share: float = 0.2,
    views_per_scene: int = 8,
    world_options: dict[str, Any] | None = None,
) -> Iterator[tuple[np.ndarray, int | None, np.ndarray]]:
    """Yield `count` views `(image, heard, state)` with the gripper placed around one end of a block (arm
    worlds): a random block, `past_centre_m` from its centre along its long side (x) to either end, within
    `across_m` of it across (y); `centre_share` of them within the first bound of its centre instead. Random
    exploration almost never puts the gripper a few centimetres past a block's end, where the ray already says
    nothing but the image barely changes. A new scene every `views_per_scene` views; `heard` is the ray's.
    The same arguments give the same views."""
    if count < 0:
        raise ValueError(f"count must be zero or more views, got {count}")
    if not has_blocks(world):
        raise ValueError(f"the {world} world has no blocks to place the gripper around")
    env = gym.make(world_id(world), image_size=image_size, domain=domain, **(world_options or {}))
    scene = env.unwrapped
    rng = np.random.default_rng(seed)
    try:
        for produced in range(count):
            if produced % views_per_scene == 0:
                env.reset(seed=int(rng.integers(2**31 - 1)))
            centre = np.asarray(scene.slot_position(int(rng.integers(scene.num_intents)))[:2])
            near, far = past_centre_m
            along = (
                rng.uniform(-near, near)
                if rng.random() < centre_share
                else rng.choice([-1, 1]) * rng.uniform(near, far)
            )
            place_gripper(scene, centre + np.array([along, rng.uniform(-across_m, across_m)]))
            yield scene.render(), scene.heard(), np.asarray(scene.arm.gripper_xy(), dtype=np.float32)
    finally:
        env.close()


def place_gripper(scene: gym.Env, xy: np.ndarray) -> None:
    """Moves an arm world's gripper target to `xy` (clipped to the workspace); the motors then get there."""
    x, y = scene.arm.target_xy
    scene.arm.move_target(float(xy[0] - x), float(xy[1] - y))
    for _ in range(SETTLE_STEPS):
        if np.hypot(*(np.asarray(scene.arm.gripper_xy()) - xy)) < SETTLED_M:
            return
        scene.arm.move_target(0.0, 0.0)
