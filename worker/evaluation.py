"""Stage 3: measure a candidate against the active version on the same household data, and the promotion
gate that decides whether the candidate becomes active.

(a) triplet accuracy on the held-out household triplets (images of snapshots never trained on);
(b) simulated success with the household's clips as goals: the evaluation protocol of `learning.rl.evaluate`
    (fixed episode list, deterministic policy) in the robot's simulated world, in its room (domain shift).
"""

import math
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from core.rooms import DomainShift
from worker.household import HouseholdData
from worker.var_stage import triplet_accuracy

if TYPE_CHECKING:
    from learning.rl.evaluate import EvalResult
    from learning.rl.rewards import ClipBank
    from learning.var.model import VAR


@dataclass
class ModelScore:
    triplet_accuracy: float | None
    held_out_triplets: int
    sim_success: float | None
    sim_episodes: int
    sim_success_by_intent: list[float] | None = None
    # per intent: how many tries ended at each intent's object, the last column at none (between or off them)
    sim_final_views: list[list[int]] | None = None
    # per intent: the median distance (m) to its object at the end of the tries that ended at no object
    sim_missed_by_m: list[float | None] | None = None
    sim_note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()}


def sim_goals(data: HouseholdData):  # type: ignore[no-untyped-def]
    """Goal clips with the intent each one means (the simulator's account of the views answered *is*), or a
    reason why simulated success cannot be measured: it is, on the targets the commands name, as soon as
    every recorded command has at least one *is* answer."""
    from learning.rl.rewards import ClipBank

    known = data.clip_intent >= 0
    if not known.all():
        return None, (
            f"simulated success not measured: {int((~known).sum())} of {len(known)} recordings belong to "
            "commands with no 'is' answer yet (answer 'is' for each command at least once)"
        )
    return ClipBank(data.features, data.clip_intent), None


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
        from learning.rl.evaluate import median_miss_by_intent

        goals.embed(var)
        intents = sorted(set(data.clip_intent.tolist()))
        result = simulate(policy_path, var, goals, world, episodes_per_intent, room, seed, num_envs, intents)
        score.sim_success = float(result.success_rate)
        score.sim_episodes = len(result.episodes)
        score.sim_success_by_intent = [None if math.isnan(x) else float(x) for x in result.success_by_intent]
        score.sim_final_views = result.final_view_by_intent
        score.sim_missed_by_m = median_miss_by_intent(result.episodes, len(result.final_view_by_intent))
    return score


def simulate(
    policy_path: Path,
    var: "VAR",
    goals: "ClipBank",
    world: str,
    episodes_per_intent: int,
    room: DomainShift | None,
    seed: int,
    num_envs: int,
    intents: list[int],
) -> "EvalResult":
    """The evaluation protocol's episodes (`learning.rl.evaluate`) of the policy at `policy_path`, seeing
    through `var`, with `goals` (embedded by `var`) naming `intents`, in `room` (None: the training room)."""
    from learning.rl.evaluate import evaluate
    from learning.rl.ppo import PPOConfig, load_policy

    policy, payload = load_policy(policy_path)
    config = PPOConfig.from_dict(payload["config"])
    return evaluate(
        policy,
        var,
        goals,
        world,
        var.config.image_size,
        split="household",
        episodes_per_intent=episodes_per_intent,
        seed=seed,
        num_envs=min(num_envs, len(intents) * episodes_per_intent),
        success_rule=config.success_rule,
        max_steps=config.max_episode_steps,
        world_options=config.world_options,
        domain=room,
        progress=False,
        intents=intents,
    )


class Verdict(StrEnum):
    BETTER = "better"
    NO_CHANGE = "no_change"
    WORSE = "worse"


# The rule every claim follows: a difference between two success rates measured on the same n items counts
# only beyond Z standard errors of a difference of two proportions, sqrt(2 p(1 - p) / n) at their pooled rate
# p (about 95 % of chance differences stay inside); and a gain is claimed only from MIN_ITEMS items, the
# fewest at which a MEANINGFUL_GAIN (two more successes in ten tries) clears that bar at the worst case p = ½.
Z = 2.0
MEANINGFUL_GAIN = 0.2
MIN_ITEMS = math.ceil(2 * Z**2 * 0.25 / MEANINGFUL_GAIN**2)  # 50


@dataclass
class GateDecision:
    promote: bool
    reasons: list[str] = field(default_factory=list)
    verdict: Verdict = Verdict.NO_CHANGE
    summary: str = ""  # the verdict in the household's words
    min_items: int = MIN_ITEMS


def standard_error(candidate: float, active: float, items: int) -> float:
    """One standard error of the difference of two rates on the same `items` items, at their pooled rate."""
    pooled = (candidate + active) / 2
    return math.sqrt(2 * pooled * (1 - pooled) / items)


def compare(candidate: float, active: float, items: int) -> Verdict:
    """Two rates on the same `items` items, by the rule above."""
    noise = Z * standard_error(candidate, active, items)
    difference = candidate - active
    if difference > noise + 1e-9 and items >= MIN_ITEMS:
        return Verdict.BETTER
    if difference < -noise - 1e-9:
        return Verdict.WORSE
    return Verdict.NO_CHANGE


def decide(
    candidate: ModelScore, active: ModelScore | None, command_names: dict[int, str] | None = None
) -> GateDecision:
    """Better, no measurable change or worse, on held-out triplet accuracy and simulated success with the
    household's commands (each by `compare`); worse on either is worse, else better on either is better,
    except that a candidate whose simulated success fell by more than one standard error is not better.
    Only a better candidate is promoted (or the first version of a robot). `command_names`: the household's
    word for each intent, for the summary."""
    if active is None:
        return GateDecision(
            True, ["no active version to compare with: the candidate becomes active"], Verdict.BETTER,
            "This is the robot's first version; it is now active.",
        )  # fmt: skip
    names = command_names or {}
    reasons: list[str] = []
    verdicts: dict[str, Verdict] = {}  # by measure
    for name, cand, act, count, why_not in (
        (ACCURACY, candidate.triplet_accuracy, active.triplet_accuracy, candidate.held_out_triplets, None),
        (SUCCESS, candidate.sim_success, active.sim_success, candidate.sim_episodes,
         candidate.sim_note or active.sim_note),
    ):  # fmt: skip
        if cand is None or act is None or count == 0:
            reasons.append(f"{name}: not measured" + (f" ({why_not})" if why_not else ""))
            continue
        verdict = compare(cand, act, count)
        verdicts[name] = verdict
        shortfall = f"; a gain needs at least {MIN_ITEMS}, this had {count}" if count < MIN_ITEMS else ""
        reasons.append(
            f"{name}: candidate {cand:.3f} vs active {act:.3f} on {count} ({_WORDS[verdict]}{shortfall})"
        )
    details = _per_command(candidate, active, names)
    if not verdicts:
        summary = "Nothing could be measured, so nothing changed: kept the old version."
        return GateDecision(False, [*reasons, "nothing could be measured: the candidate stays a candidate"],
                            Verdict.NO_CHANGE, summary)  # fmt: skip
    found = set(verdicts.values())
    overall = (
        Verdict.WORSE if Verdict.WORSE in found
        else Verdict.BETTER if Verdict.BETTER in found
        else Verdict.NO_CHANGE
    )  # fmt: skip
    if overall == Verdict.BETTER and _success_slipped(candidate, active):
        reasons.append(
            f"{SUCCESS} fell by more than one standard error, within the noise but the wrong way: a gain in "
            "the answers alone does not promote a robot that may now do worse"
        )
        said = f"{_accuracy_change(candidate, active)}, but {_success_change(candidate, active)}"
        summary = (
            f"No measurable change: {said}; kept the old version until more answers tell. "
            f"{_measured_on(candidate)}."
        )
        return GateDecision(False, reasons, Verdict.NO_CHANGE, summary)
    said = _what_changed(overall, verdicts, candidate, active, details)
    return GateDecision(overall == Verdict.BETTER, reasons, overall, _summary(overall, candidate, said))


def _success_slipped(candidate: ModelScore, active: ModelScore) -> bool:
    """Simulated success lower than the active version's by more than one standard error of the difference
    (about one chance difference in six goes that far down): not a measured loss, but enough doubt that a
    gain claimed from triplet accuracy alone should not replace what the household has."""
    new, old, tries = candidate.sim_success, active.sim_success, candidate.sim_episodes
    if new is None or old is None or not tries:
        return False
    return old - new > standard_error(new, old, tries) + 1e-9


ACCURACY = "held-out triplet accuracy"
SUCCESS = "simulated success with the household's commands"
_WORDS = {
    Verdict.BETTER: "better",
    Verdict.NO_CHANGE: "no measurable change",
    Verdict.WORSE: "worse",
}


def _per_command(candidate: ModelScore, active: ModelScore, names: dict[int, str]) -> list[str]:
    """ "*two* now works in 8 of 10 tries, was 3 of 10" for every command whose rate changed."""
    new, old = candidate.sim_success_by_intent, active.sim_success_by_intent
    if not new or not old or not candidate.sim_episodes:
        return []
    tries = candidate.sim_episodes // max(1, sum(rate is not None for rate in new))
    lines = []
    for intent, (now, before) in enumerate(zip(new, old, strict=False)):
        if now is None or before is None or round(now * tries) == round(before * tries):
            continue
        word = names.get(intent, f"target {intent + 1}")
        works, worked = round(now * tries), round(before * tries)
        lines.append(f"*{word}* now works in {works} of {tries} tries, was {worked} of {tries}")
    return lines


def _what_changed(
    verdict: Verdict,
    verdicts: dict[str, Verdict],
    candidate: ModelScore,
    active: ModelScore,
    details: list[str],
) -> str:
    """What moved, said only of the measures that gave `verdict`: a command's tries that changed within the
    noise are not the reason for a verdict another measure gave."""
    said = []
    if verdicts.get(ACCURACY) == verdict:
        said.append(_accuracy_change(candidate, active))
    if verdicts.get(SUCCESS) == verdict:
        said.append("; ".join(details) or _success_change(candidate, active))
    return "; ".join(said)


def _summary(verdict: Verdict, candidate: ModelScore, said: str) -> str:
    measured = _measured_on(candidate)
    if verdict == Verdict.BETTER:
        return f"Better: {said}; the new version is active. {measured}."
    if verdict == Verdict.WORSE:
        return f"Worse: {said}; kept the old version. {measured}."
    count = candidate.held_out_triplets
    if max(count, candidate.sim_episodes) < MIN_ITEMS:
        evidence = f"a claim needs at least {MIN_ITEMS} held-out answers or tries; this run had {count}"
        return f"No measurable change ({evidence}); kept the old version."
    return f"No measurable change; kept the old version. {measured}."


def _success_change(candidate: ModelScore, active: ModelScore) -> str:
    tries = candidate.sim_episodes
    now, before = round((candidate.sim_success or 0) * tries), round((active.sim_success or 0) * tries)
    return f"it now succeeds in {now} of {tries} tries, was {before} of {tries}"


def _measured_on(candidate: ModelScore) -> str:
    """How many items the verdict rests on, in words: "Measured on 120 held-out answers and 80 tries"."""
    parts = [f"{candidate.held_out_triplets} held-out answers"]
    if candidate.sim_success is not None and candidate.sim_episodes:
        parts.append(f"{candidate.sim_episodes} tries")
    return "Measured on " + " and ".join(parts)


def _accuracy_change(candidate: ModelScore, active: ModelScore) -> str:
    count = candidate.held_out_triplets
    if candidate.triplet_accuracy is None or active.triplet_accuracy is None or not count:
        return "the measures moved"
    now, before = round(candidate.triplet_accuracy * count), round(active.triplet_accuracy * count)
    return f"it now matches {now} of {count} held-out answers, was {before} of {count}"


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
