"""The training environments as groups of worker processes that step in turn.

While one group's workers step, the learner embeds, rewards and acts for the group that just returned, so
workers and learner wait less for each other (one group: plain lockstep). Every environment still acts with
exactly the current policy. Environments reset in the same step as they end (gymnasium's SAME_STEP
autoreset): `ended_view` puts the final observation back where the reward needs it.

A real robot's one environment runs in the learner's process instead (its driver's link lives there): the
caller registers it with `in_process_env` and configures the `env_context` it yields.
"""

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import psutil
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv

from learning.rl.envs import RLInfo, make_vector_env, world_id

RESET_INFO = ("intent", "heard", "distance")
IN_PROCESS = "in-process:"  # env_context prefix of an environment registered by `in_process_env`
_in_process_envs: dict[str, Callable[[], gym.Env]] = {}


@contextmanager
def in_process_env(name: str, make_env: Callable[[], gym.Env]) -> Iterator[str]:
    """While the block runs, `env_context=<what this yields>` (with num_envs = env_groups = 1) trains on the
    env `make_env` builds, in this process. `name` stays the same for the same robot, so a run resumes."""
    context = IN_PROCESS + name
    _in_process_envs[context] = make_env
    try:
        yield context
    finally:
        _in_process_envs.pop(context, None)


def _in_process_vector_env(context: str, num_envs: int) -> SyncVectorEnv:
    if context not in _in_process_envs:
        raise RuntimeError(f"no environment is registered for {context!r} (see in_process_env)")
    if num_envs != 1:
        raise ValueError(f"an in-process environment is one robot: num_envs must be 1, got {num_envs}")
    make_env = _in_process_envs[context]
    return _InProcessVectorEnv([lambda: RLInfo(make_env())], autoreset_mode=AutoresetMode.SAME_STEP)


class _InProcessVectorEnv(SyncVectorEnv):
    """A SyncVectorEnv with AsyncVectorEnv's step_async / step_wait, which the trainer calls."""

    def step_async(self, actions: np.ndarray) -> None:
        self._pending_actions = actions

    def step_wait(self) -> tuple[Any, ...]:
        return self.step(self._pending_actions)


def replay_env_indices(num_envs: int, replay_envs: int) -> frozenset[int]:
    """Which environments practise in the replay room: `replay_envs` of them spread evenly over the
    environments (so over the groups too), never environment 0, the one the scene follows."""
    return frozenset(num_envs - 1 - (i * num_envs) // replay_envs for i in range(replay_envs))


def env_rooms(num_envs: int, room: Any, replay_envs: int = 0, replay_room: Any = None) -> list[Any]:
    """Each environment's room: `room`, but `replay_room` for the replay environments."""
    replays = replay_env_indices(num_envs, replay_envs)
    return [replay_room if i in replays else room for i in range(num_envs)]


class EnvGroups:
    def __init__(
        self,
        world: str,
        num_envs: int,
        groups: int,
        image_size: int,
        success_rule: str | None,
        max_steps: int | None,
        context: str,
        domains: list[Any] | None = None,
        world_options: dict[str, Any] | None = None,
    ) -> None:
        """`domains`: each environment's room as its world takes it (None: all in the training room);
        `world_options`: further keyword arguments of every world (`PPOConfig.world_options`)."""
        size = num_envs // groups
        domains = domains or [None] * num_envs
        self.num_envs = num_envs
        self.slices = [slice(g * size, (g + 1) * size) for g in range(groups)]
        self.vector_envs: list[AsyncVectorEnv | SyncVectorEnv] = [
            _in_process_vector_env(context, num_envs)
            if context.startswith(IN_PROCESS)
            else make_vector_env(
                world_id(world),
                size,
                image_size,
                success_rule,
                max_steps,
                domains=domains[group],
                context=context,
                world_options=world_options,
            )
            for group in self.slices
        ]

    def __iter__(self) -> Iterator[tuple[AsyncVectorEnv, slice]]:
        return iter(zip(self.vector_envs, self.slices, strict=True))

    @property
    def state_dim(self) -> int:
        return int(self.vector_envs[0].single_observation_space["state"].shape[0])

    @property
    def num_intents(self) -> int:
        return int(self.vector_envs[0].get_attr("num_intents")[0])

    def reset(self, seeds: list[int]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Reset every environment with its seed; observations and `RESET_INFO` of all of them."""
        results = [envs.reset(seed=seeds[group]) for envs, group in self]
        obs = {key: np.concatenate([o[key] for o, _ in results]) for key in ("image", "state")}
        info = {key: np.concatenate([i[key] for _, i in results]) for key in RESET_INFO}
        return obs, info

    def set_attr(self, name: str, values: list[Any]) -> None:
        """One value per environment, each sent to its worker (used at the worker's next reset or step)."""
        for envs, group in self:
            envs.set_attr(name, values[group])

    def worker_processes(self) -> list[psutil.Process]:
        processes = [p for envs in self.vector_envs for p in getattr(envs, "processes", ())]
        return [psutil.Process(p.pid) for p in processes if p.is_alive()]

    def close(self) -> None:
        for envs in self.vector_envs:
            envs.close()
        self.vector_envs = []


@dataclass
class EndedView:
    """A group's step as the reward sees it: where an episode ended, its final observation, not the reset."""

    images: np.ndarray
    state: np.ndarray  # float32
    heard: np.ndarray
    distance: np.ndarray
    success: np.ndarray  # the episode ended in success


def ended_view(obs: dict, info: dict, done: np.ndarray) -> EndedView:
    done_envs = np.flatnonzero(done)
    images, heard, distance = obs["image"], np.asarray(info["heard"]), np.asarray(info["distance"])
    state = np.asarray(obs["state"], dtype=np.float32)
    success = np.zeros(len(done), dtype=bool)
    if len(done_envs):
        final = info["final_info"]
        images, state = images.copy(), state.copy()
        heard, distance = heard.copy(), distance.copy()
        for e in done_envs:  # only the few environments that just ended
            images[e] = info["final_obs"][e]["image"]
            state[e] = info["final_obs"][e]["state"]
        heard[done_envs] = np.asarray(final["heard"])[done_envs]
        distance[done_envs] = np.asarray(final["distance"])[done_envs]
        success = np.asarray(final["success"], dtype=bool) & done
    return EndedView(images, state, heard, distance, success)
