"""The household's supervision rule (core.labels): which clips are one command, and which triplets pair labels
give. Nothing else is ever used as supervision."""

from hypothesis import given
from hypothesis import strategies as st

from core.labels import SILENCE_CLIP, Triplet, Verdict, command_key, derive_triplets

IS, IS_NOT = Verdict.IS, Verdict.IS_NOT


def test_recordings_with_one_name_are_one_command_whatever_the_case_and_spaces() -> None:
    assert command_key(1, "The red block") == command_key(2, "  the RED block ") == "name:the red block"
    assert command_key(1, "the red block") != command_key(3, "the blue block")


def test_a_clip_without_a_name_is_a_command_of_its_own() -> None:
    assert command_key(4, None) == "clip:4"
    assert command_key(5, "   ") == "clip:5", "a blank name is no name"
    assert command_key(4, None) != command_key(5, None)


def test_an_image_with_is_and_is_not_answers_gives_every_is_clip_against_every_is_not_clip() -> None:
    commands = {1: "name:left", 2: "name:right", 3: "name:up", 4: "name:left"}
    answers = {10: [(1, IS), (4, IS), (2, IS_NOT), (3, IS_NOT)]}
    assert derive_triplets(answers, commands) == [(10, 1, 2), (10, 1, 3), (10, 4, 2), (10, 4, 3)]


@given(positives=st.integers(0, 5), negatives=st.integers(0, 5))
def test_an_image_gives_is_times_is_not_triplets_while_it_has_an_is_answer(
    positives: int, negatives: int
) -> None:
    clips = range(1, positives + negatives + 1)
    commands = {clip: f"clip:{clip}" for clip in [*clips, 99]}  # clip 99 is never asked about this image
    answers = {7: [(clip, IS if clip <= positives else IS_NOT) for clip in clips]}
    triplets = derive_triplets(answers, commands)
    assert len(triplets) == (positives * negatives if positives else 0)
    assert all(not triplet.silent for triplet in triplets)


def test_an_image_answered_is_not_for_every_command_gives_silence_against_each_clip() -> None:
    commands = {1: "name:left", 2: "name:right", 3: "name:right"}
    answers = {11: [(1, IS_NOT), (2, IS_NOT)]}  # clip 3 is "right" too: every command has its "is not"
    triplets = derive_triplets(answers, commands)
    assert triplets == [(11, SILENCE_CLIP, 1), (11, SILENCE_CLIP, 2)]
    assert all(triplet.silent for triplet in triplets)


def test_an_image_not_yet_answered_for_every_command_gives_nothing() -> None:
    commands = {1: "name:left", 2: "name:right"}
    assert derive_triplets({12: [(1, IS_NOT)]}, commands) == []


def test_an_image_with_only_is_answers_gives_nothing() -> None:
    commands = {1: "name:left", 2: "name:right"}
    assert derive_triplets({13: [(1, IS), (2, IS)]}, commands) == []


def test_triplets_come_sorted_by_image_then_clips_as_named_tuples() -> None:
    commands = {1: "name:left", 2: "name:right"}
    answers = {21: [(2, IS), (1, IS_NOT)], 20: [(1, IS_NOT), (2, IS_NOT)]}
    triplets = derive_triplets(answers, commands)
    assert triplets == [(20, SILENCE_CLIP, 1), (20, SILENCE_CLIP, 2), (21, 2, 1)]
    assert triplets[-1] == Triplet(snapshot_id=21, positive_clip_id=2, negative_clip_id=1)


def test_verdicts_compare_equal_to_the_strings_the_database_stores() -> None:
    assert derive_triplets({30: [(1, "is"), (2, "is_not")]}, {1: "clip:1", 2: "clip:2"}) == [(30, 1, 2)]
