"""The triplets a household's labels yield (the rule is `core.labels`), read from the database: what a
training run will use, and how many each command and each member contributed."""

from collections import Counter, defaultdict
from dataclasses import dataclass, field

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.schemas import TripletCount, TripletStats
from core.labels import SILENCE_COMMAND, Triplet, command_key, derive_triplets

SILENCE_NAME = "nothing I said (silence)"


@dataclass
class HouseholdAnswers:
    """Every answer about a live image and a live clip; labels of deleted clips or images leave training."""

    clip_names: dict[int, str | None]  # every live clip of the household
    answers: dict[int, list[tuple[int, str]]] = field(default_factory=dict)  # snapshot → (clip, verdict)
    labellers: dict[tuple[int, int], int] = field(default_factory=dict)  # (snapshot, clip) → who answered

    @property
    def clip_commands(self) -> dict[int, str]:
        return {clip_id: command_key(clip_id, name) for clip_id, name in self.clip_names.items()}

    @property
    def label_count(self) -> int:
        return len(self.labellers)

    def triplets(self) -> list[Triplet]:
        return derive_triplets(self.answers, self.clip_commands)

    def credited(self, triplet: Triplet) -> int:
        """Who a triplet is counted for: whoever answered its *is* clip, or for silence its *is not* clip."""
        clip = triplet.negative_clip_id if triplet.silent else triplet.positive_clip_id
        return self.labellers[triplet.snapshot_id, clip]


def household_answers(session: Session, household_id: int, robot_id: int | None) -> HouseholdAnswers:
    """The household's answers, about the images of one robot (or of all its robots)."""
    live_clips = select(models.Clip.id, models.Clip.name).where(
        models.Clip.household_id == household_id, models.Clip.deleted_at.is_(None)
    )
    result = HouseholdAnswers(clip_names=dict(session.execute(live_clips).all()))
    query = (
        select(models.Label.snapshot_id, models.Label.clip_id, models.Label.verdict, models.Label.labeller_id)
        .join(models.Snapshot, models.Snapshot.id == models.Label.snapshot_id)
        .where(models.Label.household_id == household_id, models.Snapshot.deleted_at.is_(None))
    )
    if robot_id is not None:
        query = query.where(models.Snapshot.robot_id == robot_id)
    answers: defaultdict[int, list[tuple[int, str]]] = defaultdict(list)
    for snapshot_id, clip_id, verdict, labeller_id in session.execute(query):
        if clip_id in result.clip_names:
            answers[snapshot_id].append((clip_id, verdict))
            result.labellers[snapshot_id, clip_id] = labeller_id
    result.answers = dict(answers)
    return result


def triplet_stats(session: Session, household_id: int, robot_id: int | None) -> TripletStats:
    household = household_answers(session, household_id, robot_id)
    triplets = household.triplets()
    commands = household.clip_commands
    per_command = Counter(
        SILENCE_COMMAND if triplet.silent else commands[triplet.positive_clip_id] for triplet in triplets
    )
    per_member = Counter(household.credited(triplet) for triplet in triplets)
    names = {commands[clip_id]: name or f"clip {clip_id}" for clip_id, name in household.clip_names.items()}
    names[SILENCE_COMMAND] = SILENCE_NAME
    members = dict(
        session.execute(
            select(models.User.id, models.User.display_name).where(models.User.household_id == household_id)
        ).all()
    )
    return TripletStats(
        triplets=len(triplets),
        with_silence_positive=sum(triplet.silent for triplet in triplets),
        snapshots_used=len({triplet.snapshot_id for triplet in triplets}),
        labels=household.label_count,
        per_command=[TripletCount(key=k, name=names[k], triplets=n) for k, n in per_command.most_common()],
        per_member=[
            TripletCount(key=str(who), name=members.get(who, f"member {who}"), triplets=n)
            for who, n in per_member.most_common()
        ],
    )
