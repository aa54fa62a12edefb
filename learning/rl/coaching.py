"""Coaching by voice: the paper's real-time voice supervision (eq. 3) with a person's live voice.

During a short self-improvement session one robot acts at a pace a person can follow (`steps_per_s`), and a
coach says the command while the robot is where it should be. The reward of each step is

    r_t = f_I(I_t) · f_S(S_goal) + f_S(S_t) · f_S(S_goal)

with S_t the coach's voice over the frame of step t (silence when nobody speaks). A clip is only known after
it was said (it is sent when the speaker lets go), so the voice term is added once a rollout is collected,
just before its advantages are computed: the trainer notes when each step's frame was on show
(`StepMoment`) and asks its `Coach` what was heard over each.
"""

import dataclasses
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from learning.rl.checkpoints import read_policy_checkpoint
from learning.rl.env_groups import ended_view, in_process_env
from learning.rl.envs import make_env_fn, world_id
from learning.rl.frozen_var import LoadedVar, load_frozen_var
from learning.rl.ppo import PPOConfig, PPOTrainer, Rollout, compute_gae
from learning.rl.rewards import ClipBank
from learning.rl.watch import RolloutStep, Watcher

DEFAULT_STEPS_PER_S = 5.0  # slow enough to follow, fast enough that an episode takes seconds
DEFAULT_STEPS_PER_UPDATE = 25  # one PPO update every 5 s at the default pace
LATE_CLIP_GRACE_S = 1.0  # a paced session waits this long after a rollout for the clips said over its end


class CoachingStopped(Exception):
    """Raised between two steps when the session was asked to stop (cancel)."""


@dataclass(frozen=True)
class StepMoment:
    """When one step's frame was on show, and (for a simulated coach only) what the simulator says of it."""

    shown_from: float  # time.time() when the frame appeared
    shown_to: float  # ... and when the next one replaced it (planned, for the rollout's last step)
    heard: int  # the target in view (-1: none); ground truth, for a simulated coach
    goal_clip: int  # index into the goal bank of the goal the step was rewarded against
    goal_intent: int  # that clip's target (-1: unknown, e.g. a household recording)


class Coach(Protocol):
    def voice_over(self, moments: Sequence[StepMoment]) -> list[torch.Tensor | None]:
        """f_S of the voice heard over each moment's frame, or None where nothing was said."""
        ...


class SilentCoach:
    """Nobody speaks: plain self-improvement, S_t is silence at every step."""

    def voice_over(self, moments: Sequence[StepMoment]) -> list[torch.Tensor | None]:
        return [None] * len(moments)


@dataclass(frozen=True)
class SpokenClip:
    """One push-to-talk clip of a live coach, on the learner's clock (time.time())."""

    said_from: float
    said_to: float
    embedding: torch.Tensor  # f_S of the clip, (d,)

    def overlaps(self, moment: StepMoment) -> bool:
        return self.said_from < moment.shown_to and moment.shown_from < self.said_to


class LiveCoach:
    """A person's clips as they arrive (`fetch_new` returns the clips sent since its last call); each is the
    voice over every frame it overlaps."""

    def __init__(self, fetch_new: Callable[[], list[SpokenClip]]) -> None:
        self.fetch_new = fetch_new
        self.clips: list[SpokenClip] = []

    def voice_over(self, moments: Sequence[StepMoment]) -> list[torch.Tensor | None]:
        self.clips += self.fetch_new()
        return [next((c.embedding for c in self.clips if c.overlaps(m)), None) for m in moments]


@dataclass
class CoachingSettings:
    steps: int  # environment steps of the whole session
    steps_per_s: float | None = DEFAULT_STEPS_PER_S  # None: as fast as the machine goes (benches)
    steps_per_update: int = DEFAULT_STEPS_PER_UPDATE
    seed: int = 0

    def __post_init__(self) -> None:
        if self.steps_per_update < 2:
            raise ValueError(f"steps_per_update must be at least 2, got {self.steps_per_update}")
        if self.steps < self.steps_per_update:
            raise ValueError(
                f"a session of {self.steps} steps is shorter than one update "
                f"({self.steps_per_update} steps): "
                "coach for longer"
            )
        if self.steps_per_s is not None and not 0.2 <= self.steps_per_s <= 50:
            raise ValueError(f"steps_per_s must be between 0.2 and 50, got {self.steps_per_s}")


def coaching_config(policy_checkpoint: Path, settings: CoachingSettings, env_context: str) -> PPOConfig:
    """The policy's own training settings, for one robot (`env_context`: `learning.rl.env_groups.
    in_process_env`) and short updates, at a third of its learning rate, as self-improvement does."""
    base = PPOConfig.from_dict(read_policy_checkpoint(policy_checkpoint)["config"])
    if base.goal_encoder != "var":
        raise ValueError("coaching needs a policy trained with the VAR (method `var`)")
    return dataclasses.replace(
        base,
        num_envs=1,
        env_groups=1,
        num_minibatches=1,
        num_steps=settings.steps_per_update,
        total_steps=settings.steps // settings.steps_per_update * settings.steps_per_update,
        learning_rate=base.learning_rate / 3,
        anneal_lr=False,
        current_sound=False,  # the coach's voice is the current sound (CoachingTrainer)
        goal_split="household",
        env_context=env_context,
        checkpoint_every=10**9,  # one checkpoint, at the end
        seed=settings.seed,
        torch_threads=1,
    )


class CoachingTrainer(PPOTrainer):
    """PPO on one robot at a person's pace, with the coach's voice as the current sound of eq. 3."""

    def __init__(
        self,
        config: PPOConfig,
        run_dir: Path,
        var: LoadedVar,
        goals: ClipBank,
        coach: Coach,
        init_policy: Path,
        steps_per_s: float | None = DEFAULT_STEPS_PER_S,
        should_stop: Callable[[], bool] = lambda: False,
    ) -> None:
        super().__init__(config, run_dir, var, goals, init_policy=init_policy)
        self.coach, self.should_stop = coach, should_stop
        self.step_period_s = 1.0 / steps_per_s if steps_per_s else 0.0
        self.moments: list[StepMoment] = []
        self.voiced_steps = 0  # steps whose frame the coach spoke over, the whole session
        self._next_step_at = 0.0
        self._silence: torch.Tensor | None = None
        self._step_heard, self._step_goal = -1, 0  # of env 0's step just taken (`_after_step`)

    def coach_session(self, watcher: Watcher | None = None, progress: bool = False) -> dict[str, Any]:
        """Train for `total_steps`, pacing every step; `watcher` sees each step as it is shown. Raises
        CoachingStopped (from between two steps) once `should_stop()` says so."""
        return self.train(progress=progress, on_rollout_step=self._paced(watcher))

    def _paced(self, watcher: Watcher | None) -> Watcher:
        def after_step(step: RolloutStep) -> None:
            if self.should_stop():
                raise CoachingStopped("the coaching session was stopped")
            wait = self._next_step_at - time.time()
            if wait > 0:
                time.sleep(wait)
            now = time.time()
            self._next_step_at = now + self.step_period_s  # never faster to catch up: a person follows it
            goal, intent = self._step_goal, int(self.goals.intents[self._step_goal])
            self.moments.append(StepMoment(now, now + self.step_period_s, self._step_heard, goal, intent))
            if watcher is not None:
                watcher(step)

        return after_step

    def _after_step(
        self, group: slice, obs: dict, terminated: np.ndarray, truncated: np.ndarray, info: dict,
        finished: list,
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:  # fmt: skip
        """Notes what env 0's step was rewarded against before the base class starts a new episode."""
        self._step_heard = int(ended_view(obs, info, terminated | truncated).heard[0])
        self._step_goal = int(self.episode_goals.clip[0])
        return super()._after_step(group, obs, terminated, truncated, info, finished)

    def collect_rollout(self) -> tuple[Rollout, list[dict[str, float]]]:
        self.moments = []
        buf, finished = super().collect_rollout()
        self._wait_for_late_clips()
        voice = self.voice_term(self.moments)
        self.voiced_steps += int((voice != 0).sum())
        buf.rewards[:, 0] += torch.from_numpy(voice / self._reward_scale()).float()
        with torch.inference_mode():
            _, next_value, _ = self.policy.step(
                self.next_policy_images, self.next_var, self.next_state, self.episode_goals.features,
                self.hidden, self.next_start,
            )  # fmt: skip
        c = self.config
        buf.advantages, buf.returns = compute_gae(
            buf.rewards, buf.values, buf.dones, next_value, c.gamma, c.gae_lambda
        )
        return buf, finished

    def _wait_for_late_clips(self) -> None:
        """A clip is sent when its speaker lets go: one said over the rollout's last frames arrives a moment
        after it. The robot stands still meanwhile (as it does while it learns)."""
        if not self.step_period_s or not self.moments:
            return
        until = self.moments[-1].shown_to + LATE_CLIP_GRACE_S
        while (left := until - time.time()) > 0:
            if self.should_stop():
                raise CoachingStopped("the coaching session was stopped")
            time.sleep(min(left, 0.1))

    def voice_term(self, moments: Sequence[StepMoment]) -> np.ndarray:
        """(T,) f_S(S_t)·f_S(S_goal) minus the same with silence: the silence term is the same at every step
        of an episode (a constant the advantages cancel), so a step nobody spoke over adds 0."""
        goal = self.goals.embeddings[torch.tensor([m.goal_clip for m in moments])]
        silence = self.silence_embedding()
        voices = self.coach.voice_over(moments)
        heard = torch.stack([silence if v is None else v.reshape(-1) for v in voices])
        term = ((heard - silence) * goal).sum(-1)
        return term.numpy().astype(np.float64)

    def silence_embedding(self) -> torch.Tensor:
        if self._silence is None:
            with torch.inference_mode():
                self._silence = self.var.encode_silence().reshape(-1).float()
        return self._silence

    def _reward_scale(self) -> float:
        """What the step rewards were divided by (`learning.rl.normalize`), so the voice term matches them."""
        return math.sqrt(self.normalise.rms.var + 1e-8) if self.normalise.enabled else 1.0


def embed_clip_features(var: torch.nn.Module, features: np.ndarray) -> torch.Tensor:
    """f_S of one clip's features (the VAR's sound front end), (d,)."""
    with torch.inference_mode():
        return var.encode_sound(torch.from_numpy(features[None].astype(np.float32)))[0].float()


@contextmanager
def simulated_robot(name: str, policy_checkpoint: Path, domain: Any = None) -> Iterator[str]:
    """The policy's world as one robot in this process, at the policy's image size; yields its env_context."""
    config = read_policy_checkpoint(policy_checkpoint)["config"]
    make = make_env_fn(
        world_id(config["world"]), int(config["image_size"]), config.get("success_rule"),
        config.get("max_episode_steps"), None, domain,
    )  # fmt: skip
    with in_process_env(name, lambda: make().env) as context:  # .env: the trainer adds its own RLInfo
        yield context


@contextmanager
def coaching_trainer(
    policy_checkpoint: Path,
    var_path: Path,
    goals: ClipBank,
    coach: Coach,
    settings: CoachingSettings,
    run_dir: Path,
    domain: Any = None,
    should_stop: Callable[[], bool] = lambda: False,
) -> Iterator[CoachingTrainer]:
    """A started trainer for one coaching session of a simulated robot, closed on leaving the block."""
    with simulated_robot(f"coaching-{run_dir.name}", policy_checkpoint, domain) as context:
        config = coaching_config(policy_checkpoint, settings, context)
        trainer = CoachingTrainer(
            config, run_dir, load_frozen_var(var_path), goals, coach, policy_checkpoint,
            settings.steps_per_s, should_stop,
        )  # fmt: skip
        trainer.start()
        try:
            yield trainer
        finally:
            trainer.close()
