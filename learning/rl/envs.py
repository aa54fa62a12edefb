"""Environment side of RL: what runs inside each worker process. No torch here, so workers stay small.

`RLInfo` gives every step and reset the same numeric info keys (the vector env stacks them into arrays), and
can play a fixed schedule of (intent, seed) episodes — the evaluation protocol uses that to give each worker
its share of the 50-episodes-per-intent list.
"""

import json
import multiprocessing
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AsyncVectorEnv, AutoresetMode

from sim.vector import worker_ignoring_ctrl_c

NO_SOUND = -1  # `heard` when nothing (or several things) is in view


class RLInfo(gym.Wrapper):
    """Normalises `info` to: intent (int), heard (int, -1 = nothing), success (bool), distance (float, m to
    the target, simulator ground truth used only by the shaped-reward baseline), episode (int, index within
    the schedule; -1 once a schedule is exhausted). With `intent_weights` set (the learner's curriculum, via
    `vector_env.set_attr`), an episode outside a schedule draws its intent with those probabilities instead
    of the world's uniform draw; with `start_strip_weights` set (the learner's start curriculum, block worlds
    only), it also draws the strip of the table its gripper starts in (`sim.blocks.start_strip_bounds`). With
    `mirror_in_info` set (the learner sets it on the
    one environment a watcher follows: `vector_env.set_attr`), also mirror: the world's pose as JSON
    (`sim.mirror`), so a watcher needs no extra round trip to the worker."""

    def __init__(self, env: gym.Env, schedule: Sequence[tuple[int, int]] | None = None) -> None:
        super().__init__(env)
        self.schedule = list(schedule) if schedule is not None else None
        self.episode = -1
        self.mirror_in_info = False
        self.intent_weights: list[float] | None = None
        self.start_strip_weights: list[float] | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        self.episode += 1
        options = dict(options or {})
        if self.schedule is not None and self.episode < len(self.schedule):
            intent, seed = self.schedule[self.episode]
            options["intent"] = intent
        else:
            self._draw_curriculum_options(seed, options)
        obs, info = self.env.reset(seed=seed, options=options or None)
        return obs, self._info(obs, info)

    def _draw_curriculum_options(self, seed: int | None, options: dict) -> None:
        """Add the curricula's draws (target, start strip) to `options`, unless the caller chose them."""
        curricula = (("intent", self.intent_weights), ("start_strip", self.start_strip_weights))
        wanted = [(key, weights) for key, weights in curricula if weights is not None and key not in options]
        if not wanted:
            return
        # a seeded reset draws from its seed, later episodes from the world's own (seeded) generator
        rng = np.random.default_rng(seed) if seed is not None else self.env.unwrapped.np_random
        for key, weights in wanted:
            options[key] = int(rng.choice(len(weights), p=weights))

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(reward), terminated, truncated, self._info(obs, info)

    def _info(self, obs: dict, info: dict) -> dict:
        heard = info.get("heard")
        in_schedule = self.schedule is None or self.episode < len(self.schedule)
        normalised = {
            "intent": int(info["intent"]),
            "heard": NO_SOUND if heard is None else int(heard),
            "success": bool(info.get("success", False)),
            "distance": target_distance(self.env, obs, info),
            "episode": self.episode if in_schedule else -1,
        }
        if self.mirror_in_info:
            normalised["mirror"] = json.dumps(self.env.unwrapped.mirror_state())
        return normalised


def target_distance(env: gym.Env, obs: dict, info: dict) -> float:
    """Ground-truth distance from the robot to the target (metres); only the shaped baseline reads it. Arm
    worlds: gripper (x, y) to the target block's centre; TurtleBot: bumper-to-object clearance."""
    if "target_clearance" in info:
        return float(info["target_clearance"])
    unwrapped = env.unwrapped
    if hasattr(unwrapped, "slot_position"):
        target = np.asarray(unwrapped.slot_position(int(info["intent"]))[:2])
        return float(np.linalg.norm(np.asarray(obs["state"][:2], dtype=np.float64) - target))
    return float("nan")


def make_env_fn(
    world_id: str,
    image_size: int,
    success_rule: str | None = None,
    max_steps: int | None = None,
    schedule: Sequence[tuple[int, int]] | None = None,
    domain: Any = None,
    world_options: dict[str, Any] | None = None,
) -> Callable[[], gym.Env]:
    """`world_options`: further keyword arguments of the world (benches: `visual_detail="full"`)."""

    def make() -> gym.Env:
        import sim  # noqa: F401  (registers the worlds inside the worker)

        kwargs: dict[str, Any] = {"image_size": image_size, "max_steps": max_steps, **(world_options or {})}
        if success_rule is not None:  # None: the world's own rule (Kuka "final", TurtleBot "hold")
            kwargs["success_rule"] = success_rule
        if domain is not None:
            kwargs["domain"] = domain
        return RLInfo(gym.make(world_id, **kwargs), schedule)

    return make


def make_vector_env(
    world_id: str,
    num_envs: int,
    image_size: int,
    success_rule: str | None = None,
    max_steps: int | None = None,
    schedules: Sequence[Sequence[tuple[int, int]]] | None = None,
    domains: Sequence[Any] | None = None,
    context: str = "forkserver",
    world_options: dict[str, Any] | None = None,
) -> AsyncVectorEnv:
    """`num_envs` worlds in their own processes, reset in the same step as they end (final observation in
    `info["final_obs"]`, the final step's info in `info["final_info"]`); `domains`: each world's room (None:
    all in the training room)."""
    if domains is not None and len(domains) != num_envs:
        raise ValueError(f"domains names {len(domains)} rooms for {num_envs} environments")
    if context == "forkserver":
        # the fork server imports these once; each worker forks from it instead of importing torch-free code
        # again
        multiprocessing.set_forkserver_preload(["learning.rl.envs", "sim.kuka_blocks", "sim.turtlebot_arena"])
    fns = [
        make_env_fn(
            world_id,
            image_size,
            success_rule,
            max_steps,
            schedules[i] if schedules else None,
            domains[i] if domains is not None else None,
            world_options,
        )
        for i in range(num_envs)
    ]
    return AsyncVectorEnv(
        fns, context=context, autoreset_mode=AutoresetMode.SAME_STEP, worker=worker_ignoring_ctrl_c
    )


def world_id(world: str) -> str:
    import sim

    if world not in sim.WORLDS:
        raise ValueError(f"unknown world {world!r}: choose one of {', '.join(sim.WORLDS)}")
    return sim.WORLDS[world]
