"""Frames of the worlds as files: shared by `varbot sim show` and the demo."""

from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np

from sim import world_id
from sim.domain import DomainShift
from sim.oracle import oracle_action

DOMAINS = {"none": None, "unseen": DomainShift.unseen_room, "lamplit": DomainShift.lamplit_room}


def domain_named(name: str) -> DomainShift | None:
    if name not in DOMAINS:
        raise ValueError(f"unknown domain {name!r}: choose one of {', '.join(DOMAINS)}")
    make = DOMAINS[name]
    return make() if make else None


def render_world_frame(
    world: str, intent: int, size: int, seed: int, domain: str = "none", oracle_steps: int = 0
) -> tuple[np.ndarray, dict]:
    """The camera image after `reset(seed, intent)` and `oracle_steps` oracle steps, with the last info."""
    if oracle_steps < 0:
        raise ValueError(f"oracle_steps must be zero or more, got {oracle_steps}")
    env = gym.make(world_id(world), image_size=size, domain=domain_named(domain))
    try:
        if not 0 <= intent < env.unwrapped.num_intents:
            raise ValueError(f"intent must be in 0..{env.unwrapped.num_intents - 1}, got {intent}")
        observation, info = env.reset(seed=seed, options={"intent": intent})
        for _ in range(oracle_steps):
            observation, _, terminated, truncated, info = env.step(oracle_action(env))
            if terminated or truncated:
                break
        return observation["image"], info
    finally:
        env.close()


def save_png(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}: check that the folder is writable and the name ends in .png")
