"""A household's training data, read from the database and the blob store: camera images, the household's
recorded commands as features of the VAR's sound front end (MFCC by default), and the triplets their pair
labels yield.

The triplet rule is the household's (`core.labels`): a snapshot with at least one *is* clip and one *is not*
clip gives |is| × |is not| triplets; a snapshot answered *is not* for every command is "nothing I said" and
gives (image, silence, clip) for each *is not* clip. Nothing else is ever used as supervision; the answers are
read as the API's triplet statistics read them (`backend.services.triplets.household_answers`).
"""

import io
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np
from PIL import Image
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobStore
from backend.services.triplets import household_answers
from core.labels import SILENCE_CLIP, Verdict, derive_triplets

SILENCE_ROW = -1  # the positive clip row of a "nothing I said" triplet
# the snapshot id of a view of the training room replayed with the household's (worker.replay)
REPLAYED_VIEW = -1
UNKNOWN_INTENT = -1


class TooFewTriplets(ValueError):
    """Refused before any training: the labels do not give enough triplets."""


@dataclass
class HouseholdData:
    snapshot_ids: np.ndarray  # (S,)
    images: np.ndarray  # (S, H, W, 3) uint8 at the VAR's image size
    sim_heard: np.ndarray  # (S,) what the simulator says is in view (-1 nothing/several, -2 not simulated)
    clip_ids: np.ndarray  # (C,) every live clip of the household
    features: np.ndarray  # (C, frames, values) float32 features of the VAR's front end: (C, 100, 40) MFCC
    clip_intent: np.ndarray  # (C,) intent inferred from the clip's *is* snapshots (-1 unknown)
    triplets: np.ndarray  # (T, 3): snapshot row, positive clip row (-1 = silence), negative clip row
    held_out: np.ndarray  # (T,) bool: the triplet's snapshot is held out (evaluation only)
    labels_used: int

    @property
    def train_triplets(self) -> np.ndarray:
        return self.triplets[~self.held_out]

    @property
    def test_triplets(self) -> np.ndarray:
        return self.triplets[self.held_out]


def load_household(
    session: Session,
    blobs: BlobStore,
    robot: models.Robot,
    image_size: int,
    feature_kind: str,
    held_out_fraction: float,
    seed: int,
    min_triplets: int,
    front_end: str = "mfcc",
) -> HouseholdData:
    """`front_end`: the sound front end of the VAR the data is for (`front_end_of(checkpoint)`)."""
    from learning.audio import features_from_bytes

    clips = list(
        session.scalars(
            select(models.Clip)
            .where(models.Clip.household_id == robot.household_id, models.Clip.deleted_at.is_(None))
            .order_by(models.Clip.id)
        )
    )
    household = household_answers(session, robot.household_id, robot.id)
    answers, clip_commands = household.answers, household.clip_commands
    triplet_ids = derive_triplets(answers, clip_commands)
    if len(triplet_ids) < max(min_triplets, 2):
        needed = max(min_triplets, 2)
        raise TooFewTriplets(
            f"fine-tuning needs at least {needed} triplets and this robot's labels give {len(triplet_ids)}: "
            f"{needed - len(triplet_ids)} more are needed. Answer more pairs on the Label page (each image "
            "needs one 'is' and one 'is not' answer, or 'is not' for every command)."
        )
    used_snapshots = sorted({t[0] for t in triplet_ids})
    # Every answered snapshot, not only those giving triplets: an *is* answer on a view with no *is not* yet
    # still tells which target a command names (for scoring simulated success).
    snapshots = {
        s.id: s for s in session.scalars(select(models.Snapshot).where(models.Snapshot.id.in_(list(answers))))
    }
    snapshot_row = {sid: row for row, sid in enumerate(used_snapshots)}
    clip_row = {clip.id: row for row, clip in enumerate(clips)}
    images = np.stack(
        [decoded_image(blobs.get(snapshots[sid].image_key), image_size) for sid in used_snapshots]
    )
    sim_heard = np.array([_sim_heard(snapshots[sid]) for sid in used_snapshots], dtype=np.int64)
    features = np.stack(
        [features_from_bytes(blobs.get(clip.wav_key), feature_kind, front_end) for clip in clips]
    )
    triplets = np.array(
        [
            (snapshot_row[s], SILENCE_ROW if p == SILENCE_CLIP else clip_row[p], clip_row[n])
            for s, p, n in triplet_ids
        ],
        dtype=np.int64,
    )
    held_out_snapshots = _held_out_rows(len(used_snapshots), held_out_fraction, seed)
    return HouseholdData(
        snapshot_ids=np.array(used_snapshots, dtype=np.int64),
        images=images,
        sim_heard=sim_heard,
        clip_ids=np.array([clip.id for clip in clips], dtype=np.int64),
        features=features.astype(np.float32),
        clip_intent=_infer_clip_intents(answers, clip_row, snapshots, [clip_commands[c.id] for c in clips]),
        triplets=triplets,
        held_out=np.isin(triplets[:, 0], held_out_snapshots),
        labels_used=sum(len(answers[sid]) for sid in used_snapshots),
    )


def decoded_image(png: bytes, size: int) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as image:
        image = image.convert("RGB")
        if image.size != (size, size):
            image = image.resize((size, size), Image.BILINEAR)
        return np.asarray(image, dtype=np.uint8)


def _sim_heard(snapshot: models.Snapshot) -> int:
    heard = (snapshot.meta or {}).get("sim_heard", -2)
    return -1 if heard is None else int(heard)


def _held_out_rows(count: int, fraction: float, seed: int) -> np.ndarray:
    if fraction <= 0 or count < 2:
        return np.array([], dtype=np.int64)
    held = min(count - 1, max(1, round(count * fraction)))
    return np.sort(np.random.default_rng([seed, 11]).permutation(count)[:held])


def _infer_clip_intents(
    answers: dict[int, list[tuple[int, str]]],
    clip_row: dict[int, int],
    snapshots: dict[int, models.Snapshot],
    commands: list[str],
) -> np.ndarray:
    """For simulated robots: which of the world's intents a command means, by majority over the simulator's
    ground truth of the images the household answered *is* for any of its clips (clips of one command share
    it). Used only to score simulated success and to match goals to the world's target; never as a training
    label. -1 when unknown."""
    votes: dict[str, Counter[int]] = defaultdict(Counter)
    for snapshot_id, pairs in answers.items():
        snapshot = snapshots.get(snapshot_id)
        heard = _sim_heard(snapshot) if snapshot is not None else -2
        if heard < 0:
            continue
        for clip_id, verdict in pairs:
            if verdict == Verdict.IS and clip_id in clip_row:
                votes[commands[clip_row[clip_id]]][heard] += 1
    return np.array(
        [votes[command].most_common(1)[0][0] if votes[command] else UNKNOWN_INTENT for command in commands],
        dtype=np.int64,
    )
