"""Several envs of one world in worker processes (PPO runs 8)."""

import functools
import signal
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from gymnasium.vector import AsyncVectorEnv
from gymnasium.vector.async_vector_env import _async_worker

# Workers start from a fresh interpreter (forkserver), never from a fork of a process whose torch threads
# are already running: forking those has deadlocked env workers on our 2-core machines.
DEFAULT_CONTEXT = "forkserver"


NOTHING_HEARD = -1  # as in the triplet datasets' heard.npy


class HeardAsInt(gym.Wrapper):
    """`info["heard"]` None -> -1: vector envs stack infos into typed arrays and cannot mix None and ints."""

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        return observation, _heard_as_int(info)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        return observation, reward, terminated, truncated, _heard_as_int(info)


def _heard_as_int(info: dict) -> dict:
    if info.get("heard", NOTHING_HEARD) is None:
        info = {**info, "heard": NOTHING_HEARD}
    return info


def _make(world: str, env_kwargs: dict) -> gym.Env:
    from sim import world_id  # registers the ids inside the worker process

    return HeardAsInt(gym.make(world_id(world), **env_kwargs))


def worker_ignoring_ctrl_c(*args: Any) -> None:
    """Ctrl-C in a terminal reaches the whole process group; the trainer that owns an env worker decides when
    it stops (after a checkpoint) and closes it, so the worker itself ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _async_worker(*args)


def env_factory(world: str, **env_kwargs) -> Callable[[], gym.Env]:
    """A picklable no-argument function that makes one env of `world` with `env_kwargs`."""
    return functools.partial(_make, world, env_kwargs)


def make_vector_env(
    world: str, num_envs: int = 8, context: str = DEFAULT_CONTEXT, **env_kwargs
) -> AsyncVectorEnv:
    if num_envs < 1:
        raise ValueError(f"num_envs must be at least 1, got {num_envs}")
    factories = [env_factory(world, **env_kwargs) for _ in range(num_envs)]
    return AsyncVectorEnv(factories, context=context, worker=worker_ignoring_ctrl_c)
