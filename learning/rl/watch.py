"""A live watcher of training: after every step of env 0, what it sees, earns and where its robot is."""

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from learning.rl.env_groups import EnvGroups


@dataclass
class RolloutStep:
    """Environment 0 right after one vector step, for a watcher (`PPOTrainer.train(on_rollout_step=...)`)."""

    global_step: int  # environment steps of the run so far, this step included
    image: np.ndarray  # env 0's camera now, uint8 (H, W, 3); after an end, the new episode's first frame
    reward: float  # env 0's reward for this step, before normalisation (the intrinsic reward for VAR runs)
    episode_ended: bool  # env 0's episode ended with this step (and env 0 was reset)
    goal_clip: int  # index into the goal bank of the clip env 0 now works toward
    mirror: Callable[[], dict[str, Any]]  # env 0's pose now (`sim.mirror`), decoded only when asked for


Watcher = Callable[[RolloutStep], None]


class EnvZeroWatch:
    """Calls the watcher (if any) after every step of env 0. Env 0 then puts its pose into its info
    (`RLInfo.mirror_in_info`): a watcher costs the learner no round trip. No watcher costs nothing."""

    def __init__(self) -> None:
        self.watcher: Watcher | None = None

    def attach(self, watcher: Watcher | None, envs: EnvGroups) -> None:
        self.watcher = watcher
        envs.set_attr("mirror_in_info", [watcher is not None] + [False] * (envs.num_envs - 1))

    def after_step(
        self, global_step: int, obs: dict, reward: float, ended: bool, info: dict, goal_clip: int
    ) -> None:
        """`obs` and `info` are those of the group holding env 0."""
        if self.watcher is None:
            return
        pose = info["mirror"][0]
        self.watcher(
            RolloutStep(
                global_step=global_step,
                image=obs["image"][0],
                reward=float(reward),
                episode_ended=bool(ended),
                goal_clip=int(goal_clip),
                mirror=lambda: json.loads(pose),
            )
        )
