"""PPO with the VAR's intrinsic reward: one readable file, CleanRL-style, every PPO detail visible.

Where the time goes, and what this file does about it (the reference spends 91 % of its time in the update):
- environments step in 8 worker processes (`AsyncVectorEnv`, forkserver); torch threads are set in the learner
  only after the workers exist (threads configured before a fork have deadlocked workers on this machine);
- per step the learner makes one batched VAR call: f_I(I_{t+1}) is the reward now and the observation next
  step; f_S of every goal/current-sound clip is computed once when the run starts (the VAR is frozen);
- the policy CNN sees a 32×32 copy of the image (made once per step and stored), so an update over 800 steps
  costs well under a second; the update runs the CNN and heads on whole minibatches, only the GRU loops in
  time;
- rollouts run under `torch.inference_mode`; the learner uses one torch thread (`torch_threads`): on two busy
  cores a second thread made the many tiny GRU ops 10-30x slower (OpenMP barriers waiting for a descheduled
  thread).

Checkpoints are written every `checkpoint_every` updates together with all RNG states. At each such boundary
the environments are re-seeded and the recurrent state cleared, both in a continuing run and in a resumed one,
so a resumed run makes exactly the same next updates as one that never stopped.
"""

import contextlib
import json
import math
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np
import psutil
import torch
from torch import nn
from torch.nn import functional as F

from learning.rl.envs import NO_SOUND, make_vector_env, world_id
from learning.rl.policy import GoalFusion, Policy, PolicyConfig, downsample_images
from learning.rl.pretrain import load_encoders_into
from learning.rl.rewards import (
    ClipBank,
    CurrentSound,
    RewardKind,
    intrinsic_reward_from_embeddings,
    shaped_reward,
    sparse_reward,
)

CHECKPOINT_KIND = "varbot-policy"

# what runs saved before these options existed were trained with: the policy config's own defaults, and
# targets drawn uniformly
LEGACY_POLICY_OPTIONS = ("goal_fusion", "bounded_mean", "goal_match")
LEGACY_DEFAULTS = {
    **{f.name: f.default for f in fields(PolicyConfig) if f.name in LEGACY_POLICY_OPTIONS},
    "hard_target_share": 0.0,
}


@dataclass
class PPOConfig:
    # task
    world: str = "kuka"
    sounds: str = "wordset"  # corpus the goal clips come from
    goal_split: str = "train"
    reward: RewardKind = "var"
    current_sound: bool = (
        False  # add f_S(S_t)·f_S(S_goal), S_t = a clip of what is heard now (silence if nothing)
    )
    goal_encoder: Literal["var", "learned"] = (
        "var"  # "learned": the baselines' own MFCC encoder, no VAR input
    )
    aux_loss_coef: float = 0.0  # RSI-style auxiliary classification losses on ground-truth labels
    init_encoders: str | None = None  # one-hot pre-trained image + goal encoders (learning.rl.pretrain)
    goal_fusion: GoalFusion = "image"  # how the goal meets the observation (learning.rl.policy)
    bounded_mean: bool = True  # keep the Gaussian's mean inside the action range (learning.rl.policy)
    goal_match: bool = False  # the policy also sees f_I(I_t)·f_S(S_goal) (learning.rl.policy); experimental
    hard_target_share: float = 0.5  # share of episodes whose target favours low recent return (0: uniform)
    target_intents: list[int] | None = None  # diagnostics: the world asks only for these targets (None: all)
    image_size: int = 96  # rendered size; must equal the VAR's input size
    policy_image_size: int = 32
    success_rule: str | None = None  # None: the world's own rule (Kuka "final", TurtleBot "hold")
    max_episode_steps: int | None = None  # None: the world's own T (100)
    # PPO
    total_steps: int = 1_000_000
    num_envs: int = 8
    env_groups: int = (
        2  # groups of workers that step in turn while the learner serves the other (1: in lockstep)
    )
    num_steps: int = 100  # per environment per update: 800 steps per update
    learning_rate: float = 3e-4
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    num_minibatches: int = 2  # minibatches are sets of whole environments (recurrent sequences stay whole)
    update_epochs: int = 4
    norm_adv: bool = True
    clip_coef: float = 0.2
    clip_vloss: bool = True
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    normalize_reward: bool = True  # divide by the running std of the discounted return
    bootstrap_truncated: bool = True  # a time-limit end is not a real end: add γ·V(final observation)
    # run
    seed: int = 1
    torch_threads: int = 1  # 2 threads on 2 busy cores made the update 10-30x slower (OpenMP barriers)
    checkpoint_every: int = 25  # updates
    env_context: str = "forkserver"
    success_window: int = 100  # episodes in the "recent success rate"

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.batch_size)

    def validate(self) -> None:
        if self.num_envs % self.num_minibatches:
            raise ValueError(f"num_envs ({self.num_envs}) must be divisible by num_minibatches")
        if self.num_envs % self.env_groups:
            raise ValueError(
                f"num_envs ({self.num_envs}) must be divisible by env_groups ({self.env_groups})"
            )
        if self.reward == "var" and self.goal_encoder != "var":
            raise ValueError("the intrinsic reward needs the VAR's goal embedding: use goal_encoder='var'")
        if self.current_sound and self.reward != "var":
            raise ValueError("--current-sound adds to the intrinsic reward; it needs reward='var'")
        if not 0.0 <= self.hard_target_share <= 1.0:
            raise ValueError(f"hard_target_share must be in [0, 1], got {self.hard_target_share}")
        if self.target_intents is not None and not self.target_intents:
            raise ValueError("target_intents must name at least one target (None: all of them)")
        if self.aux_loss_coef and self.goal_encoder != "learned":
            raise ValueError("auxiliary losses train the baselines' own encoders: use goal_encoder='learned'")
        if self.init_encoders is not None and self.goal_encoder != "learned":
            raise ValueError(
                "pre-trained encoders replace the baselines' own encoders: use goal_encoder='learned'"
            )

    @classmethod
    def from_dict(cls, data: dict) -> "PPOConfig":
        """Settings saved by older versions lack newer fields: those get the value the old code used."""
        names = {f.name for f in fields(cls)}
        return cls(**{**LEGACY_DEFAULTS, **{k: v for k, v in data.items() if k in names}})


def _mean_or_nan(values: list[float]) -> float:
    """Mean of the known values; NaN when there are none (goals without intents have no success rate)."""
    known = [v for v in values if not math.isnan(v)]
    return float(np.mean(known)) if known else float("nan")


class RunningMeanStd:
    """Parallel-algorithm running moments (as gymnasium's NormalizeReward), for the discounted return."""

    def __init__(self) -> None:
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def update(self, x: np.ndarray) -> None:
        batch_mean, batch_var, batch_count = float(x.mean()), float(x.var()), x.size
        delta = batch_mean - self.mean
        total = self.count + batch_count
        self.mean += delta * batch_count / total
        m2 = self.var * self.count + batch_var * batch_count + delta**2 * self.count * batch_count / total
        self.var, self.count = m2 / total, total

    def state(self) -> list[float]:
        return [self.mean, self.var, self.count]


@dataclass
class Rollout:
    """Time-major buffers (T, E, ...) for one update, plus the recurrent state before step 0."""

    images: torch.Tensor
    var_embedding: torch.Tensor
    state: torch.Tensor
    goal: torch.Tensor  # VAR goal embedding (T, E, d), or goal clip index (T, E) for a learned encoder
    episode_start: torch.Tensor
    actions: torch.Tensor
    logprobs: torch.Tensor
    values: torch.Tensor
    rewards: torch.Tensor
    dones: torch.Tensor  # episode ended after this step
    heard: torch.Tensor  # ground truth, used only by the RSI auxiliary loss
    intent: torch.Tensor
    initial_hidden: torch.Tensor
    advantages: torch.Tensor | None = None
    returns: torch.Tensor | None = None


@dataclass
class Timings:
    env_s: float = 0.0  # waiting for the workers to step
    var_s: float = 0.0  # f_I on the new images (reward + next observation)
    policy_s: float = 0.0  # acting (policy forward + sampling) and preparing observations
    update_s: float = 0.0
    other_s: float = 0.0

    def shares(self) -> dict[str, float]:
        total = self.env_s + self.var_s + self.policy_s + self.update_s + self.other_s
        return {k: v / total if total else 0.0 for k, v in asdict(self).items()}


@dataclass
class RolloutStep:
    """Environment 0 right after one vector step, for a watcher (`PPOTrainer.train(on_rollout_step=...)`)."""

    global_step: int  # environment steps of the run so far, this step included
    image: np.ndarray  # env 0's camera now, uint8 (H, W, 3); after an end, the new episode's first frame
    reward: float  # env 0's reward for this step, before normalisation (the intrinsic reward for VAR runs)
    episode_ended: bool  # env 0's episode ended with this step (and env 0 was reset)
    goal_clip: int  # index into the goal bank of the clip env 0 now works toward
    mirror: Callable[[], dict[str, Any]]  # env 0's pose now (`sim.mirror`), decoded only when asked for


@dataclass
class EpisodeStats:
    returns: deque = field(default_factory=lambda: deque(maxlen=100))
    lengths: deque = field(default_factory=lambda: deque(maxlen=100))
    successes: deque = field(default_factory=lambda: deque(maxlen=100))
    intents: deque = field(default_factory=lambda: deque(maxlen=100))  # -1: unknown (older checkpoints)

    @classmethod
    def over_last(cls, episodes: int) -> "EpisodeStats":
        return cls(**{f.name: deque(maxlen=episodes) for f in fields(cls)})

    def success_by_intent(self, num_intents: int) -> list[float]:
        """Recent success rate of each intent's episodes (NaN for an intent with none in the window)."""
        pairs = list(zip(self.intents, self.successes, strict=True))
        return [_mean_or_nan([s for i, s in pairs if i == intent]) for intent in range(num_intents)]

    def return_by_intent(self, num_intents: int) -> list[float]:
        """Recent mean episode return of each intent (NaN for an intent with none in the window)."""
        pairs = list(zip(self.intents, self.returns, strict=True))
        return [_mean_or_nan([r for i, r in pairs if i == intent]) for intent in range(num_intents)]


def curriculum_weights(mean_returns: list[float], hard_share: float) -> list[float]:
    """Target probabilities: `1 - hard_share` spread evenly, `hard_share` in proportion to how far each
    target's recent mean return lies below the best one's. Uniform until every target has episodes.

    The returns are whatever the run is rewarded with (the intrinsic reward for VAR runs), so a target the
    policy has not learned yet comes up more often, without its success being known."""
    k = len(mean_returns)
    if not k:
        return []
    gaps = max(mean_returns) - np.asarray(mean_returns, dtype=np.float64)
    if np.isnan(gaps).any() or gaps.sum() <= 0:
        return [1.0 / k] * k
    weights = (1.0 - hard_share) / k + hard_share * gaps / gaps.sum()
    return [float(w) for w in weights / weights.sum()]


class PPOTrainer:
    """Owns the environments, the frozen VAR, the policy and the optimiser for one run directory."""

    def __init__(
        self,
        config: PPOConfig,
        run_dir: Path,
        var: nn.Module | None,
        goals: ClipBank,
        current_sounds: ClipBank | None = None,
        init_policy: Path | None = None,
        var_path: str | None = None,
        label_counts: dict[str, int] | None = None,
    ) -> None:
        config.validate()
        self.config = config
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.var = var.eval().requires_grad_(False) if var is not None else None
        if config.goal_encoder == "var" and self.var is None:
            raise ValueError("this configuration needs a VAR checkpoint (--var)")
        if self.var is not None and self.var.config.image_size != config.image_size:
            raise ValueError(
                f"the VAR was trained on {self.var.config.image_size}px images but image_size is "
                f"{config.image_size}; render at the VAR's size (--image-size {self.var.config.image_size})"
            )
        self.var_path = var_path
        self.label_counts = dict(label_counts or {})
        self.goals = goals
        if config.current_sound and current_sounds is None:
            raise ValueError("--current-sound needs the training clips of the corpus")
        self.current_sounds = current_sounds if config.current_sound else None
        self.current: CurrentSound | None = None
        self.goal_features_table = torch.from_numpy(goals.features)
        self.vector_envs: list = []
        self.update_index = 0  # updates completed
        self.global_step = 0
        self.rng = np.random.default_rng(config.seed)
        self.torch_rng = torch.Generator().manual_seed(config.seed)
        self.return_rms = RunningMeanStd()
        self.stats = EpisodeStats.over_last(config.success_window)
        self.timings = Timings()
        self.peak_memory_bytes = 0
        self.policy: Policy | None = None
        self.init_policy = init_policy
        self.needs_reset = True  # environments are (re-)seeded before the first update and after a resume
        self.intent_weights: list[float] | None = None  # the curriculum's last target probabilities
        self.on_rollout_step: Callable[[RolloutStep], None] | None = None  # see `watch`

    # -- set-up ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the workers, then (only then) configure torch threads and build the policy."""
        c = self.config
        size = c.num_envs // c.env_groups
        self.groups = [slice(g * size, (g + 1) * size) for g in range(c.env_groups)]
        self.vector_envs = [
            make_vector_env(
                world_id(c.world),
                size,
                c.image_size,
                c.success_rule,
                c.max_episode_steps,
                context=c.env_context,
            )
            for _ in self.groups
        ]
        torch.set_num_threads(c.torch_threads)
        self._embed_sounds()
        first = self.vector_envs[0]
        self.state_dim = int(first.single_observation_space["state"].shape[0])
        self.num_intents = int(first.get_attr("num_intents")[0])
        unknown = sorted(set(c.target_intents or []) - set(range(self.num_intents)))
        if unknown:
            self.close()
            raise ValueError(
                f"target_intents {unknown} are not targets of the {c.world} world (0..{self.num_intents - 1})"
            )
        torch.manual_seed(c.seed)
        policy_config = PolicyConfig(
            image_size=c.image_size,
            state_dim=self.state_dim,
            var_dim=self.var.config.embedding_dim if c.goal_encoder == "var" else 0,
            goal_encoder=c.goal_encoder,
            goal_dim=self.var.config.embedding_dim if self.var is not None else 3,
            policy_image_size=c.policy_image_size,
            num_intents=self.num_intents,
            aux_heads=c.aux_loss_coef > 0,
            goal_fusion=c.goal_fusion,
            bounded_mean=c.bounded_mean,
            goal_match=c.goal_match,
        )
        self.policy = Policy(policy_config)
        if c.init_encoders is not None:
            self.label_counts.update(load_encoders_into(self.policy, c.init_encoders))
        if self.init_policy is not None:
            payload = read_policy_checkpoint(self.init_policy)
            if PolicyConfig(**payload["policy_config"]) != policy_config:
                raise ValueError(
                    f"{self.init_policy} holds a policy for {payload['policy_config']}, this run needs "
                    f"{policy_config.to_dict()}"
                )
            self.policy.load_state_dict(payload["policy"])
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=c.learning_rate, eps=1e-5)
        self.hidden = self.policy.initial_state(c.num_envs)

    def _embed_sounds(self) -> None:
        """f_S of every goal (and current-sound) clip, once. Done after the thread count is set: the same
        clips embedded with another number of threads differ in the last bits, and a resumed run would then
        not repeat the original one exactly."""
        if self.var is None:
            return
        if self.goals.embeddings is None:
            self.goals.embed(self.var)
        if self.current_sounds is not None:
            if self.current_sounds.embeddings is None:
                self.current_sounds.embed(self.var)
            with torch.inference_mode():
                silence = self.var.encode_silence()
            self.current = CurrentSound(self.current_sounds, silence)

    def close(self) -> None:
        for envs in self.vector_envs:
            envs.close()
        self.vector_envs = []

    # -- observations and goals ------------------------------------------------------------------------------
    def _encode_images(self, images: np.ndarray) -> torch.Tensor:
        if self.var is None:
            return torch.zeros(len(images), 0)
        return self.var.encode_image(torch.from_numpy(images))

    def _goal_inputs(self, clip_indices: np.ndarray) -> torch.Tensor:
        index = torch.from_numpy(clip_indices)
        if self.config.goal_encoder == "var":
            return self.goals.embeddings[index]
        return self.goal_features_table[index]

    def _new_goals(self, envs: np.ndarray, intents: np.ndarray) -> None:
        """A fresh goal clip for each environment that starts an episode; its features computed once here."""
        self.goal_clip[envs] = self.goals.sample(intents, self.rng)
        self.goal_input[envs] = self._goal_inputs(self.goal_clip[envs])
        self.goal_features[envs] = self.policy.encode_goal(self.goal_input[envs])

    def _send_intent_weights(self) -> None:
        """The target probabilities (curriculum, restricted targets), to every worker; they use them at their
        next resets."""
        c = self.config
        if not (c.hard_target_share or c.target_intents) or not self.goals.has_intents:
            return
        targets = sorted(set(c.target_intents or range(self.num_intents)))
        returns = self.stats.return_by_intent(self.num_intents)
        weights = [0.0] * self.num_intents
        for target, weight in zip(
            targets, curriculum_weights([returns[t] for t in targets], c.hard_target_share), strict=True
        ):
            weights[target] = weight
        if weights == self.intent_weights:
            return  # the workers already hold them (a fresh trainer starts from None: it always sends)
        for envs in self.vector_envs:
            envs.set_attr("intent_weights", [weights] * envs.num_envs)
        self.intent_weights = weights

    def _reset_envs(self) -> None:
        """Re-seed every environment (at the start and checkpoint boundaries); clear per-episode state."""
        c, E = self.config, self.config.num_envs
        self._send_intent_weights()
        seeds = [int(s) for s in np.random.SeedSequence([c.seed, self.update_index]).generate_state(E)]
        results = [
            envs.reset(seed=seeds[group]) for envs, group in zip(self.vector_envs, self.groups, strict=True)
        ]
        images = np.concatenate([obs["image"] for obs, _ in results])
        info = {key: np.concatenate([i[key] for _, i in results]) for key in ("intent", "heard", "distance")}
        self.needs_reset = False
        with torch.inference_mode():
            self.next_policy_images = downsample_images(torch.from_numpy(images), c.policy_image_size)
            self.next_var = self._encode_images(images)
        self.next_state = torch.from_numpy(np.concatenate([obs["state"] for obs, _ in results])).float()
        self.next_start = torch.ones(E)
        self.intent = info["intent"].astype(np.int64)
        self.heard = info["heard"].astype(np.int64)
        self.distance = info["distance"].astype(np.float64)
        self.hidden = self.policy.initial_state(E)
        self.discounted_return = np.zeros(E)
        self.episode_return = np.zeros(E)
        self.episode_length = np.zeros(E, dtype=np.int64)
        self.goal_clip = np.zeros(E, dtype=np.int64)
        goal_shape = (
            self.goals.embeddings.shape[1:] if c.goal_encoder == "var" else self.goals.features.shape[1:]
        )
        self.goal_input = torch.zeros(E, *goal_shape)
        self.goal_features = torch.zeros(E, self.policy.goal_feature_size)
        with torch.inference_mode():
            self._new_goals(np.arange(E), self.intent)

    # -- rollout ---------------------------------------------------------------------------------------------
    def _allocate(self) -> Rollout:
        c, T, E = self.config, self.config.num_steps, self.config.num_envs
        p = c.policy_image_size
        goal = (
            torch.zeros(T, E, self.goal_input.shape[1])
            if c.goal_encoder == "var"
            else torch.zeros(T, E, dtype=torch.int64)
        )
        return Rollout(
            images=torch.zeros(T, E, p, p, 3, dtype=torch.uint8),
            var_embedding=torch.zeros(T, E, self.next_var.shape[1]),
            state=torch.zeros(T, E, self.state_dim),
            goal=goal,
            episode_start=torch.zeros(T, E),
            actions=torch.zeros(T, E, 2),
            logprobs=torch.zeros(T, E),
            values=torch.zeros(T, E),
            rewards=torch.zeros(T, E),
            dones=torch.zeros(T, E),
            heard=torch.zeros(T, E, dtype=torch.int64),
            intent=torch.zeros(T, E, dtype=torch.int64),
            initial_hidden=self.hidden.clone(),
        )

    def collect_rollout(self) -> tuple[Rollout, list[dict[str, float]]]:
        """`num_steps` steps of every environment. The environments run in `env_groups` groups that take
        turns: while one group's workers step, the learner embeds, rewards and acts for the group that just
        returned, so workers and learner wait less for each other (one group: plain lockstep). Every
        environment still acts with exactly the current policy: this is on-policy PPO."""
        c = self.config
        finished: list[dict[str, float]] = []
        buf = self._allocate()  # outside inference mode: the update needs these as ordinary tensors
        self._send_intent_weights()
        with torch.inference_mode():
            # policy parameters changed in the last update: recompute the (once per episode) goal features
            self.goal_features = self.policy.encode_goal(self.goal_input)
            for envs, group in zip(self.vector_envs, self.groups, strict=True):
                self._act(buf, 0, group, envs)
            for t in range(c.num_steps):
                for envs, group in zip(self.vector_envs, self.groups, strict=True):
                    tick = time.perf_counter()
                    obs, _, terminated, truncated, info = envs.step_wait()
                    self.timings.env_s += time.perf_counter() - tick
                    buf.rewards[t, group], buf.dones[t, group], raw = self._after_step(
                        group, obs, terminated, truncated, info, finished
                    )
                    if self.on_rollout_step is not None and group.start == 0:
                        self._watch(t, obs["image"][0], raw[0], terminated[0] or truncated[0], info)
                    if t + 1 < c.num_steps:
                        self._act(buf, t + 1, group, envs)
            # value of the observation after the last step, for GAE (the hidden state is not advanced)
            _, next_value, _ = self.policy.step(
                self.next_policy_images,
                self.next_var,
                self.next_state,
                self.goal_features,
                self.hidden,
                self.next_start,
            )
        self._compute_advantages(buf, next_value)
        self.global_step += c.batch_size
        return buf, finished

    def watch(self, on_rollout_step: Callable[[RolloutStep], None] | None) -> None:
        """Call `on_rollout_step` after every step of env 0 from now on (None: stop watching). Env 0 then puts
        its pose into its info (`RLInfo.mirror_in_info`): a watcher costs the learner no round trip."""
        self.on_rollout_step = on_rollout_step
        first = self.vector_envs[0]
        first.set_attr("mirror_in_info", [on_rollout_step is not None] + [False] * (first.num_envs - 1))

    def _watch(self, t: int, image: np.ndarray, reward: float, ended: bool, info: dict) -> None:
        pose = info["mirror"][0]
        self.on_rollout_step(
            RolloutStep(
                global_step=self.global_step + (t + 1) * self.config.num_envs,
                image=image,
                reward=float(reward),
                episode_ended=bool(ended),
                goal_clip=int(self.goal_clip[0]),
                mirror=lambda: json.loads(pose),
            )
        )

    def _act(self, buf: Rollout, t: int, group: slice, envs: Any) -> None:
        """Store the group's observation at step t, sample its actions and send them to its workers."""
        tick = time.perf_counter()
        c = self.config
        buf.images[t, group] = self.next_policy_images[group]
        buf.var_embedding[t, group] = self.next_var[group]
        buf.state[t, group] = self.next_state[group]
        goal = self.goal_input[group] if c.goal_encoder == "var" else torch.from_numpy(self.goal_clip[group])
        buf.goal[t, group] = goal
        buf.episode_start[t, group] = self.next_start[group]
        buf.heard[t, group] = torch.from_numpy(self.heard[group])
        buf.intent[t, group] = torch.from_numpy(self.intent[group])
        mean, value, self.hidden[group] = self.policy.step(
            self.next_policy_images[group],
            self.next_var[group],
            self.next_state[group],
            self.goal_features[group],
            self.hidden[group],
            self.next_start[group],
        )
        std = self.policy.actor_logstd.exp().expand_as(mean)
        action = mean + std * torch.randn(mean.shape, generator=self.torch_rng)
        buf.actions[t, group] = action
        buf.logprobs[t, group] = self.policy.distribution(mean).log_prob(action).sum(-1)
        buf.values[t, group] = value
        envs.step_async(action.clamp(-1.0, 1.0).numpy())
        self.timings.policy_s += time.perf_counter() - tick

    def _after_step(
        self,
        group: slice,
        obs: dict,
        terminated: np.ndarray,
        truncated: np.ndarray,
        info: dict,
        finished: list,
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """Reward for the group's step just taken, then its next observation (new goals where episodes
        started). Indices in `done_envs` are within the group; `group.start + i` is the environment.
        Returns the normalised reward, the episode ends and the raw reward."""
        c = self.config
        done = terminated | truncated
        done_envs = np.flatnonzero(done)
        n = len(done)
        images = obs["image"]
        reward_images, heard_after = images, np.asarray(info["heard"])
        distance_after = np.asarray(info["distance"])
        final_success = np.zeros(n, dtype=bool)
        final_state = None
        if len(done_envs):
            final = info["final_info"]
            reward_images = images.copy()
            final_state = np.asarray(obs["state"], dtype=np.float32).copy()
            heard_after, distance_after = heard_after.copy(), distance_after.copy()
            for e in done_envs:  # only the few environments that just ended
                reward_images[e] = info["final_obs"][e]["image"]
                final_state[e] = info["final_obs"][e]["state"]
            heard_after[done_envs] = np.asarray(final["heard"])[done_envs]
            distance_after[done_envs] = np.asarray(final["distance"])[done_envs]
            final_success = np.asarray(final["success"], dtype=bool) & done

        # one VAR call: the reward images (final observations where an episode ended) and the reset images
        tick = time.perf_counter()
        embedded = self._encode_images(
            np.concatenate([reward_images, images[done_envs]]) if len(done_envs) else reward_images
        )
        reward_embedding, reset_embedding = embedded[:n], embedded[n:]
        self.timings.var_s += time.perf_counter() - tick

        tick = time.perf_counter()
        raw = self._reward(group, reward_embedding, heard_after, distance_after, done, final_success)
        reward = self._normalise(group, raw, done)
        cut = np.flatnonzero(truncated & ~terminated) if c.bootstrap_truncated else []
        if len(cut):
            final_images = downsample_images(torch.from_numpy(reward_images[cut]), c.policy_image_size)
            envs = torch.from_numpy(cut + group.start)
            _, final_value, _ = self.policy.step(
                final_images,
                reward_embedding[cut],
                torch.from_numpy(final_state[cut]),
                self.goal_features[envs],
                self.hidden[envs],
                torch.zeros(len(cut)),
            )
            reward[cut] += c.gamma * final_value

        self._track_episodes(group, raw, done, final_success, finished)
        next_var = reward_embedding.clone()
        if len(done_envs):
            next_var[done_envs] = reset_embedding
        self.next_var[group] = next_var
        self.next_policy_images[group] = downsample_images(torch.from_numpy(images), c.policy_image_size)
        self.next_state[group] = torch.from_numpy(np.asarray(obs["state"], dtype=np.float32))
        self.next_start[group] = torch.from_numpy(done.astype(np.float32))
        self.heard[group] = np.asarray(info["heard"], dtype=np.int64)
        self.intent[group] = np.asarray(info["intent"], dtype=np.int64)
        self.distance[group] = np.asarray(info["distance"], dtype=np.float64)
        if len(done_envs):
            started = done_envs + group.start
            self._new_goals(started, self.intent[started])
        self.timings.policy_s += time.perf_counter() - tick
        return reward, torch.from_numpy(done.astype(np.float32)), raw

    def _reward(
        self,
        group: slice,
        image_embedding: torch.Tensor,
        heard_after: np.ndarray,
        distance_after: np.ndarray,
        done: np.ndarray,
        final_success: np.ndarray,
    ) -> np.ndarray:
        c = self.config
        if c.reward == "var":
            current = self.current.embeddings(heard_after, self.rng) if self.current is not None else None
            goal = self.goals.embeddings[torch.from_numpy(self.goal_clip[group])]
            return intrinsic_reward_from_embeddings(image_embedding, goal, current).numpy().astype(np.float64)
        if c.reward == "sparse":
            return sparse_reward(done, final_success).astype(np.float64)
        return shaped_reward(self.distance[group], distance_after, done, final_success).astype(np.float64)

    def _normalise(self, group: slice, raw: np.ndarray, done: np.ndarray) -> torch.Tensor:
        """Divide by the running std of the discounted return (as gymnasium's NormalizeReward, per env)."""
        c = self.config
        if not c.normalize_reward:
            return torch.from_numpy(raw.astype(np.float32))
        returns = self.discounted_return[group] * c.gamma + raw
        self.return_rms.update(returns)
        returns[done] = 0.0
        self.discounted_return[group] = returns
        return torch.from_numpy((raw / math.sqrt(self.return_rms.var + 1e-8)).astype(np.float32))

    def _track_episodes(
        self, group: slice, raw: np.ndarray, done: np.ndarray, success: np.ndarray, finished: list
    ) -> None:
        self.episode_return[group] += raw
        self.episode_length[group] += 1
        for e in np.flatnonzero(done) + group.start:
            ok = float(success[e - group.start]) if self.goals.has_intents else float("nan")
            episode = {
                "return": float(self.episode_return[e]),
                "length": int(self.episode_length[e]),
                "success": ok,
            }
            finished.append(episode)
            self.stats.returns.append(episode["return"])
            self.stats.lengths.append(episode["length"])
            self.stats.successes.append(ok)
            self.stats.intents.append(int(self.intent[e]))
        self.episode_return[group][done] = 0.0
        self.episode_length[group][done] = 0

    def _compute_advantages(self, buf: Rollout, next_value: torch.Tensor) -> None:
        """GAE(λ). A time-limit end was already bootstrapped into its reward, so every end stops the trace."""
        c = self.config
        advantages = torch.zeros_like(buf.rewards)
        last = torch.zeros(c.num_envs)
        for t in reversed(range(c.num_steps)):
            next_values = next_value if t == c.num_steps - 1 else buf.values[t + 1]
            not_done = 1.0 - buf.dones[t]
            delta = buf.rewards[t] + c.gamma * next_values * not_done - buf.values[t]
            last = delta + c.gamma * c.gae_lambda * not_done * last
            advantages[t] = last
        buf.advantages = advantages
        buf.returns = advantages + buf.values

    # -- update ----------------------------------------------------------------------------------------------
    def _minibatch_goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        """Goal features for (T, B) steps, with gradients; a learned encoder runs once per distinct clip."""
        if self.config.goal_encoder == "var":
            return self.policy.encode_goal(goal)
        clips, inverse = torch.unique(goal, return_inverse=True)
        features = self.policy.encode_goal(self.goal_features_table[clips])
        return features[inverse]

    def update(self, buf: Rollout) -> dict[str, float]:
        c = self.config
        if c.anneal_lr:
            frac = 1.0 - self.update_index / c.num_updates
            self.optimizer.param_groups[0]["lr"] = max(frac, 0.0) * c.learning_rate
        envs_per_minibatch = c.num_envs // c.num_minibatches
        clipfracs, stats = [], {}
        for _ in range(c.update_epochs):
            order = torch.randperm(c.num_envs, generator=self.torch_rng)
            for start in range(0, c.num_envs, envs_per_minibatch):
                idx = order[start : start + envs_per_minibatch]
                goal_features = self._minibatch_goal_features(buf.goal[:, idx])
                mean, new_value, inputs = self.policy.evaluate_sequences(
                    buf.images[:, idx],
                    buf.var_embedding[:, idx],
                    buf.state[:, idx],
                    goal_features,
                    buf.initial_hidden[idx],
                    buf.episode_start[:, idx],
                )
                dist = self.policy.distribution(mean)
                new_logprob = dist.log_prob(buf.actions[:, idx]).sum(-1)
                entropy = dist.entropy().sum(-1)
                log_ratio = new_logprob - buf.logprobs[:, idx]
                ratio = log_ratio.exp()
                with torch.no_grad():
                    approx_kl = ((ratio - 1) - log_ratio).mean()
                    clipfracs.append(((ratio - 1.0).abs() > c.clip_coef).float().mean().item())

                advantages = buf.advantages[:, idx]
                if c.norm_adv:
                    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
                pg_loss = torch.max(
                    -advantages * ratio, -advantages * ratio.clamp(1 - c.clip_coef, 1 + c.clip_coef)
                ).mean()

                returns, old_values = buf.returns[:, idx], buf.values[:, idx]
                if c.clip_vloss:
                    v_clipped = old_values + (new_value - old_values).clamp(-c.clip_coef, c.clip_coef)
                    v_loss = 0.5 * torch.max((new_value - returns) ** 2, (v_clipped - returns) ** 2).mean()
                else:
                    v_loss = 0.5 * ((new_value - returns) ** 2).mean()
                entropy_loss = entropy.mean()
                loss = pg_loss - c.ent_coef * entropy_loss + v_loss * c.vf_coef
                aux_loss = torch.zeros(())
                if c.aux_loss_coef:
                    aux_loss = self._aux_loss(inputs, goal_features, buf.heard[:, idx], buf.intent[:, idx])
                    loss = loss + c.aux_loss_coef * aux_loss

                self.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(self.policy.parameters(), c.max_grad_norm)
                self.optimizer.step()
            if c.target_kl is not None and approx_kl > c.target_kl:
                break

        y_pred, y_true = buf.values.flatten().numpy(), buf.returns.flatten().numpy()
        var_y = np.var(y_true)
        stats.update(
            {
                "learning_rate": self.optimizer.param_groups[0]["lr"],
                "value_loss": v_loss.item(),
                "policy_loss": pg_loss.item(),
                "entropy": entropy_loss.item(),
                "approx_kl": approx_kl.item(),
                "clipfrac": float(np.mean(clipfracs)),
                "explained_variance": float("nan")
                if var_y == 0
                else float(1 - np.var(y_true - y_pred) / var_y),
                "aux_loss": aux_loss.item(),
                "action_std": self.policy.actor_logstd.exp().mean().item(),
            }
        )
        return stats

    def _aux_loss(
        self, inputs: torch.Tensor, goal_features: torch.Tensor, heard: torch.Tensor, intent: torch.Tensor
    ) -> torch.Tensor:
        """RSI-style: classify what is in view (intents + "nothing") and which intent the goal is."""
        view_labels = torch.where(heard == NO_SOUND, self.num_intents, heard)
        view = F.cross_entropy(self.policy.aux_view(inputs.flatten(0, 1)), view_labels.flatten())
        goal = F.cross_entropy(self.policy.aux_goal(goal_features.flatten(0, 1)), intent.flatten())
        return view + goal

    # -- the loop --------------------------------------------------------------------------------------------
    def train(
        self,
        progress: bool = True,
        on_update: Callable[[dict[str, Any]], bool | None] | None = None,
        on_rollout_step: Callable[[RolloutStep], None] | None = None,
    ) -> dict[str, Any]:
        """Run to `total_steps`. `on_update(metrics)` is called after every update; returning True stops early
        (cooperative cancel) after the next checkpoint is written. `on_rollout_step(step)` is called after
        every step of env 0 (a watcher decides itself how often to act on it); None costs nothing."""
        from tqdm.auto import tqdm

        from learning.rl.plots import plot_run

        c = self.config
        if self.policy is None:
            self.start()
        self.watch(on_rollout_step)
        metrics_path = self.run_dir / "metrics.jsonl"
        bar = tqdm(
            total=c.num_updates * c.batch_size, initial=self.global_step, unit="step", disable=not progress
        )
        stop = False
        try:
            while self.update_index < c.num_updates and not stop:
                if self.needs_reset or self.update_index % c.checkpoint_every == 0:
                    self._reset_envs()
                record = self.run_one_update()
                with metrics_path.open("a") as f:
                    f.write(json.dumps(record) + "\n")
                bar.update(c.batch_size)
                bar.set_postfix(sps=f"{record['sps']:.0f}", success=f"{record['recent_success']:.2f}")
                if on_update is not None and on_update(record):
                    stop = True
                if self.update_index % c.checkpoint_every == 0 or self.update_index == c.num_updates or stop:
                    self.save_checkpoint()
                    plot_run(self.run_dir)  # curves.png stays current during long runs
        finally:
            bar.close()
        return self.summary()

    def run_one_update(self) -> dict[str, Any]:
        started = time.perf_counter()
        before = Timings(**asdict(self.timings))
        buf, finished = self.collect_rollout()
        tick = time.perf_counter()
        stats = self.update(buf)
        self.timings.update_s += time.perf_counter() - tick
        self.update_index += 1
        self._sample_memory()
        elapsed = time.perf_counter() - started
        self.timings.other_s += elapsed - sum(asdict(self.timings).values()) + sum(asdict(before).values())
        return {
            "update": self.update_index,
            "global_step": self.global_step,
            "sps": self.config.batch_size / elapsed,
            "episodes": len(finished),
            "episode_return": float(np.mean([e["return"] for e in finished])) if finished else float("nan"),
            "episode_length": float(np.mean([e["length"] for e in finished])) if finished else float("nan"),
            "success": _mean_or_nan([e["success"] for e in finished]),
            "recent_success": _mean_or_nan(list(self.stats.successes)),
            "recent_success_by_intent": self.stats.success_by_intent(self.num_intents),
            "intent_weights": self.intent_weights,
            "time": {k: round(v - getattr(before, k), 4) for k, v in asdict(self.timings).items()},
            "peak_memory_mb": self.peak_memory_bytes / 2**20,
            **stats,
        }

    def _sample_memory(self) -> None:
        """Learner + worker processes: proportional set sizes summed (shared pages counted once)."""
        processes = [psutil.Process(os.getpid())]
        processes += [
            psutil.Process(p.pid) for envs in self.vector_envs for p in envs.processes if p.is_alive()
        ]
        total = 0
        for process in processes:
            with contextlib.suppress(psutil.Error):  # a worker that just exited
                total += process.memory_full_info().pss
        self.peak_memory_bytes = max(self.peak_memory_bytes, total)

    def summary(self) -> dict[str, Any]:
        return {
            "updates": self.update_index,
            "env_steps": self.global_step,
            "recent_success": _mean_or_nan(list(self.stats.successes)),
            "time_shares": self.timings.shares(),
            "time_s": asdict(self.timings),
            "peak_memory_mb": self.peak_memory_bytes / 2**20,
            "labels": self.labels_used(),
        }

    def labels_used(self) -> dict[str, int]:
        """The paper's accounting: a VAR triplet is 2 labels; each extrinsic-reward step is a simulator query;
        each auxiliary-loss step uses 2 ground-truth labels (what is in view, which intent)."""
        counts = dict(self.label_counts)
        if self.config.reward in ("sparse", "shaped"):
            counts["reward_queries"] = self.global_step
        if self.config.aux_loss_coef:
            counts["aux_labels"] = 2 * self.global_step
        counts["total"] = sum(v for k, v in counts.items() if k != "total")
        return counts

    # -- checkpoints -----------------------------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.run_dir / "checkpoint.pt"

    def save_checkpoint(self, path: Path | None = None) -> Path:
        path = path or self.checkpoint_path
        payload = {
            "kind": CHECKPOINT_KIND,
            "config": asdict(self.config),
            "policy_config": self.policy.config.to_dict(),
            "policy": self.policy.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "update_index": self.update_index,
            "global_step": self.global_step,
            "return_rms": self.return_rms.state(),
            "numpy_rng": self.rng.bit_generator.state,
            "torch_rng": self.torch_rng.get_state(),
            "stats": {k: list(v) for k, v in vars(self.stats).items()},
            "timings": asdict(self.timings),
            "peak_memory_bytes": self.peak_memory_bytes,
            "var_path": self.var_path,
            "label_counts": self.label_counts,
        }
        temporary = path.with_name(path.name + ".tmp")
        torch.save(payload, temporary)
        os.replace(temporary, path)
        if self.update_index % self.config.checkpoint_every == 0:
            torch.save(payload, self.run_dir / f"checkpoint_{self.update_index:06d}.pt")
        return path

    def load_checkpoint(self, path: Path | None = None) -> None:
        """Restore everything a run needs to continue exactly (call after `start`)."""
        payload = read_policy_checkpoint(path or self.checkpoint_path)
        self.policy.load_state_dict(payload["policy"])
        self.optimizer.load_state_dict(payload["optimizer"])
        self.update_index = payload["update_index"]
        self.global_step = payload["global_step"]
        self.return_rms.mean, self.return_rms.var, self.return_rms.count = payload["return_rms"]
        self.rng.bit_generator.state = payload["numpy_rng"]
        self.torch_rng.set_state(payload["torch_rng"])
        stats = {"intents": [-1] * len(payload["stats"]["successes"]), **payload["stats"]}
        for key, values in stats.items():
            getattr(self.stats, key).extend(values)
        self.timings = Timings(**payload["timings"])
        self.peak_memory_bytes = payload["peak_memory_bytes"]
        self.label_counts = payload.get("label_counts", self.label_counts)
        self.needs_reset = True
        metrics = self.run_dir / "metrics.jsonl"
        if metrics.exists():  # drop records of updates made after this checkpoint
            kept = [
                line
                for line in metrics.read_text().splitlines()
                if json.loads(line)["update"] <= self.update_index
            ]
            metrics.write_text("".join(line + "\n" for line in kept))


def read_policy_checkpoint(path: Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy checkpoint at {path}; train one with `varbot rl train`")
    payload = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(payload, dict) or payload.get("kind") != CHECKPOINT_KIND:
        raise ValueError(f"{path} is not a varbot policy checkpoint")
    return payload


def load_policy(path: Path) -> tuple[Policy, dict[str, Any]]:
    """The policy stored in a checkpoint (eval mode) and the checkpoint's contents."""
    payload = read_policy_checkpoint(path)
    policy = Policy(PolicyConfig(**payload["policy_config"]))
    policy.load_state_dict(payload["policy"])
    return policy.eval(), payload
