"""The multilingual Wordset: the same four intents in six languages, unheard speakers per language and in
simulated rooms, and nothing of the language or the words in what a VAR reads."""

import dataclasses
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from learning.sounds import SoundCorpus, build, engines, load_corpus
from learning.sounds.build import MANIFEST, build_corpora
from learning.sounds.sets import SOUND_SETS
from learning.sounds.speakers import (
    HELD_OUT_ACCENTS,
    HELD_OUT_VARIANTS,
    MULTILINGUAL_SIZES,
    TRAIN_ACCENTS,
    TRAIN_VARIANTS,
    MixedVoices,
    mixed_variant,
)
from learning.var.dataset import SoundBank

NAME = "wordset-multilingual"
SET = SOUND_SETS[NAME]


@pytest.fixture(scope="module")
def small_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    missing = engines.missing_packages({"espeak-ng"})
    assert not missing, f"Debian packages missing: {missing} (sudo bash scripts/install-system-packages.sh)"
    root = tmp_path_factory.mktemp("multilingual")
    build_corpora([NAME], profile="small", root=root, progress=False, log=lambda _: None)
    return root


def records(root: Path) -> list[dict]:
    return [json.loads(line) for line in (root / "sounds" / NAME / MANIFEST).read_text().splitlines()]


def test_every_espeak_ng_accent_the_corpora_use_takes_the_speakers_voice_variant() -> None:
    """An accent espeak-ng cannot resolve to one voice file drops the "+variant" silently ("fr-fr" did): all
    of that accent's speakers then share one voice."""
    accents = {*TRAIN_ACCENTS, *HELD_OUT_ACCENTS}
    for language in SET.languages:
        accents |= {*language.train_accents, *language.held_out_accents}
    for accent in sorted(accents):
        voices = {engines.espeak("deux", variant, accent, 50, 160) for variant in ("m1", "f2", "klatt")}
        assert len(voices) == 3, f"espeak-ng ignores the voice variant of accent {accent!r}"


def test_at_least_five_languages_each_with_a_word_for_every_intent() -> None:
    assert len(SET.languages) >= 5
    assert {"en", "de", "es", "fr", "cmn"} <= {language.code for language in SET.languages}
    for language in SET.languages:
        assert len(language.words) == len(SET.intent_names) == 4
        assert len(set(language.words)) == 4, language


def test_every_language_has_its_own_unheard_speakers_and_every_tier_every_intent(small_root: Path) -> None:
    corpus = load_corpus(NAME, small_root)
    codes = [language.code for language in SET.languages]
    assert set(corpus.splits) == {"train", "unheard-room", *(f"unheard-{code}" for code in codes)}
    for split in corpus.splits:
        assert set(corpus.subset(split).intent.tolist()) == {0, 1, 2, 3}, split
    by_language = defaultdict(set)
    for record in records(small_root):
        by_language[record["language"]].add(record["split"])
        language = next(language for language in SET.languages if language.code == record["language"])
        assert record["text"].rstrip(".!?") == language.words[record["intent"]]
        params = record["speaker_params"]
        if "variant_text" in params:
            assert record["split"] == "train", "mixed voices are for training only"
        else:
            variants = TRAIN_VARIANTS if record["split"] == "train" else HELD_OUT_VARIANTS
            assert params["voice"] in variants
        assert ("room" in record["variation"]) == (record["split"] == "unheard-room")
    assert by_language == {code: {"train", f"unheard-{code}", "unheard-room"} for code in codes}
    assert not (np.abs(corpus.features).sum(axis=(1, 2)) == 0).any(), "a clip came out silent"


def test_the_same_seed_builds_the_same_clips(small_root: Path, tmp_path: Path) -> None:
    build_corpora([NAME], profile="small", root=tmp_path, progress=False, log=lambda _: None)
    assert records(tmp_path) == records(small_root)
    np.testing.assert_array_equal(
        load_corpus(NAME, tmp_path).features, load_corpus(NAME, small_root).features
    )


def test_more_training_speakers_leave_the_unheard_speakers_and_their_clips_as_they_were(monkeypatch) -> None:
    def planned_unheard(train_speakers: int) -> list[tuple]:
        sizes = {"default": dataclasses.replace(MULTILINGUAL_SIZES["default"], train=train_speakers)}
        monkeypatch.setattr(build, "MULTILINGUAL_SIZES", sizes)
        plans = build._plan(SET, build.PROFILES["default"], seed=0)
        return [(p.clip, p.speaker, p.text, p.variation) for p in plans if p.speaker.split != "train"]

    assert planned_unheard(16) == planned_unheard(32)


def test_a_corpus_is_built_again_when_its_mixed_voices_change(small_root: Path, monkeypatch) -> None:
    def logged_build() -> list[str]:
        lines: list[str] = []
        build_corpora([NAME], profile="small", root=small_root, progress=False, log=lines.append)
        return lines

    assert any("up to date" in line for line in logged_build())
    small = MULTILINGUAL_SIZES["small"]
    width = small.mixed_voices.width
    wider = dataclasses.replace(small.mixed_voices, width=(width[0] + 1, width[1]))
    sizes = {**MULTILINGUAL_SIZES, "small": dataclasses.replace(small, mixed_voices=wider)}
    monkeypatch.setattr(build, "MULTILINGUAL_SIZES", sizes)
    recipe = build._recipe(SET, build.PROFILES["small"], 0, small_root / "sounds")
    assert not build._is_cached(small_root / "sounds" / NAME, recipe)


def test_every_language_trains_with_mixed_voices_that_sound_unlike_any_named_variant(
    small_root: Path,
) -> None:
    mixed = [r for r in records(small_root) if "variant_text" in r["speaker_params"]]
    assert {r["language"] for r in mixed} == {language.code for language in SET.languages}
    rng = np.random.default_rng(0)
    ranges = MixedVoices()
    texts = [mixed_variant(rng, f"mix{index:02d}", ranges) for index in range(3)]
    assert len(set(texts)) == 3
    for text in texts:
        formants = [line for line in text.splitlines() if line.startswith("formant")]
        assert len(formants) == len(ranges.formants)
        for line in formants:
            _, formant, frequency, strength, width = line.split()
            assert int(formant) in ranges.formants
            assert ranges.frequency[0] <= int(frequency) <= ranges.frequency[1]
            assert ranges.strength[0] <= int(strength) <= ranges.strength[1]
            assert ranges.width[0] <= int(width) <= ranges.width[1]
    named = {
        engines.espeak("deux", variant, "fr", 50, 160) for variant in (*TRAIN_VARIANTS, *HELD_OUT_VARIANTS)
    }
    heard = [engines.espeak("deux", "mix", "fr", 50, 160, variant_text=text) for text in texts]
    assert len(set(heard)) == 3 and not set(heard) & named
    assert heard[0] == engines.espeak("deux", "mix", "fr", 50, 160, variant_text=texts[0]), "not repeatable"


def test_no_language_or_transcript_reaches_the_var(small_root: Path) -> None:
    fields = {field.name for field in dataclasses.fields(SoundCorpus)}
    assert not fields & {"language", "text", "transcript", "intent_name"}
    corpus = load_corpus(NAME, small_root)
    bank = SoundBank.from_corpus(corpus)  # what triplets are drawn from: features and intents only
    assert {field.name for field in dataclasses.fields(bank)} == {"features", "intent", "starts", "counts"}
    assert len(bank.intent) == len(corpus.subset("train").intent)
