"""What a household's pair labels mean: which clips are one command, and which triplets the answers give.

A command is a clip's name when it has one (several recordings of "the red block" are one command), else the
clip itself. A triplet (image, positive sound, negative sound) comes from a snapshot with at least one *is*
clip and one *is not* clip (|is| × |is not| triplets). A snapshot answered *is not* for every command of the
household shows "nothing I said": silence is its positive, each *is not* clip a negative. Nothing else is
ever used as supervision.
"""

from collections.abc import Mapping, Sequence
from enum import StrEnum
from typing import NamedTuple

SILENCE_CLIP = -1  # the positive of a "nothing I said" triplet: no clip, silence
SILENCE_COMMAND = "silence"  # the command key of silence, beside the keys of `command_key`


class Verdict(StrEnum):
    IS = "is"
    IS_NOT = "is_not"


class Triplet(NamedTuple):
    snapshot_id: int
    positive_clip_id: int  # SILENCE_CLIP for "nothing I said"
    negative_clip_id: int

    @property
    def silent(self) -> bool:
        return self.positive_clip_id == SILENCE_CLIP


def command_key(clip_id: int, name: str | None) -> str:
    """The command a clip records: its name, ignoring case and surrounding spaces, or the clip alone."""
    return f"name:{name.strip().casefold()}" if name and name.strip() else f"clip:{clip_id}"


def derive_triplets(
    answers: Mapping[int, Sequence[tuple[int, str]]], clip_commands: Mapping[int, str]
) -> list[Triplet]:
    """The triplets of each snapshot's (clip id, verdict) answers, sorted. `clip_commands` maps every live
    clip of the household to its command: a snapshot is "nothing I said" only once every command has an
    *is not* answer."""
    all_commands = set(clip_commands.values())
    triplets = []
    for snapshot_id, pairs in answers.items():
        positives = [clip for clip, verdict in pairs if verdict == Verdict.IS]
        negatives = [clip for clip, verdict in pairs if verdict == Verdict.IS_NOT]
        if positives and negatives:
            triplets += [Triplet(snapshot_id, p, n) for p in positives for n in negatives]
        elif negatives and {clip_commands[c] for c in negatives} >= all_commands:
            triplets += [Triplet(snapshot_id, SILENCE_CLIP, n) for n in negatives]
    return sorted(triplets)
