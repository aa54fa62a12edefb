"""Random exploration views for VAR triplet collection and snapshot capture."""

from collections.abc import Iterator

import gymnasium as gym
import numpy as np

from sim import world_id
from sim.domain import DomainShift, RoomRanges


def random_views(
    world: str,
    count: int,
    seed: int,
    image_size: int = 96,
    domain: DomainShift | RoomRanges | None = None,
) -> Iterator[tuple[np.ndarray, int | None, np.ndarray]]:
    """Yield `count` views `(image, heard, state)` while the robot moves at random as the reference does.

    The arms' gripper target jumps to random places in the workspace; the TurtleBot wanders. Each world's env
    provides `random_view_step(rng)`, which returns what `step` returns. A new scene (block row, object
    layout, and with `RoomRanges` a room) is drawn whenever an episode ends. The same arguments give the same
    views.
    """
    if count < 0:
        raise ValueError(f"count must be zero or more views, got {count}")
    env = gym.make(world_id(world), image_size=image_size, domain=domain)
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
