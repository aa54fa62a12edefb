"""The evaluation protocol, the same for every method: `episodes_per_intent` episodes per intent (50 → 200
for four intents), the deterministic policy (the Gaussian's mean), goal clips drawn from an unheard tier,
per-intent and mean success rate and episode length; optionally a GIF of a few episodes.

`final_view_by_intent` tells failures apart: for each intent, how many episodes ended with the robot at
each intent's object (the world's `heard` at the last step) or at none of them (the last column). A wrong
object means the goal was misunderstood; nothing means the robot aimed right but did not arrive.

The episode list (intent, seed) is fixed by `seed`, dealt round-robin to the workers (each worker plays its
share through `RLInfo`'s schedule), so every method meets exactly the same layouts, intents and goal clips.
"""

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from learning.rl.envs import NO_SOUND, make_vector_env, world_id
from learning.rl.policy import Policy, PolicyConfig
from learning.rl.rewards import ClipBank

NUM_INTENTS = 4  # every world has four intents (the shared contract)


@dataclass
class EpisodeResult:
    intent: int
    seed: int
    goal_clip: int
    success: bool
    length: int
    steps_to_success: int | None  # first step at which the world reported success
    final_distance: float  # ground truth, robot to target at the end (diagnosis only)
    final_heard: int  # the intent whose object the robot was at after the last step; NO_SOUND for none


@dataclass
class EvalResult:
    world: str
    split: str
    episodes_per_intent: int
    intent_names: list[str]
    success_by_intent: list[float]
    episodes_by_intent: list[int]
    success_rate: float
    mean_episode_length: float
    mean_steps_to_success: float | None
    mean_final_distance: float
    final_view_by_intent: list[list[int]]  # [intent][intent at the end, or the last column: none]
    episodes: list[EpisodeResult] = field(default_factory=list)
    gif: str | None = None

    def to_dict(self, with_episodes: bool = False) -> dict[str, Any]:
        data = asdict(self)
        if not with_episodes:
            data.pop("episodes")
        return data


def episode_schedule(
    num_intents: int, episodes_per_intent: int, seed: int, intents: Sequence[int] | None = None
) -> list[tuple[int, int]]:
    """The fixed evaluation list: (intent, layout seed) for every episode, intents interleaved; `intents`
    limits it to those (a household whose commands name only some of the world's targets)."""
    chosen = list(range(num_intents)) if intents is None else sorted(set(intents))
    seeds = np.random.SeedSequence([seed, 20230529]).generate_state(len(chosen) * episodes_per_intent)
    return [(chosen[k % len(chosen)], int(seeds[k])) for k in range(len(chosen) * episodes_per_intent)]


def deal(schedule: list[tuple[int, int]], num_envs: int) -> list[list[tuple[int, int]]]:
    return [schedule[i::num_envs] for i in range(num_envs)]


def evaluate(
    policy: Policy | None,
    var: torch.nn.Module | None,
    goals: ClipBank,
    world: str,
    image_size: int,
    split: str = "unheard",
    episodes_per_intent: int = 50,
    seed: int = 12345,
    num_envs: int = 8,
    success_rule: str | None = None,
    max_steps: int | None = None,
    domain: Any = None,
    gif_path: Path | None = None,
    gif_episodes: int = 4,
    progress: bool = True,
    intents: Sequence[int] | None = None,
    world_options: dict[str, Any] | None = None,
) -> EvalResult:
    """`world_options`: further keyword arguments of the world, as the policy was trained with them
    (`PPOConfig.world_options`)."""
    from tqdm.auto import tqdm

    if not goals.has_intents:
        raise ValueError("evaluation needs goal clips with known intents (an unheard tier of a corpus)")
    policy = policy.eval() if policy is not None else RandomPolicy(seed)
    config = policy.config
    schedule = episode_schedule(NUM_INTENTS, episodes_per_intent, seed, intents)
    num_envs = min(num_envs, len(schedule))
    shares = deal(schedule, num_envs)
    envs = make_vector_env(
        world_id(world), num_envs, image_size, success_rule, max_steps, schedules=shares,
        domains=[domain] * num_envs, world_options=world_options,
    )  # fmt: skip
    results: list[EpisodeResult] = []
    frames: list[np.ndarray] = []
    try:
        intent_names = list(envs.get_attr("intent_names")[0])
        if len(intent_names) != NUM_INTENTS:
            raise ValueError(f"{world} has {len(intent_names)} intents; the protocol expects {NUM_INTENTS}")
        obs, info = envs.reset()
        episode = np.asarray(info["episode"])
        goal_clip = _episode_goals(goals, np.asarray(info["intent"]), episode, num_envs, seed)
        length = np.zeros(num_envs, dtype=np.int64)
        first_success = np.full(num_envs, -1)
        hidden = policy.initial_state(num_envs)
        start = torch.ones(num_envs)
        bar = tqdm(total=len(schedule), unit="episode", desc=f"eval {world}", disable=not progress)
        with torch.inference_mode():
            goal_features = policy.encode_goal(goal_inputs(goals, goal_clip, config.goal_encoder))
            var_embedding = encode_views(var, obs["image"], config.var_dim)
            while len(results) < len(schedule):
                if gif_path is not None and episode[0] < gif_episodes and episode[0] >= 0:
                    frames.append(obs["image"][0])
                images = policy.view_of(torch.from_numpy(obs["image"]))
                state = torch.from_numpy(np.asarray(obs["state"], dtype=np.float32))
                mean, _, hidden = policy.step(images, var_embedding, state, goal_features, hidden, start)
                obs, _, terminated, truncated, info = envs.step(mean.clamp(-1.0, 1.0).numpy())
                length += 1
                done = terminated | truncated
                success_now = np.where(
                    done, info.get("final_info", {}).get("success", False), info["success"]
                )
                first_success = np.where((first_success < 0) & success_now, length, first_success)
                for e in np.flatnonzero(done):
                    if episode[e] >= 0:
                        intent, layout_seed = shares[e][episode[e]]
                        ok = bool(info["final_info"]["success"][e])
                        steps = int(first_success[e]) if first_success[e] > 0 and ok else None
                        distance = float(info["final_info"]["distance"][e])
                        heard = int(info["final_info"]["heard"][e])
                        results.append(
                            EpisodeResult(
                                intent, layout_seed, int(goal_clip[e]), ok, int(length[e]), steps, distance,
                                heard,
                            )
                        )  # fmt: skip
                        bar.update(1)
                length[done], first_success[done] = 0, -1
                start = torch.from_numpy(done.astype(np.float32))
                episode = np.where(done, np.asarray(info["episode"]), episode)
                var_embedding = encode_views(var, obs["image"], config.var_dim)
                if done.any():
                    ended = np.flatnonzero(done)
                    goal_clip[ended] = _episode_goals(
                        goals, np.asarray(info["intent"])[ended], episode[ended], num_envs, seed, ended
                    )
                    goal_features = goal_features.clone()
                    goal_features[ended] = policy.encode_goal(
                        goal_inputs(goals, goal_clip[ended], config.goal_encoder)
                    )
        bar.close()
    finally:
        envs.close()
    gif = _write_gif(frames, gif_path) if gif_path is not None and frames else None
    return _summarise(world, split, episodes_per_intent, intent_names, results, gif)


class RandomPolicy:
    """The random baseline: uniform actions in [-1, 1]², ignoring everything (same interface as `Policy`)."""

    def __init__(self, seed: int, action_dim: int = 2) -> None:
        self.config = PolicyConfig(
            image_size=0, state_dim=0, var_dim=0, goal_encoder="learned", policy_image_size=1
        )
        self.generator = torch.Generator().manual_seed(seed)
        self.action_dim = action_dim

    def eval(self) -> "RandomPolicy":
        return self

    def initial_state(self, batch: int) -> torch.Tensor:
        return torch.zeros(batch, 1)

    def encode_goal(self, goal: torch.Tensor) -> torch.Tensor:
        return torch.zeros(len(goal), 1)

    def view_of(self, images: torch.Tensor) -> torch.Tensor:
        return images

    def step(self, images, var_embedding, state, goal_features, hidden, episode_start):
        action = torch.rand(len(state), self.action_dim, generator=self.generator) * 2 - 1
        return action, torch.zeros(len(state)), hidden


def _episode_goals(
    goals: ClipBank,
    intents: np.ndarray,
    episodes: np.ndarray,
    num_envs: int,
    seed: int,
    envs: np.ndarray | None = None,
) -> np.ndarray:
    """The goal clip of each episode depends only on its place in the schedule, not on which worker plays it
    or when it finishes (worker e's j-th episode is schedule entry j·num_envs + e)."""
    envs = np.arange(len(intents)) if envs is None else envs
    picks = []
    for intent, episode, env in zip(intents, episodes, envs, strict=True):
        index = int(episode) * num_envs + int(env) if episode >= 0 else -1
        rng = np.random.default_rng([seed, index + 1])
        picks.append(goals.sample(np.array([intent]), rng)[0])
    return np.asarray(picks, dtype=np.int64)


def encode_views(var: torch.nn.Module | None, images: np.ndarray, var_dim: int) -> torch.Tensor:
    """f_I of each view, as the policy takes it (no columns for a policy that does not see the VAR)."""
    if var is None or var_dim == 0:
        return torch.zeros(len(images), 0)
    return var.encode_image(torch.from_numpy(images))


def goal_inputs(goals: ClipBank, clips: np.ndarray, goal_encoder: str) -> torch.Tensor:
    """What the policy's goal encoder takes for these clips: their VAR embeddings, or their features."""
    index = torch.from_numpy(np.asarray(clips))
    if goal_encoder == "var":
        return goals.embeddings[index]
    return torch.from_numpy(goals.features)[index]


def _summarise(
    world: str, split: str, per_intent: int, names: list[str], results: list[EpisodeResult], gif: str | None
) -> EvalResult:
    by_intent = [[r for r in results if r.intent == k] for k in range(len(names))]
    rates = [float(np.mean([r.success for r in rs])) if rs else float("nan") for rs in by_intent]
    to_success = [r.steps_to_success for r in results if r.steps_to_success is not None]
    return EvalResult(
        world=world,
        split=split,
        episodes_per_intent=per_intent,
        intent_names=names,
        success_by_intent=rates,
        episodes_by_intent=[len(rs) for rs in by_intent],
        success_rate=float(np.mean([r.success for r in results])),
        mean_episode_length=float(np.mean([r.length for r in results])),
        mean_steps_to_success=float(np.mean(to_success)) if to_success else None,
        mean_final_distance=float(np.mean([r.final_distance for r in results])),
        final_view_by_intent=final_view_counts(results, len(names)),
        episodes=results,
        gif=gif,
    )


def final_view_counts(results: list[EpisodeResult], num_intents: int) -> list[list[int]]:
    counts = np.zeros((num_intents, num_intents + 1), dtype=np.int64)
    for r in results:
        counts[r.intent, r.final_heard if r.final_heard != NO_SOUND else num_intents] += 1
    return counts.tolist()


def median_miss_by_intent(results: list[EpisodeResult], num_intents: int) -> list[float | None]:
    """Per intent, the median distance (m) from the robot to its target at the end of the tries that ended
    at no object: a few centimetres is a robot that stopped just beside its block, tens of centimetres one
    that ended elsewhere on the table. None where no try ended at no object."""
    missed: list[list[float]] = [[] for _ in range(num_intents)]
    for r in results:
        if r.final_heard == NO_SOUND:
            missed[r.intent].append(r.final_distance)
    return [float(np.median(distances)) if distances else None for distances in missed]


def _write_gif(frames: list[np.ndarray], path: Path, scale: int = 2) -> str:
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images = [
        Image.fromarray(f).resize((f.shape[1] * scale, f.shape[0] * scale), Image.NEAREST) for f in frames
    ]
    images[0].save(path, save_all=True, append_images=images[1:], duration=66, loop=0)
    return str(path)


def save_eval(result: EvalResult, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result.to_dict(with_episodes=True), indent=2))
