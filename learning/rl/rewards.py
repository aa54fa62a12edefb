"""Rewards and goals, computed in the learner for all environments at once.

A run's reward is one of the `RewardFunction`s below, chosen by `make_reward` from the run's settings:
- `IntrinsicReward` (`var`): the paper's r_t = f_I(I_{t+1}) · f_S(S_goal). The image embedding is computed
  once per step and is both this reward and, one step later, part of the observation, so the reward reads
  embeddings the trainer already has (`intrinsic_reward_from_embeddings`).
- `IntrinsicRewardWithCurrentSound` (`var` + current sound): adds f_S(S_{t+1}) · f_S(S_goal).
- `IntrinsicRewardAgainstOtherCommands` (`var` + against others): subtracts the view's best match with any
  other command the robot knows, so a wrong block pays less than no block (experimental).
- `SharpenedIntrinsicReward` (`var` + a temperature T): exp((f_I(I_{t+1})·f_S(S_goal) − 1)/T), still rising
  with the match but paying the goal's own block many times what any other view pays (experimental).
- `SparseReward` (`sparse`): 1 on every step that ends at the target (NoAux+SparseR baseline).
- `ShapedReward` (`shaped`): progress towards the target from simulator ground truth, plus the sparse reward
  (RSI-style baseline).
"""

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
import torch

if TYPE_CHECKING:
    from learning.sounds import SoundCorpus

RewardKind = Literal["var", "sparse", "shaped"]
# Raised when what a reward pays changes; stored with every Table I run and part of its recipe, so runs before
# and after a change are never seeds of one recipe (records without it: revision 1). Revision 2 (2026-12-02):
# sparse and shaped pay 1 on every step at the target, not once at a successful end.
REWARD_REVISIONS: dict[RewardKind, int] = {"var": 1, "sparse": 2, "shaped": 2}
SHAPED_STEP_M = (
    0.02  # one full action moves the Kuka/Kinova gripper target 2 cm: progress is counted in steps
)


def intrinsic_reward_from_embeddings(
    image_embedding: torch.Tensor,
    goal_embedding: torch.Tensor,
    current_sound_embedding: torch.Tensor | None = None,
) -> torch.Tensor:
    """(B, d) unit vectors → (B,) rewards: f_I(I)·f_S(S_goal) [+ f_S(S_t)·f_S(S_goal)]."""
    reward = (image_embedding * goal_embedding).sum(dim=-1)
    if current_sound_embedding is not None:
        reward = reward + (current_sound_embedding * goal_embedding).sum(dim=-1)
    return reward


def sparse_reward(heard: np.ndarray, target: np.ndarray) -> np.ndarray:
    """1 on every step that ends with the robot at its target (the gripper's ray on the target block, the
    target filling the TurtleBot's view), as the reference implementation's environment reward pays: a
    reward only at a successful episode's last step reached a random policy about once in 100 episodes,
    and PPO never learnt from it."""
    return ((heard == target) & (target >= 0)).astype(np.float32)


def shaped_reward(
    distance_before: np.ndarray, distance_after: np.ndarray, heard: np.ndarray, target: np.ndarray
) -> np.ndarray:
    """Distance decrease in action steps (ground truth, one simulator query per step) plus the sparse reward
    on every step at the target. Until 2026-12-02 the bonus came once, at a successful episode's last step:
    progress alone pays nothing for staying at the target, and those policies drifted off it."""
    progress = (distance_before - distance_after) / SHAPED_STEP_M
    return (np.nan_to_num(progress) + sparse_reward(heard, target)).astype(np.float32)


@dataclass
class StepOutcome:
    """What one vector step of some environments left behind, as the reward functions read it."""

    image_embedding: torch.Tensor  # f_I after the step (of the final observation where an episode ended)
    goal_clips: np.ndarray  # index into the goal bank of each environment's goal
    heard: np.ndarray  # the intent in view after the step (-1: nothing)
    distance_before: np.ndarray  # ground truth, metres to the target (the shaped baseline only)
    distance_after: np.ndarray
    done: np.ndarray  # the episode ended with this step
    success: np.ndarray  # ... and ended in success
    target: np.ndarray  # the intent each environment's episode asks for (ground truth)


class RewardFunction(Protocol):
    queries_simulator: bool  # every step costs one ground-truth query (counted as a label, as the paper does)

    def __call__(self, step: StepOutcome) -> np.ndarray:
        """The reward of each environment, float64."""
        ...


class IntrinsicReward:
    queries_simulator = False

    def __init__(self, goals: "ClipBank") -> None:
        if goals.embeddings is None:
            raise ValueError("embed the goal clips with the VAR first")
        self.goals = goals

    def goal_embeddings(self, step: StepOutcome) -> torch.Tensor:
        return self.goals.embeddings[torch.from_numpy(step.goal_clips)]

    def __call__(self, step: StepOutcome) -> np.ndarray:
        reward = intrinsic_reward_from_embeddings(step.image_embedding, self.goal_embeddings(step))
        return reward.numpy().astype(np.float64)


class IntrinsicRewardWithCurrentSound(IntrinsicReward):
    def __init__(self, goals: "ClipBank", current: "CurrentSound", rng: np.random.Generator) -> None:
        super().__init__(goals)
        self.current, self.rng = current, rng

    def __call__(self, step: StepOutcome) -> np.ndarray:
        heard_now = self.current.embeddings(step.heard, self.rng)
        reward = intrinsic_reward_from_embeddings(step.image_embedding, self.goal_embeddings(step), heard_now)
        return reward.numpy().astype(np.float64)


class IntrinsicRewardAgainstOtherCommands(IntrinsicReward):
    """r_t = f_I(I_{t+1})·f_S(S_goal) − max over the other commands c of f_I(I_{t+1})·p_c, with p_c the unit
    mean of command c's goal-clip embeddings.

    Why: with 3-D embeddings, four blocks and "nothing" cannot all be far apart, so the plain reward pays
    about 0 at a block next to the goal's and about −0.3 at no block; policies settled on the neighbour and
    rarely found their own block. Here the neighbour pays about −0.85 and no block about 0, while the goal's
    own block still pays about +0.8. Reads only the VAR and which clips are of one command (the commands a
    robot is given), never the simulator."""

    def __init__(self, goals: "ClipBank") -> None:
        super().__init__(goals)
        commands = goals.commands
        if len(commands) < 2:
            raise ValueError(
                "the reward against other commands needs goal clips of at least two commands, "
                f"grouped by command; these clips have {len(commands)}"
            )
        if (goals.intents < 0).any():
            raise ValueError(
                "the reward against other commands needs every goal clip's command; "
                f"{int((goals.intents < 0).sum())} clips have none (-1)"
            )
        means = torch.stack([goals.embeddings[torch.from_numpy(goals.clips_of(c))].mean(0) for c in commands])
        self.prototypes = torch.nn.functional.normalize(means, dim=-1)
        row_of = {c: i for i, c in enumerate(commands)}
        self.command_row = torch.tensor([row_of[int(k)] for k in goals.intents])

    def __call__(self, step: StepOutcome) -> np.ndarray:
        own = intrinsic_reward_from_embeddings(step.image_embedding, self.goal_embeddings(step))
        matches = step.image_embedding @ self.prototypes.T  # (B, commands)
        rows = self.command_row[torch.from_numpy(step.goal_clips)]
        matches[torch.arange(len(rows)), rows] = -torch.inf
        return (own - matches.max(dim=-1).values).numpy().astype(np.float64)


class SharpenedIntrinsicReward(IntrinsicReward):
    """r_t = exp((f_I(I_{t+1})·f_S(S_goal) − 1)/T). Why: the plain match pays a block next to the goal's about
    0.3 more than no block, a third of what the goal's own block adds; at T = 0.25 that share falls to about
    1/30, while the reward still rises along every path towards the goal's block. (Subtracting the other
    commands' matches instead made PPO stop going to blocks: every evaluation episode ended at none.)"""

    def __init__(self, goals: "ClipBank", temperature: float) -> None:
        super().__init__(goals)
        if temperature <= 0:
            raise ValueError(f"the reward's temperature must be positive, got {temperature}")
        self.temperature = temperature

    def __call__(self, step: StepOutcome) -> np.ndarray:
        match = intrinsic_reward_from_embeddings(step.image_embedding, self.goal_embeddings(step))
        return torch.exp((match - 1.0) / self.temperature).numpy().astype(np.float64)


class SparseReward:
    queries_simulator = True

    def __call__(self, step: StepOutcome) -> np.ndarray:
        return sparse_reward(step.heard, step.target).astype(np.float64)


class ShapedReward:
    queries_simulator = True

    def __call__(self, step: StepOutcome) -> np.ndarray:
        return shaped_reward(step.distance_before, step.distance_after, step.heard, step.target).astype(
            np.float64
        )


def make_reward(
    kind: RewardKind,
    goals: "ClipBank",
    var: torch.nn.Module | None = None,
    current_sounds: "ClipBank | None" = None,
    rng: np.random.Generator | None = None,
    against_others: bool = False,
    temperature: float | None = None,
) -> RewardFunction:
    """The reward of a run. With `current_sounds` (and the VAR, and the generator that picks which clip of the
    intent in view is heard) the intrinsic reward adds the current-sound term; with `against_others` it
    subtracts the view's best match with another command; with a `temperature` it is sharpened."""
    if kind == "sparse":
        return SparseReward()
    if kind == "shaped":
        return ShapedReward()
    if against_others:
        return IntrinsicRewardAgainstOtherCommands(goals)
    if temperature is not None:
        return SharpenedIntrinsicReward(goals, temperature)
    if current_sounds is None:
        return IntrinsicReward(goals)
    return IntrinsicRewardWithCurrentSound(goals, CurrentSound.heard_through(var, current_sounds), rng)


@dataclass
class ClipBank:
    """Sound clips (features of the VAR's sound front end) with their intents (-1 = unknown, e.g. a household
    recording not matched to an intent) and, when a VAR is given, their f_S embeddings computed once."""

    features: np.ndarray  # (N, frames, values) float32: (N, 100, 40) MFCC, (N, frames, 96) speech-embedding
    intents: np.ndarray  # (N,) int64
    embeddings: torch.Tensor | None = None  # (N, d)

    def __post_init__(self) -> None:
        if self.features.ndim != 3:
            raise ValueError(f"clip features must be shaped (N, frames, values), got {self.features.shape}")
        if len(self.features) == 0:
            raise ValueError("no goal clips: give at least one clip")
        if len(self.intents) != len(self.features):
            raise ValueError("one intent per clip is needed (use -1 for unknown)")
        known = self.intents[self.intents >= 0]
        self._by_intent = {int(k): np.flatnonzero(self.intents == k) for k in np.unique(known)}
        self._any = np.arange(len(self.features))

    def embed(self, var: torch.nn.Module, batch: int = 512) -> "ClipBank":
        with torch.inference_mode():
            chunks = [
                var.encode_sound(torch.from_numpy(self.features[i : i + batch])).float()
                for i in range(0, len(self.features), batch)
            ]
        self.embeddings = torch.cat(chunks).clone()
        return self

    @property
    def has_intents(self) -> bool:
        return bool(self._by_intent)

    @property
    def commands(self) -> list[int]:
        """The intents with clips here, in order."""
        return sorted(self._by_intent)

    def clips_of(self, intent: int) -> np.ndarray:
        return self._by_intent[intent]

    def sample(self, intents: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One clip index per requested intent (uniform over that intent's clips; over all clips when the bank
        has no intents)."""
        picks = np.empty(len(intents), dtype=np.int64)
        for i, intent in enumerate(intents):
            pool = self._by_intent.get(int(intent), self._any) if self._by_intent else self._any
            if self._by_intent and int(intent) not in self._by_intent:
                raise ValueError(
                    f"no goal clip for intent {int(intent)}; the clip list must cover every intent"
                )
            picks[i] = pool[rng.integers(len(pool))]
        return picks


def corpus_bank(
    name: str, splits: str | list[str], data_dir: Path | None = None, front_end: str = "mfcc"
) -> ClipBank:
    """The clips of these splits with the features of `front_end` (the VAR's: `var.front_end`)."""
    from learning.sounds import load_corpus

    return clip_bank_of(load_corpus(name, data_dir, front_end=front_end).subset(splits))


def clip_bank_of(corpus: "SoundCorpus", rows: list[int] | None = None) -> ClipBank:
    """A corpus's clips (or only these rows of it) as a bank of goal clips."""
    picked = slice(None) if rows is None else rows
    features, intents = corpus.features[picked], corpus.intent[picked]
    return ClipBank(np.asarray(features, dtype=np.float32), np.asarray(intents, dtype=np.int64))


def clip_bank_from_paths(specs: list[str], front_end: str = "mfcc") -> ClipBank:
    """`[INTENT:]PATH` entries: a WAV/audio file or a .npy of `front_end` features, e.g. MFCC (100, 40) or
    (N, 100, 40)."""
    from learning.audio import features_from_bytes

    features, intents = [], []
    for spec in specs:
        intent_text, sep, path_text = spec.partition(":")
        if sep and intent_text.isdigit():
            intent, path = int(intent_text), Path(path_text)
        else:
            intent, path = -1, Path(spec)
        if not path.exists():
            raise FileNotFoundError(f"goal clip {path} does not exist")
        if path.suffix == ".npy":
            array = np.load(path).astype(np.float32)
            array = array[None] if array.ndim == 2 else array
        else:
            array = features_from_bytes(path.read_bytes(), front_end=front_end)[None]
        features.append(array)
        intents += [intent] * len(array)
    return ClipBank(np.concatenate(features), np.asarray(intents, dtype=np.int64))


class CurrentSound:
    """S_t: a random training clip of the intent heard now, silence when nothing is — as embeddings."""

    def __init__(self, bank: ClipBank, silence_embedding: torch.Tensor) -> None:
        if bank.embeddings is None:
            raise ValueError("embed the clip bank with the VAR first")
        self.bank = bank
        self.silence = silence_embedding.reshape(-1)

    @classmethod
    def heard_through(cls, var: torch.nn.Module, bank: ClipBank) -> "CurrentSound":
        """The clips and silence as the VAR embeds them."""
        if bank.embeddings is None:
            bank.embed(var)
        with torch.inference_mode():
            silence = var.encode_silence()
        return cls(bank, silence)

    def embeddings(self, heard: np.ndarray, rng: np.random.Generator) -> torch.Tensor:
        out = self.silence.expand(len(heard), -1).clone()
        heard_any = heard >= 0
        if heard_any.any():
            picks = self.bank.sample(heard[heard_any], rng)
            out[torch.from_numpy(heard_any)] = self.bank.embeddings[torch.from_numpy(picks)]
        return out
