"""What a run reports besides its losses: recent episodes, where the time goes, and the peak memory."""

import contextlib
import math
import os
from collections import deque
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields

import numpy as np
import psutil


def mean_or_nan(values: list[float]) -> float:
    """Mean of the known values; NaN when there are none (goals without intents have no success rate)."""
    known = [v for v in values if not math.isnan(v)]
    return float(np.mean(known)) if known else float("nan")


@dataclass
class EpisodeStats:
    returns: deque = field(default_factory=lambda: deque(maxlen=100))
    lengths: deque = field(default_factory=lambda: deque(maxlen=100))
    successes: deque = field(default_factory=lambda: deque(maxlen=100))
    intents: deque = field(default_factory=lambda: deque(maxlen=100))  # -1: unknown (older checkpoints)
    replayed: deque = field(default_factory=lambda: deque(maxlen=100))  # ran in a replay environment
    # the strip of the table the gripper started in (sim.blocks.start_strip_of); -1: not tracked (the start
    # curriculum is off, or the checkpoint is older)
    start_strips: deque = field(default_factory=lambda: deque(maxlen=100))

    @staticmethod
    def unknown(key: str) -> object:
        """What a field holds for episodes stored before it was tracked (older checkpoints): -1 for start
        strips; False for `replayed` (they count as the run's own room's)."""
        return -1 if key == "start_strips" else False

    @classmethod
    def over_last(cls, episodes: int) -> "EpisodeStats":
        return cls(**{f.name: deque(maxlen=episodes) for f in fields(cls)})

    def success_by_intent(self, num_intents: int) -> list[float]:
        """Recent success rate of each intent's episodes (NaN for an intent with none in the window)."""
        pairs = list(zip(self.intents, self.successes, strict=True))
        return [mean_or_nan([s for i, s in pairs if i == intent]) for intent in range(num_intents)]

    def success_by_room(self) -> dict[str, float]:
        """Recent success in the run's own room and in the replay room (NaN where none ended lately)."""
        pairs = list(zip(self.replayed, self.successes, strict=True))
        return {
            "own_room": mean_or_nan([s for replayed, s in pairs if not replayed]),
            "replay_room": mean_or_nan([s for replayed, s in pairs if replayed]),
        }

    def return_by_intent(self, num_intents: int) -> list[float]:
        """Recent mean episode return of each intent (NaN for an intent with none in the window)."""
        pairs = list(zip(self.intents, self.returns, strict=True))
        return [mean_or_nan([r for i, r in pairs if i == intent]) for intent in range(num_intents)]

    def return_by_start_strip(self, num_strips: int) -> list[float]:
        """Recent mean episode return of each start strip (NaN for a strip with none in the window)."""
        pairs = list(zip(self.start_strips, self.returns, strict=True))
        return [mean_or_nan([r for k, r in pairs if k == strip]) for strip in range(num_strips)]


class EpisodeTracker:
    """Sums each environment's episode as it runs; a finished episode goes into `stats`."""

    def __init__(
        self, stats: EpisodeStats, success_known: bool, replay_envs: frozenset[int] = frozenset()
    ) -> None:
        self.stats = stats
        self.success_known = success_known  # goals with intents: success means something
        self.replay_envs = replay_envs
        self.reset(0)

    def reset(self, num_envs: int) -> None:
        self.episode_return = np.zeros(num_envs)
        self.episode_length = np.zeros(num_envs, dtype=np.int64)

    def step(
        self, group: slice, raw: np.ndarray, done: np.ndarray, success: np.ndarray, intent: np.ndarray,
        start_strip: np.ndarray | None = None,
    ) -> list[dict[str, float]]:  # fmt: skip
        """Add the group's step; returns the episodes it ended. `intent` is every environment's target,
        `start_strip` the strip every environment's episode started in (None: not tracked)."""
        self.episode_return[group] += raw
        self.episode_length[group] += 1
        finished = []
        for e in np.flatnonzero(done) + group.start:
            ok = float(success[e - group.start]) if self.success_known else float("nan")
            episode = {
                "return": float(self.episode_return[e]),
                "length": int(self.episode_length[e]),
                "success": ok,
            }
            finished.append(episode)
            self.stats.returns.append(episode["return"])
            self.stats.lengths.append(episode["length"])
            self.stats.successes.append(ok)
            self.stats.intents.append(int(intent[e]))
            self.stats.replayed.append(int(e) in self.replay_envs)
            self.stats.start_strips.append(-1 if start_strip is None else int(start_strip[e]))
        self.episode_return[group][done] = 0.0
        self.episode_length[group][done] = 0
        return finished


@dataclass
class Timings:
    env_s: float = 0.0  # handing actions to the workers and waiting for them to step
    var_s: float = 0.0  # f_I on the new images (reward + next observation), and the policy's view of them
    policy_s: float = 0.0  # acting (policy forward + sampling) and preparing observations
    update_s: float = 0.0
    other_s: float = 0.0

    def shares(self) -> dict[str, float]:
        total = self.env_s + self.var_s + self.policy_s + self.update_s + self.other_s
        return {k: v / total if total else 0.0 for k, v in asdict(self).items()}


class PeakMemory:
    """Learner + worker processes: proportional set sizes summed (shared pages counted once); the peak."""

    def __init__(self, peak_bytes: int = 0) -> None:
        self.peak_bytes = peak_bytes

    def sample(self, workers: Iterable[psutil.Process]) -> None:
        total = 0
        for process in [psutil.Process(os.getpid()), *workers]:
            with contextlib.suppress(psutil.Error):  # a worker that just exited
                total += process.memory_full_info().pss
        self.peak_bytes = max(self.peak_bytes, total)

    @property
    def peak_mb(self) -> float:
        return self.peak_bytes / 2**20
