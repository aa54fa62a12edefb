"""Scripted controllers that solve each world with ground truth, and their evaluation.

Every world's env class exposes `oracle_action()`; `oracle_action(env)` works on wrapped envs too.
"""

from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from sim import world_id


def oracle_action(env: gym.Env) -> np.ndarray:
    """The scripted action for the env's current state (ground truth allowed)."""
    unwrapped = env.unwrapped
    if not hasattr(unwrapped, "oracle_action"):
        raise TypeError(
            f"{type(unwrapped).__name__} has no scripted oracle (it needs an oracle_action() method)"
        )
    return np.asarray(unwrapped.oracle_action(), dtype=np.float32)


@dataclass
class OracleReport:
    world: str
    rule: str
    episodes_per_intent: int
    successes: dict[int, int] = field(default_factory=dict)

    @property
    def episodes(self) -> int:
        return self.episodes_per_intent * len(self.successes)

    @property
    def success_rate(self) -> float:
        return sum(self.successes.values()) / max(self.episodes, 1)

    def intent_rate(self, intent: int) -> float:
        return self.successes[intent] / self.episodes_per_intent


def evaluate_oracle(
    world: str,
    episodes: int,
    rule: str,
    seed: int = 0,
    on_episode: Callable[[], None] | None = None,
) -> OracleReport:
    """Run the oracle for `episodes` episodes split evenly over the intents (episode i uses seed + i).

    Images are not rendered: the oracle uses ground truth only, so this measures the task, not the camera.
    """
    env = gym.make(world_id(world), success_rule=rule, **_no_image_kwargs(world))
    try:
        intents = env.unwrapped.num_intents
        if episodes < intents or episodes % intents:
            raise ValueError(f"episodes must be a positive multiple of the {intents} intents, got {episodes}")
        report = OracleReport(world, rule, episodes // intents, dict.fromkeys(range(intents), 0))
        for episode in range(episodes):
            intent = episode % intents
            env.reset(seed=seed + episode, options={"intent": intent})
            info: dict = {}
            done = False
            while not done:
                _, _, terminated, truncated, info = env.step(oracle_action(env))
                done = terminated or truncated
            report.successes[intent] += int(bool(info["success"]))
            if on_episode is not None:
                on_episode()
        return report
    finally:
        env.close()


def _no_image_kwargs(world: str) -> dict:
    return {"render_images": False} if world in ("kuka", "kinova") else {}
