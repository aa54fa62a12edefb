"""Reward normalisation as gymnasium's NormalizeReward does it, per environment: divide each reward by the
running standard deviation of the discounted return."""

import math

import numpy as np
import torch


class RunningMeanStd:
    """Parallel-algorithm running moments, for the discounted return."""

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

    def load(self, state: list[float]) -> None:
        self.mean, self.var, self.count = state


class ReturnNormalizer:
    """Off (`enabled=False`): rewards pass unchanged. The moments carry over resets; the returns do not."""

    def __init__(self, gamma: float, enabled: bool) -> None:
        self.gamma, self.enabled = gamma, enabled
        self.rms = RunningMeanStd()
        self.reset(0)

    def reset(self, num_envs: int) -> None:
        self.discounted_return = np.zeros(num_envs)

    def __call__(self, group: slice, raw: np.ndarray, done: np.ndarray) -> torch.Tensor:
        """The group's rewards (float64) normalised, float32."""
        if not self.enabled:
            return torch.from_numpy(raw.astype(np.float32))
        returns = self.discounted_return[group] * self.gamma + raw
        self.rms.update(returns)
        returns[done] = 0.0
        self.discounted_return[group] = returns
        return torch.from_numpy((raw / math.sqrt(self.rms.var + 1e-8)).astype(np.float32))
