"""PPO with the VAR's intrinsic reward: CleanRL-shaped, every PPO detail visible in this file.

The variants sit behind small strategies in their own modules: where the goal comes from
(`learning.rl.goals`: the VAR's embedding or the baselines' encoder), what the reward is
(`learning.rl.rewards`: intrinsic, with the current sound, sparse, shaped), which targets the worlds ask for
(`learning.rl.curriculum`), how the environments step in turn (`learning.rl.env_groups`), the live watcher
(`learning.rl.watch`), what is measured (`learning.rl.stats`) and how checkpoints are versioned and older
ones read (`learning.rl.checkpoints`).

Where the time goes, and what this file does about it (the reference spends 91 % of its time in the update):
- environments step in worker processes, in groups that take turns with the learner; torch threads are set
  in the learner only after the workers exist (threads configured before a fork have deadlocked workers);
- per step the learner makes one batched VAR call: f_I(I_{t+1}) is the reward now and the observation next
  step; f_S of every goal/current-sound clip is computed once when the run starts (the VAR is frozen);
- the policy CNN sees a 32×32 copy of the image (made once per step and stored); the update runs the CNN and
  heads on whole minibatches, only the GRU loops in time;
- rollouts run under `torch.inference_mode`; the learner uses one torch thread (`torch_threads`): on two busy
  cores a second thread made the many tiny GRU ops 10-30x slower (OpenMP barriers).

Checkpoints are written every `checkpoint_every` updates together with all RNG states. At each such boundary
the environments are re-seeded and the recurrent state cleared, both in a continuing run and in a resumed one,
so a resumed run makes exactly the same next updates as one that never stopped.
"""

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from core.rooms import world_room
from learning.device import core_plan, spread_processes
from learning.rl.checkpoints import (  # the F401 ones: callers reach them through this module
    CHECKPOINT_KIND,  # noqa: F401
    load_initial_policy,
    load_policy,  # noqa: F401
    read_policy_checkpoint,  # noqa: F401
    restore_run,
    with_legacy_run_options,
    write_run_checkpoint,
)
from learning.rl.curriculum import Curriculum, StartCurriculum
from learning.rl.env_groups import EnvGroups, ended_view, env_rooms, replay_env_indices
from learning.rl.frozen_var import LoadedVar, VarOnDevice
from learning.rl.goals import EpisodeGoals, goal_source
from learning.rl.normalize import ReturnNormalizer
from learning.rl.policy import GoalFusion, Policy, PolicyConfig, PolicyView
from learning.rl.pretrain import load_encoders_into
from learning.rl.rewards import ClipBank, RewardKind, StepOutcome, make_reward
from learning.rl.stats import EpisodeStats, EpisodeTracker, PeakMemory, Timings, mean_or_nan
from learning.rl.view_changes import EpisodeViewChanges
from learning.rl.watch import (
    EnvZeroWatch,
    RolloutStep,  # noqa: F401  (callers watch runs through this module)
    Watcher,
)
from learning.var.model import VAR
from learning.var.room_adaptation import in_view_order, with_statistics
from sim.blocks import START_STRIPS, start_strip_of


@dataclass
class PPOConfig:
    # task
    world: str = "kuka"
    sounds: str = "wordset"  # corpus the goal clips come from
    goal_split: str = "train"
    reward: RewardKind = "var"
    current_sound: bool = False  # add f_S(S_t)·f_S(S_goal), S_t = a clip of what is heard now (or silence)
    # subtract the view's best match with another command (IntrinsicRewardAgainstOtherCommands); experimental
    reward_against_others: bool = False
    reward_temperature: float | None = None  # pay exp((match − 1)/T) (SharpenedIntrinsicReward); experimental
    goal_encoder: Literal["var", "learned"] = "var"  # "learned": the baselines' MFCC encoder, no VAR input
    aux_loss_coef: float = 0.0  # RSI-style auxiliary classification losses on ground-truth labels
    init_encoders: str | None = None  # one-hot pre-trained image + goal encoders (learning.rl.pretrain)
    # the network (learning.rl.policy), with the network's own defaults
    goal_fusion: GoalFusion = PolicyConfig.goal_fusion  # how the goal meets the observation
    bounded_mean: bool = PolicyConfig.bounded_mean  # keep the Gaussian's mean inside the action range
    goal_match: bool = PolicyConfig.goal_match  # the policy also sees f_I(I_t)·f_S(S_goal); experimental
    hard_target_share: float = 0.5  # share of episodes whose target favours low recent return (0: uniform)
    # block worlds: share of episodes whose gripper starts in the strips of the table where recent episodes
    # earned least (learning.rl.curriculum.StartCurriculum; 0: anywhere, uniformly, as the paper); training
    # only: the evaluation protocol's starts never change
    hard_start_share: float = 0.0
    target_intents: list[int] | None = None  # diagnostics: the world asks only for these targets (None: all)
    image_size: int = 96  # rendered size; must equal the VAR's input size
    policy_image_size: int = PolicyConfig.policy_image_size
    # "var": the policy sees through a frozen copy of the VAR's image encoder (its hidden layer), not through
    # a CNN of its own trained by PPO alone; experimental
    policy_view: PolicyView = "pixels"
    # with policy_view "var" and an initial policy: its view becomes this run's VAR (a household's fine-tuned
    # VAR) instead of the copy it was trained with
    policy_view_follows_var: bool = False
    # each episode the policy sees its view in other colours (learning.rl.colours; 0: off); experimental
    policy_colour_jitter: float = 0.0
    policy_hue_turn: float = 0.0  # and turns its hues by up to ± this many degrees (learning.rl.colours)
    policy_view_shift: int = 0  # and shifts its view by up to ± this many pixels (learning.rl.view_changes)
    success_rule: str | None = None  # None: the world's own rule (Kuka "final", TurtleBot "hold")
    max_episode_steps: int | None = None  # None: the world's own T (100)
    # TurtleBot: what a blocked robot does (sim.turtlebot_arena: "stop" or "slide"; None: the world's own)
    contact: str | None = None
    # core.rooms.world_room: "training", "randomised" (a room per episode), a preset, or DomainShift fields
    room: str | dict[str, Any] = "training"
    # environments that practise in `replay_room` instead (a household's fine-tune keeps its base's rooms)
    replay_envs: int = 0
    replay_room: str | dict[str, Any] = "randomised"
    # PPO
    total_steps: int = 1_000_000
    num_envs: int = 8
    env_groups: int = 2  # worker groups that step in turn while the learner serves the other (1: lockstep)
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
    def world_options(self) -> dict[str, Any]:
        """The world's own settings this run changes, as keyword arguments of the world."""
        return {"contact": self.contact} if self.contact is not None else {}

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.batch_size)

    def validate(self) -> None:
        world_room(self.room)  # refuses a room it cannot name, saying which exist
        from sim.turtlebot_arena import CONTACT_RULES

        if self.contact is not None and (self.world != "turtlebot" or self.contact not in CONTACT_RULES):
            raise ValueError(
                f"contact is a TurtleBot setting, one of {CONTACT_RULES}: got {self.contact!r} for "
                f"{self.world}"
            )
        world_room(self.replay_room)
        if not 0.0 <= self.policy_colour_jitter < 1.0:
            raise ValueError(f"policy_colour_jitter must be in [0, 1), got {self.policy_colour_jitter}")
        if not 0.0 <= self.policy_hue_turn <= 180.0:
            raise ValueError(f"policy_hue_turn must be in [0, 180] degrees, got {self.policy_hue_turn}")
        if not 0 <= self.policy_view_shift < self.policy_image_size // 2:
            raise ValueError(
                f"policy_view_shift must be in [0, {self.policy_image_size // 2}) pixels of the policy's "
                f"{self.policy_image_size}-pixel view, got {self.policy_view_shift}"
            )
        if self.policy_view not in ("pixels", "var"):
            raise ValueError(f"policy_view must be 'pixels' or 'var', got {self.policy_view!r}")
        view_changed = self.policy_colour_jitter or self.policy_hue_turn or self.policy_view_shift
        if self.policy_view == "var" and (self.goal_encoder != "var" or view_changed):
            raise ValueError(
                "a policy that sees through the VAR needs the VAR (goal_encoder='var'), and sees the real "
                "view: colour jitter, hue turns and view shifts change the pixels of its own CNN"
            )
        if self.policy_view_follows_var and self.policy_view != "var":
            raise ValueError(
                "policy_view_follows_var is for a policy that sees through the VAR (policy_view='var')"
            )
        if not 0 <= self.replay_envs < self.num_envs:
            raise ValueError(
                f"replay_envs ({self.replay_envs}) must leave at least one of the {self.num_envs} "
                "environments in the run's own room"
            )
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
        plain_var_changed = self.reward_against_others or self.reward_temperature is not None
        if plain_var_changed and (self.reward != "var" or self.current_sound):
            raise ValueError(
                "the reward against other commands and the reward temperature change the plain intrinsic "
                "reward: use reward='var' without the current sound"
            )
        if self.reward_against_others and self.reward_temperature is not None:
            raise ValueError("choose the reward against other commands or a reward temperature, not both")
        if not 0.0 <= self.hard_target_share <= 1.0:
            raise ValueError(f"hard_target_share must be in [0, 1], got {self.hard_target_share}")
        self._validate_start_curriculum()
        if self.target_intents is not None and not self.target_intents:
            raise ValueError("target_intents must name at least one target (None: all of them)")
        if self.aux_loss_coef and self.goal_encoder != "learned":
            raise ValueError("auxiliary losses train the baselines' own encoders: use goal_encoder='learned'")
        if self.init_encoders is not None and self.goal_encoder != "learned":
            raise ValueError(
                "pre-trained encoders replace the baselines' own encoders: use goal_encoder='learned'"
            )

    def _validate_start_curriculum(self) -> None:
        import sim

        if not 0.0 <= self.hard_start_share <= 1.0:
            raise ValueError(f"hard_start_share must be in [0, 1], got {self.hard_start_share}")
        if self.hard_start_share and not sim.has_blocks(self.world):
            raise ValueError(
                "hard_start_share chooses the strip of the table the gripper starts in: a setting of the "
                f"block worlds, not of {self.world!r} (use 0)"
            )

    @classmethod
    def from_dict(cls, data: dict) -> "PPOConfig":
        """Settings saved by older versions lack newer fields: those get the value the old code used."""
        names = {f.name for f in fields(cls)}
        return cls(**with_legacy_run_options({k: v for k, v in data.items() if k in names}))


@dataclass
class Rollout:
    """Time-major buffers (T, E, ...) for one update, plus the recurrent state before step 0."""

    images: torch.Tensor
    var_embedding: torch.Tensor
    state: torch.Tensor
    goal: torch.Tensor  # what the goal source stores: VAR goal embedding (T, E, d) or goal clip index (T, E)
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


def compute_gae(
    rewards: torch.Tensor, values: torch.Tensor, dones: torch.Tensor, next_value: torch.Tensor, gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """GAE(λ) → (advantages, returns). A time-limit end was already bootstrapped into its reward, so every end
    stops the trace."""
    steps = len(rewards)
    advantages = torch.zeros_like(rewards)
    last = torch.zeros(rewards.shape[1])
    for t in reversed(range(steps)):
        next_values = next_value if t == steps - 1 else values[t + 1]
        not_done = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_values * not_done - values[t]
        last = delta + gamma * gae_lambda * not_done * last
        advantages[t] = last
    return advantages, advantages + values


class PPOTrainer:
    """Owns the environments, the frozen VAR, the policy and the optimiser for one run directory."""

    def __init__(
        self,
        config: PPOConfig,
        run_dir: Path,
        var: LoadedVar | None,
        goals: ClipBank,
        current_sounds: ClipBank | None = None,
        init_policy: Path | None = None,
        device: str | torch.device = "cpu",
    ) -> None:
        """`device`: where the VAR and the policy run (`learning.device.resolve_device`); the rollout buffers
        and everything else stay on the CPU."""
        config.validate()
        self.config = config
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        if config.goal_encoder == "var" and var is None:
            raise ValueError("this configuration needs a VAR checkpoint (--var)")
        if var is not None and var.image_size != config.image_size:
            raise ValueError(
                f"the VAR was trained on {var.image_size}px images but image_size is "
                f"{config.image_size}; render at the VAR's size (--image-size {var.image_size})"
            )
        if config.current_sound and current_sounds is None:
            raise ValueError("--current-sound needs the training clips of the corpus")
        self.var = var.model.eval().requires_grad_(False) if var is not None else None
        self.var_path = var.path if var is not None else None
        self.base_statistics = var.base_statistics if var is not None else None
        self.label_counts = dict(var.label_counts) if var is not None and config.goal_encoder == "var" else {}
        self.goals = goals
        self.current_sounds = current_sounds if config.current_sound else None
        self.init_policy = init_policy
        self.device = torch.device(device)
        self.update_index = 0  # updates completed
        self.global_step = 0
        self.rng = np.random.default_rng(config.seed)
        self.torch_rng = torch.Generator().manual_seed(config.seed)
        self.normalise = ReturnNormalizer(config.gamma, enabled=config.normalize_reward)
        self.stats = EpisodeStats.over_last(config.success_window)
        self.timings = Timings()
        self.memory = PeakMemory()
        self.watch_env_zero = EnvZeroWatch()
        self.envs: EnvGroups | None = None  # started by `start`
        self.policy: Policy | None = None
        self.needs_reset = True  # environments are (re-)seeded before the first update and after a resume
        self.start_strip: np.ndarray | None = None  # each episode's start strip (start curriculum only)
        self.policy_sees_var = False  # the policy's view is this VAR's hidden layer (set by `reset_envs`)
        self.views_var: VAR | VarOnDevice | None = None  # the VAR that embeds rendered views (set by `start`)
        self.replay_views_var: VAR | VarOnDevice | None = None  # the replay rooms' (see `_replay_views_var`)
        replays = replay_env_indices(config.num_envs, config.replay_envs)
        self.replay_env_mask = np.array([env in replays for env in range(config.num_envs)])

    # -- set-up ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the workers, then (only then) configure torch threads and build the policy."""
        c = self.config
        self.envs = EnvGroups(
            c.world, c.num_envs, c.env_groups, c.image_size, c.success_rule, c.max_episode_steps,
            c.env_context,
            domains=env_rooms(c.num_envs, world_room(c.room), c.replay_envs, world_room(c.replay_room)),
            world_options=c.world_options,
        )  # fmt: skip
        plan = core_plan(os.cpu_count() or 1, c.num_envs, self.device, c.torch_threads)
        spread_processes(plan, self.envs.worker_processes())
        torch.set_num_threads(plan.learner_threads)
        # views are embedded by a copy with its batch norms folded in (a third of f_I's time on the CPU); the
        # VAR itself stays for f_S, the reward's sounds and comparing weights
        self.views_var = self.var.with_batch_norms_folded() if self.var is not None else None
        self.replay_views_var = self._replay_views_var()
        if self.var is not None and self.device.type != "cpu":
            self.var = VarOnDevice(self.var, self.device)
            self.views_var = VarOnDevice(self.views_var, self.device)
            if self.replay_views_var is not None:
                self.replay_views_var = VarOnDevice(self.replay_views_var, self.device)
        # f_S of every clip once, after the thread count is set: the same clips embedded with another number
        # of threads differ in the last bits, and a resumed run would then not repeat the original one exactly
        if self.var is not None and self.goals.embeddings is None:
            self.goals.embed(self.var)
        self.reward = make_reward(
            c.reward,
            self.goals,
            self.var,
            self.current_sounds,
            self.rng,
            c.reward_against_others,
            c.reward_temperature,
        )
        self.state_dim, self.num_intents = self.envs.state_dim, self.envs.num_intents
        unknown = sorted(set(c.target_intents or []) - set(range(self.num_intents)))
        if unknown:
            self.close()
            raise ValueError(
                f"target_intents {unknown} are not targets of the {c.world} world (0..{self.num_intents - 1})"
            )
        self.curriculum = Curriculum(
            c.hard_target_share, c.target_intents, self.num_intents, self.goals.has_intents
        )
        self.start_curriculum = StartCurriculum(c.hard_start_share, START_STRIPS)
        self.episodes = EpisodeTracker(
            self.stats, self.goals.has_intents, replay_env_indices(c.num_envs, c.replay_envs)
        )
        torch.manual_seed(c.seed)
        self.policy = Policy(self._policy_config())
        if c.init_encoders is not None:
            self.label_counts.update(load_encoders_into(self.policy, c.init_encoders))
        if self.init_policy is not None:
            load_initial_policy(self.policy, self.init_policy)
        if c.policy_view == "var" and (self.init_policy is None or c.policy_view_follows_var):
            # a new policy sees through this run's VAR; a loaded one keeps its own copy unless told to follow
            self.policy.var_view.encoder.load_state_dict(self._var_model().image_encoder.state_dict())
        self.policy.to(self.device)
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=c.learning_rate, eps=1e-5)
        self.goal_source = goal_source(c.goal_encoder, self.goals)
        self.hidden = self.policy.initial_state(c.num_envs)

    def _policy_config(self) -> PolicyConfig:
        c = self.config
        var_dim = self.var.config.embedding_dim if self.var is not None else 3
        return PolicyConfig(
            image_size=c.image_size,
            state_dim=self.state_dim,
            var_dim=var_dim if c.goal_encoder == "var" else 0,
            goal_encoder=c.goal_encoder,
            goal_dim=var_dim,
            policy_image_size=c.policy_image_size,
            num_intents=self.num_intents,
            aux_heads=c.aux_loss_coef > 0,
            goal_fusion=c.goal_fusion,
            bounded_mean=c.bounded_mean,
            goal_match=c.goal_match,
            view_var=self.var.config.to_dict() if c.policy_view == "var" else None,
        )

    def close(self) -> None:
        if self.envs is not None:
            self.envs.close()

    def watch(self, on_rollout_step: Watcher | None) -> None:
        """Call `on_rollout_step` after every step of env 0 from now on (None: stop watching)."""
        self.watch_env_zero.attach(on_rollout_step, self.envs)

    # -- observations ----------------------------------------------------------------------------------------
    def _var_model(self) -> VAR:
        return self.var.model if isinstance(self.var, VarOnDevice) else self.var

    def _policy_sees_this_var(self) -> bool:
        """Whether the policy's frozen view is this run's VAR's image encoder (a base model's run; not a
        household's, whose VAR was fine-tuned after the policy learnt to see through the base's)."""
        if self.config.policy_view != "var":
            return False
        theirs = self._var_model().image_encoder.state_dict()
        return all(
            torch.equal(mine.cpu(), theirs[name].cpu())
            for name, mine in self.policy.var_view.encoder.state_dict().items()
        )

    def _replay_views_var(self) -> VAR | None:
        """A VAR adapted to the household's room (`learning.var.room_adaptation`) sees the replay
        environments, which practise in the base model's rooms, by the base's batch-norm statistics: as it
        will see the training room once they are given back (None: every environment is seen alike)."""
        if self.var is None or self.base_statistics is None or not self.config.replay_envs:
            return None
        return with_statistics(self.var, self.base_statistics).with_batch_norms_folded()

    def _see(self, images: np.ndarray, envs: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """f_I of rendered views (the observation's and the reward's part) and the policy's view of them,
        before its episode's view changes; `envs[i]` is the environment that rendered `images[i]`. A policy
        that sees through this very VAR gets the hidden layer of the same pass."""
        if self.replay_views_var is None:
            return self._see_by(self.views_var, images)
        replayed = self.replay_env_mask[envs]
        if not replayed.any():
            return self._see_by(self.views_var, images)
        if replayed.all():
            return self._see_by(self.replay_views_var, images)
        own = self._see_by(self.views_var, images[~replayed])
        replay = self._see_by(self.replay_views_var, images[replayed])
        return in_view_order(own[0], replay[0], replayed), in_view_order(own[1], replay[1], replayed)

    def _see_by(
        self, views_var: "VAR | VarOnDevice | None", images: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor]:
        pixels = torch.from_numpy(images)
        if self.policy_sees_var:
            return views_var.encode_image_and_hidden(pixels)
        embedded = torch.zeros(len(images), 0) if views_var is None else views_var.encode_image(pixels)
        return embedded, self.policy.view_of(pixels)

    def _send_target_weights(self) -> None:
        weights = self.curriculum.next_weights(self.stats)
        if weights is not None:
            self.envs.set_attr("intent_weights", [weights] * self.config.num_envs)
        start_weights = self.start_curriculum.next_weights(self.stats)
        if start_weights is not None:
            self.envs.set_attr("start_strip_weights", [start_weights] * self.config.num_envs)

    def _start_strips(self, states: np.ndarray) -> np.ndarray | None:
        """The strip each new episode's gripper starts in, while the start curriculum runs (else None)."""
        return start_strip_of(np.asarray(states)[:, 1]) if self.start_curriculum.active else None

    def reset_envs(self) -> None:
        """Re-seed every environment (at the start and checkpoint boundaries); clear per-episode state."""
        c, E = self.config, self.config.num_envs
        self._send_target_weights()
        seeds = [int(s) for s in np.random.SeedSequence([c.seed, self.update_index]).generate_state(E)]
        obs, info = self.envs.reset(seeds)
        self.needs_reset = False
        self.view_changes = EpisodeViewChanges(
            E, c.policy_colour_jitter, c.policy_hue_turn, c.policy_view_shift
        )
        self.view_changes.draw(np.arange(E), self.rng)
        self.policy_sees_var = self._policy_sees_this_var()  # after a resume: the restored policy's view
        with torch.inference_mode():
            self.next_var, views = self._see(obs["image"], np.arange(E))
            self.next_policy_images = self.view_changes.apply(views, slice(None))
        self.next_state = torch.from_numpy(obs["state"]).float()
        self.start_strip = self._start_strips(obs["state"])
        self.next_start = torch.ones(E)
        self.intent = info["intent"].astype(np.int64)
        self.heard = info["heard"].astype(np.int64)
        self.distance = info["distance"].astype(np.float64)
        self.hidden = self.policy.initial_state(E)
        self.normalise.reset(E)
        self.episodes.reset(E)
        self.episode_goals = EpisodeGoals(self.goal_source, self.goals, E, self.policy.goal_feature_size)
        with torch.inference_mode():
            self.episode_goals.draw(np.arange(E), self.intent, self.rng, self.policy)

    # -- rollout ---------------------------------------------------------------------------------------------
    def _allocate(self) -> Rollout:
        T, E, view = self.config.num_steps, self.config.num_envs, self.next_policy_images
        return Rollout(
            images=torch.zeros(T, E, *view.shape[1:], dtype=view.dtype),
            var_embedding=torch.zeros(T, E, self.next_var.shape[1]),
            state=torch.zeros(T, E, self.state_dim),
            goal=self.goal_source.allocate(T, E),
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
        """`num_steps` steps of every environment, the groups taking turns (`learning.rl.env_groups`)."""
        c = self.config
        finished: list[dict[str, float]] = []
        buf = self._allocate()  # outside inference mode: the update needs these as ordinary tensors
        self._send_target_weights()
        with torch.inference_mode():
            self.episode_goals.refresh(self.policy)  # the update changed the (once per episode) features
            for envs, group in self.envs:
                self._act(buf, 0, group, envs)
            for t in range(c.num_steps):
                for envs, group in self.envs:
                    tick = time.perf_counter()
                    obs, _, terminated, truncated, info = envs.step_wait()
                    self.timings.env_s += time.perf_counter() - tick
                    buf.rewards[t, group], buf.dones[t, group], raw = self._after_step(
                        group, obs, terminated, truncated, info, finished
                    )
                    if group.start == 0:
                        step = self.global_step + (t + 1) * c.num_envs
                        ended = terminated[0] or truncated[0]
                        goal = self.episode_goals.clip[0]
                        self.watch_env_zero.after_step(step, obs, raw[0], ended, info, goal)
                    if t + 1 < c.num_steps:
                        self._act(buf, t + 1, group, envs)
            # value of the observation after the last step, for GAE (the hidden state is not advanced)
            _, next_value, _ = self.policy.step(
                self.next_policy_images, self.next_var, self.next_state, self.episode_goals.features,
                self.hidden, self.next_start,
            )  # fmt: skip
        buf.advantages, buf.returns = compute_gae(
            buf.rewards, buf.values, buf.dones, next_value, c.gamma, c.gae_lambda
        )
        self.global_step += c.batch_size
        return buf, finished

    def _act(self, buf: Rollout, t: int, group: slice, envs: Any) -> None:
        """Store the group's observation at step t, sample its actions and send them to its workers."""
        tick = time.perf_counter()
        buf.images[t, group] = self.next_policy_images[group]
        buf.var_embedding[t, group] = self.next_var[group]
        buf.state[t, group] = self.next_state[group]
        buf.goal[t, group] = self.episode_goals.stored(group)
        buf.episode_start[t, group] = self.next_start[group]
        buf.heard[t, group] = torch.from_numpy(self.heard[group])
        buf.intent[t, group] = torch.from_numpy(self.intent[group])
        mean, value, self.hidden[group] = self.policy.step(
            self.next_policy_images[group], self.next_var[group], self.next_state[group],
            self.episode_goals.features[group], self.hidden[group], self.next_start[group],
        )  # fmt: skip
        distribution = self.policy.distribution(mean)
        action = mean + distribution.stddev * torch.randn(mean.shape, generator=self.torch_rng)
        buf.actions[t, group] = action
        buf.logprobs[t, group] = distribution.log_prob(action).sum(-1)
        buf.values[t, group] = value
        self.timings.policy_s += time.perf_counter() - tick
        # handing the actions over is environment time: on a busy machine the kernel often runs a woken
        # worker before the send returns (it made the policy look like half the time)
        tick = time.perf_counter()
        envs.step_async(action.clamp(-1.0, 1.0).numpy())
        self.timings.env_s += time.perf_counter() - tick

    def _after_step(
        self, group: slice, obs: dict, terminated: np.ndarray, truncated: np.ndarray, info: dict,
        finished: list,
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:  # fmt: skip
        """Reward for the group's step just taken, then its next observation (new goals where episodes
        started). Returns the normalised reward, the episode ends and the raw reward."""
        c = self.config
        done = terminated | truncated
        done_envs = np.flatnonzero(done)  # within the group; environment `group.start + i`
        n = len(done)
        ended = ended_view(obs, info, done)
        # one VAR call: the reward images (final observations where an episode ended) and the reset images;
        # the policy's view of the same images (ended.images are the next observations where none ended)
        tick = time.perf_counter()
        embedded, viewed = self._see(
            np.concatenate([ended.images, obs["image"][done_envs]]) if len(done_envs) else ended.images,
            group.start + np.concatenate([np.arange(n), done_envs]),
        )
        reward_embedding, reset_embedding = embedded[:n], embedded[n:]
        self.timings.var_s += time.perf_counter() - tick

        tick = time.perf_counter()
        raw = self.reward(
            StepOutcome(
                reward_embedding, self.episode_goals.clip[group], ended.heard, self.distance[group],
                ended.distance, done, ended.success, self.intent[group],
            )
        )  # fmt: skip
        reward = self.normalise(group, raw, done)
        cut = np.flatnonzero(truncated & ~terminated) if c.bootstrap_truncated else []
        if len(cut):
            final_images = self.view_changes.apply(viewed[cut], cut + group.start)  # the ended episode's
            envs = torch.from_numpy(cut + group.start)
            _, final_value, _ = self.policy.step(
                final_images, reward_embedding[cut], torch.from_numpy(ended.state[cut]),
                self.episode_goals.features[envs], self.hidden[envs], torch.zeros(len(cut)),
            )  # fmt: skip
            reward[cut] += c.gamma * final_value

        finished += self.episodes.step(group, raw, done, ended.success, self.intent, self.start_strip)
        next_var = reward_embedding.clone()
        if len(done_envs):
            next_var[done_envs] = reset_embedding
        self.next_var[group] = next_var
        views = viewed[:n].clone()
        views[done_envs] = viewed[n:]
        self.view_changes.draw(done_envs + group.start, self.rng)
        self.next_policy_images[group] = self.view_changes.apply(views, group)
        self.next_state[group] = torch.from_numpy(np.asarray(obs["state"], dtype=np.float32))
        self.next_start[group] = torch.from_numpy(done.astype(np.float32))
        self.heard[group] = np.asarray(info["heard"], dtype=np.int64)
        self.intent[group] = np.asarray(info["intent"], dtype=np.int64)
        self.distance[group] = np.asarray(info["distance"], dtype=np.float64)
        if len(done_envs):
            started = done_envs + group.start
            self.episode_goals.draw(started, self.intent[started], self.rng, self.policy)
            if self.start_strip is not None:
                self.start_strip[started] = self._start_strips(obs["state"][done_envs])
        self.timings.policy_s += time.perf_counter() - tick
        return reward, torch.from_numpy(done.astype(np.float32)), raw

    # -- update ----------------------------------------------------------------------------------------------
    def update(self, buf: Rollout) -> dict[str, float]:
        c = self.config
        if c.anneal_lr:
            frac = 1.0 - self.update_index / c.num_updates
            self.optimizer.param_groups[0]["lr"] = max(frac, 0.0) * c.learning_rate
        envs_per_minibatch = c.num_envs // c.num_minibatches
        clipfracs = []
        for _ in range(c.update_epochs):
            order = torch.randperm(c.num_envs, generator=self.torch_rng)
            for start in range(0, c.num_envs, envs_per_minibatch):
                idx = order[start : start + envs_per_minibatch]
                goal_features = self.goal_source.features(self.policy, buf.goal[:, idx])
                mean, new_value, inputs = self.policy.evaluate_sequences(
                    buf.images[:, idx], buf.var_embedding[:, idx], buf.state[:, idx], goal_features,
                    buf.initial_hidden[idx], buf.episode_start[:, idx],
                )  # fmt: skip
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
                    aux_loss = self.policy.auxiliary_loss(
                        inputs, goal_features, buf.heard[:, idx], buf.intent[:, idx]
                    )
                    loss = loss + c.aux_loss_coef * aux_loss

                self.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(self.policy.parameters(), c.max_grad_norm)
                self.optimizer.step()
            if c.target_kl is not None and approx_kl > c.target_kl:
                break

        y_pred, y_true = buf.values.flatten().numpy(), buf.returns.flatten().numpy()
        var_y = np.var(y_true)
        return {
            "learning_rate": self.optimizer.param_groups[0]["lr"],
            "value_loss": v_loss.item(),
            "policy_loss": pg_loss.item(),
            "entropy": entropy_loss.item(),
            "approx_kl": approx_kl.item(),
            "clipfrac": float(np.mean(clipfracs)),
            "explained_variance": float("nan") if var_y == 0 else float(1 - np.var(y_true - y_pred) / var_y),
            "aux_loss": aux_loss.item(),
            "action_std": self.policy.actor_logstd.exp().mean().item(),
        }

    # -- the loop --------------------------------------------------------------------------------------------
    def train(
        self,
        progress: bool = True,
        on_update: Callable[[dict[str, Any]], bool | None] | None = None,
        on_rollout_step: Watcher | None = None,
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
        if self.update_index == 0:  # the policy as it starts, as the others are kept (checkpoint_000000.pt)
            self.save_checkpoint()
        metrics_path = self.run_dir / "metrics.jsonl"
        bar = tqdm(
            total=c.num_updates * c.batch_size, initial=self.global_step, unit="step", disable=not progress
        )
        stop = False
        try:
            while self.update_index < c.num_updates and not stop:
                if self.needs_reset or self.update_index % c.checkpoint_every == 0:
                    self.reset_envs()
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
        self.memory.sample(self.envs.worker_processes())
        elapsed = time.perf_counter() - started
        self.timings.other_s += elapsed - sum(asdict(self.timings).values()) + sum(asdict(before).values())
        return {
            "update": self.update_index,
            "global_step": self.global_step,
            "sps": self.config.batch_size / elapsed,
            "episodes": len(finished),
            "episode_return": float(np.mean([e["return"] for e in finished])) if finished else float("nan"),
            "episode_length": float(np.mean([e["length"] for e in finished])) if finished else float("nan"),
            "success": mean_or_nan([e["success"] for e in finished]),
            "recent_success": mean_or_nan(list(self.stats.successes)),
            "recent_success_by_intent": self.stats.success_by_intent(self.num_intents),
            **self.success_by_room(),
            "intent_weights": self.curriculum.weights,
            "start_strip_weights": self.start_curriculum.weights,
            "time": {k: round(v - getattr(before, k), 4) for k, v in asdict(self.timings).items()},
            "peak_memory_mb": self.memory.peak_mb,
            **stats,
        }

    def summary(self) -> dict[str, Any]:
        return {
            "updates": self.update_index,
            "env_steps": self.global_step,
            "recent_success": mean_or_nan(list(self.stats.successes)),
            **self.success_by_room(),
            "time_shares": self.timings.shares(),
            "time_s": asdict(self.timings),
            "peak_memory_mb": self.memory.peak_mb,
            "labels": self.labels_used(),
        }

    def success_by_room(self) -> dict[str, dict[str, float]]:
        """With replay environments: recent success in the run's own room and in the replay room apart."""
        return {"recent_success_by_room": self.stats.success_by_room()} if self.config.replay_envs else {}

    def labels_used(self) -> dict[str, int]:
        """The paper's accounting: a VAR triplet is 2 labels; each extrinsic-reward step is a simulator query;
        each auxiliary-loss step uses 2 ground-truth labels (what is in view, which intent)."""
        counts = dict(self.label_counts)
        if self.reward.queries_simulator:
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
        return write_run_checkpoint(self, path or self.checkpoint_path)

    def load_checkpoint(self, path: Path | None = None) -> None:
        """Restore everything a run needs to continue exactly (call after `start`)."""
        restore_run(self, path or self.checkpoint_path)
