"""Which targets the worlds ask for: a curriculum that favours targets whose recent return is low, and an
optional restriction to some targets (diagnostics). The workers draw their next targets with these
probabilities (`RLInfo.intent_weights`). In the block worlds, a second curriculum favours the strips of the
table where episodes that start there earn least (`RLInfo.start_strip_weights`)."""

import numpy as np

from learning.rl.stats import EpisodeStats


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


class Curriculum:
    """Off (the worlds draw uniformly) without a hard share and a restriction, or without goal intents."""

    def __init__(
        self, hard_share: float, targets: list[int] | None, num_intents: int, goals_have_intents: bool
    ) -> None:
        self.hard_share = hard_share
        self.num_intents = num_intents
        self.targets = sorted(set(targets or range(num_intents)))
        self.active = bool(hard_share or targets) and goals_have_intents
        self.weights: list[float] | None = None  # the last ones sent

    def next_weights(self, stats: EpisodeStats) -> list[float] | None:
        """New target probabilities for the workers; None when they already hold these (or it is off)."""
        if not self.active:
            return None
        returns = stats.return_by_intent(self.num_intents)
        weights = [0.0] * self.num_intents
        shares = curriculum_weights([returns[t] for t in self.targets], self.hard_share)
        for target, weight in zip(self.targets, shares, strict=True):
            weights[target] = weight
        if weights == self.weights:
            return None  # a fresh trainer starts from None: it always sends
        self.weights = weights
        return weights


class StartCurriculum:
    """Off without a hard share. Otherwise a share of the episodes start in the strips of the table
    (`sim.blocks.START_STRIPS`) whose recent mean return lies furthest below the best strip's: the starts a
    policy has not learned to leave yet (its intrinsic return, never the simulator's success)."""

    def __init__(self, hard_share: float, num_strips: int) -> None:
        self.hard_share = hard_share
        self.num_strips = num_strips
        self.active = hard_share > 0
        self.weights: list[float] | None = None  # the last ones sent

    def next_weights(self, stats: EpisodeStats) -> list[float] | None:
        """New start-strip probabilities for the workers; None when they already hold these (or it is off)."""
        if not self.active:
            return None
        weights = curriculum_weights(stats.return_by_start_strip(self.num_strips), self.hard_share)
        if weights == self.weights:
            return None
        self.weights = weights
        return weights
