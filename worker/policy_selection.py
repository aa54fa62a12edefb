"""Which policy of a self-improvement becomes the candidate: not always the last update's.

A household's PPO run need not end on its best update: the household's room or the training room can be
better some updates before the last. The trainer keeps a numbered checkpoint every `checkpoint_every`
updates, and one of the policy it started from (update 0, seeing through the run's VAR as the first update
did); this module scores each of them on validation episodes of their own, with a seed the evaluate stage
never uses, so the gate's figures stay an honest test of the one chosen. It cannot undo what the VAR
fine-tune did before PPO began: the start carries that too (README, *Choosing the policy*).

The rule: a policy that fell in the simulator's training room by more than the noise allows (`worker.
evaluation.compare`, against the start) is out; of the rest, the most successful in the household's room
wins, a later one on a tie. Where the household's room is the training room, one score serves both.
"""

import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from core.rooms import DomainShift
from worker.evaluation import Verdict, compare, sim_goals, simulate
from worker.household import HouseholdData

VALIDATION_SEED_OFFSET = 500_009  # the evaluate stage plays seed + 7919; these episodes are other ones
NUMBERED_CHECKPOINT = re.compile(r"checkpoint_(\d{6})\.pt")


@dataclass
class PolicyScore:
    update: int
    checkpoint: str
    own_room: float
    training_room: float | None  # None: the household's room is the training room


@dataclass
class Selection:
    chosen: PolicyScore
    scores: list[PolicyScore]
    episodes_per_room: int
    reason: str
    excluded_updates: list[int] = field(default_factory=list)
    wall_s: float | None = None  # the validation episodes' time, start-up included

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def policies_to_compare(run_dir: Path) -> list[tuple[int, Path]]:
    """(update, checkpoint) of every numbered checkpoint (from the start's, update 0, as PPO's first update
    saw it) and the final one, in update order."""
    from learning.rl.checkpoints import read_policy_checkpoint

    found = {}
    for path in sorted(run_dir.glob("checkpoint_*.pt")):
        match = NUMBERED_CHECKPOINT.fullmatch(path.name)
        if match:
            found[int(match.group(1))] = path
    final = run_dir / "checkpoint.pt"
    found.setdefault(int(read_policy_checkpoint(final)["update_index"]), final)
    return sorted(found.items())


def select_policy(
    data: HouseholdData,
    run_dir: Path,
    var_path: Path,
    world: str,
    room: DomainShift | None,
    seed: int,
    episodes_per_room: int,
    num_envs: int,
    on_scored: Callable[[float, PolicyScore], bool] | None = None,
) -> Selection | str:
    """Score the run's policies (`policies_to_compare`) and choose one (the module's rule); or say why none
    could be scored. `on_scored(fraction, score)` after each (True: stop, as a cancel)."""
    from learning.var.checkpoint import load_var
    from worker.progress import Cancelled

    goals, note = sim_goals(data)
    if goals is None:
        return f"the last update's policy was kept: {note}"
    var = load_var(var_path)
    goals.embed(var)
    intents = sorted(set(data.clip_intent.tolist()))
    per_intent = max(1, -(-episodes_per_room // len(intents)))
    validation_seed = seed + VALIDATION_SEED_OFFSET

    def success_in(policy: Path, in_room: DomainShift | None) -> float:
        result = simulate(policy, var, goals, world, per_intent, in_room, validation_seed, num_envs, intents)
        return float(result.success_rate)

    started = time.perf_counter()
    candidates = policies_to_compare(run_dir)
    scores: list[PolicyScore] = []
    for index, (update, policy) in enumerate(candidates):
        own = success_in(policy, room)
        training = None if room is None else success_in(policy, None)
        scores.append(PolicyScore(update, str(policy), own, training))
        if on_scored is not None and on_scored((index + 1) / len(candidates), scores[-1]):
            raise Cancelled("cancel requested while choosing among the policy's checkpoints")
    selection = choose(scores, per_intent * len(intents))
    selection.wall_s = round(time.perf_counter() - started, 1)
    return selection


def choose(scores: list[PolicyScore], episodes: int) -> Selection:
    """The module's rule over `scores` (the first is the start), each measured on `episodes` per room."""
    start, last = scores[0], scores[-1]
    kept = [score for score in scores if not _forgot(score, start, episodes)]
    chosen = max(reversed(kept), key=lambda score: score.own_room)  # reversed: a tie goes to the later one
    excluded = [score.update for score in scores if score not in kept]
    return Selection(chosen, scores, episodes, _reason(chosen, last, start, excluded, episodes), excluded)


def _forgot(score: PolicyScore, start: PolicyScore, episodes: int) -> bool:
    if score.training_room is None or start.training_room is None:
        return False
    return compare(score.training_room, start.training_room, episodes) is Verdict.WORSE


def _reason(
    chosen: PolicyScore, last: PolicyScore, start: PolicyScore, excluded: list[int], episodes: int
) -> str:
    said = (
        f"kept the policy of update {chosen.update} of {last.update}: {chosen.own_room:.0%} in the "
        f"household's room on {episodes} validation episodes"
    )
    if chosen.update != last.update:
        said += f" (the last update's: {last.own_room:.0%})"
    if chosen.update == 0:
        said += "; self-improvement did not beat the policy it started from"
    if excluded:
        said += (
            f"; updates {', '.join(map(str, excluded))} fell in the simulator's training room below the "
            f"start's {start.training_room:.0%}"
        )
    return said
