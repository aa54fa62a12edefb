"""Stage 3: measure a candidate against the active version on the same household data, and the promotion
gate that decides whether the candidate becomes active.

(a) triplet accuracy on the held-out household triplets (images of snapshots never trained on);
(b) simulated success with the household's clips as goals: the evaluation protocol of `learning.rl.evaluate`
    (fixed episode list, deterministic policy) in the robot's simulated world, in its room (domain shift).
"""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from core.rooms import DomainShift
from worker.household import HouseholdData
from worker.var_stage import triplet_accuracy

NUM_INTENTS = 4


@dataclass
class ModelScore:
    triplet_accuracy: float | None
    held_out_triplets: int
    sim_success: float | None
    sim_episodes: int
    sim_success_by_intent: list[float] | None = None
    sim_note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()}


@dataclass
class GateDecision:
    promote: bool
    reasons: list[str] = field(default_factory=list)


def sim_goals(data: HouseholdData):  # type: ignore[no-untyped-def]
    """Goal clips with the intent each one means, or a reason why simulated success cannot be measured."""
    from learning.rl.rewards import ClipBank

    known = data.clip_intent >= 0
    missing = sorted(set(range(NUM_INTENTS)) - set(data.clip_intent[known].tolist()))
    if missing:
        return None, (
            f"simulated success not measured: no recorded command is known to mean intent(s) {missing} "
            "(label more images of them with 'is')"
        )
    return ClipBank(data.features[known], data.clip_intent[known]), None


def score_model(
    data: HouseholdData,
    var_path: Path,
    policy_path: Path | None,
    world: str,
    episodes_per_intent: int,
    room: DomainShift | None,
    seed: int,
    num_envs: int,
) -> ModelScore:
    from learning.var.checkpoint import load_var

    var = load_var(var_path)
    accuracy = triplet_accuracy(var, data, data.test_triplets)
    score = ModelScore(accuracy, len(data.test_triplets), None, 0)
    goals, note = sim_goals(data)
    if policy_path is None:
        score.sim_note = "simulated success not measured: this version has no policy"
    elif goals is None:
        score.sim_note = note
    else:
        from learning.rl.evaluate import evaluate
        from learning.rl.ppo import load_policy

        policy, payload = load_policy(policy_path)
        config = payload["config"]
        goals.embed(var)
        result = evaluate(
            policy,
            var,
            goals,
            world,
            var.config.image_size,
            split="household",
            episodes_per_intent=episodes_per_intent,
            seed=seed,
            num_envs=min(num_envs, NUM_INTENTS * episodes_per_intent),
            success_rule=config.get("success_rule"),
            max_steps=config.get("max_episode_steps"),
            domain=room,
            progress=False,
        )
        score.sim_success = float(result.success_rate)
        score.sim_episodes = len(result.episodes)
        score.sim_success_by_intent = [None if math.isnan(x) else float(x) for x in result.success_by_intent]
    return score


def decide(candidate: ModelScore, active: ModelScore | None) -> GateDecision:
    """Promote only if the candidate is not worse on either measure; "not worse" allows one item's worth
    (one held-out triplet, one episode) of noise. A measure nobody could take is recorded, not judged."""
    if active is None:
        return GateDecision(True, ["no active version to compare with: the candidate becomes active"])
    reasons, worse, measured = [], False, 0
    for name, cand, act, count, why_not in (
        ("held-out triplet accuracy", candidate.triplet_accuracy, active.triplet_accuracy,
         candidate.held_out_triplets, None),
        ("simulated success with the household's commands", candidate.sim_success, active.sim_success,
         candidate.sim_episodes, candidate.sim_note or active.sim_note),
    ):  # fmt: skip
        if cand is None or act is None or count == 0:
            reasons.append(f"{name}: not measured" + (f" ({why_not})" if why_not else ""))
            continue
        measured += 1
        tolerance = 1.0 / count
        verdict = "worse" if cand < act - tolerance - 1e-9 else "not worse"
        worse |= verdict == "worse"
        reasons.append(
            f"{name}: candidate {cand:.3f} vs active {act:.3f} ({verdict}, tolerance {tolerance:.3f})"
        )
    if not measured:
        return GateDecision(False, [*reasons, "nothing could be measured: the candidate stays a candidate"])
    return GateDecision(not worse, reasons)


def summarise_scores(candidate: ModelScore, active: ModelScore | None) -> dict[str, Any]:
    return {
        "candidate": candidate.to_dict(),
        "active": None if active is None else active.to_dict(),
        "improvement": {
            "triplet_accuracy": _delta(candidate.triplet_accuracy, active and active.triplet_accuracy),
            "sim_success": _delta(candidate.sim_success, active and active.sim_success),
        },
    }


def _delta(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else float(np.round(a - b, 4))
