"""Sound corpora: a small build in seconds, honest splits by speaker, determinism for a seed, caching."""

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from learning.audio import features_from_bytes
from learning.sounds import SET_NAMES, SOUND_SETS, load_corpus
from learning.sounds import engines as sound_engines
from learning.sounds.build import MANIFEST, build_corpora
from learning.sounds.cli import app
from learning.sounds.speakers import (
    HELD_OUT_ACCENTS,
    HELD_OUT_VARIANTS,
    SMALL,
    SOUNDFONT_HELD_OUT,
    TRAIN_ACCENTS,
    TRAIN_VARIANTS,
    instruments,
    speech_speakers,
)

MISSING = sound_engines.missing_packages(
    {"espeak-ng", "flite", "festival", "fluidsynth"},
    {"kal_diphone", "ked_diphone"},
    {"FluidR3_GM", "TimGM6mb"},
)


@pytest.fixture(scope="module")
def synthesizers() -> None:
    """A missing synthesizer fails the tests that need it, with what to install (never a silent skip)."""
    assert not MISSING, (
        f"Debian packages missing: {', '.join(MISSING)} (sudo bash scripts/install-system-packages.sh)"
    )


needs_synthesizers = pytest.mark.usefixtures("synthesizers")


def manifest(root: Path, name: str) -> list[dict]:
    return [json.loads(line) for line in (root / "sounds" / name / MANIFEST).read_text().splitlines()]


@pytest.fixture(scope="module")
def small_root(tmp_path_factory: pytest.TempPathFactory, synthesizers: None) -> Path:
    root = tmp_path_factory.mktemp("sounds-small")
    build_corpora(SET_NAMES, profile="small", seed=0, root=root, progress=False, log=lambda _: None)
    return root


def test_every_phrase_intent_has_at_least_five_wordings() -> None:
    for set_ in (SOUND_SETS["phrases_blocks"], SOUND_SETS["phrases_objects"]):
        assert len(set_.wordings) == 4
        assert all(len(set(wordings)) >= 5 for wordings in set_.wordings)


def test_speaker_plan_keeps_held_out_variants_and_accents_out_of_training() -> None:
    speakers = speech_speakers(SMALL, seed=3)
    for speaker in speakers:
        if speaker.engine != "espeak-ng":
            continue
        if speaker.split == "train":
            assert speaker.voice in TRAIN_VARIANTS and speaker.accent in TRAIN_ACCENTS
        else:
            assert speaker.split == "unheard-easy"
            assert speaker.voice in HELD_OUT_VARIANTS and speaker.accent in HELD_OUT_ACCENTS
    real = {s.id for s in speakers if s.split == "unheard-real-voices"}
    assert real <= {"flite:awb", "flite:rms", "festival:ked_diphone"}
    assert not set(TRAIN_VARIANTS) & set(HELD_OUT_VARIANTS)
    assert not set(TRAIN_ACCENTS) & set(HELD_OUT_ACCENTS)


def test_one_whole_soundfont_is_held_out_of_the_notes() -> None:
    for instrument in instruments(SMALL):
        assert (instrument.soundfont == SOUNDFONT_HELD_OUT) == (instrument.split == "unheard-soundfont")


@needs_synthesizers
def test_small_build_holds_every_set_intent_and_split(small_root: Path) -> None:
    for name in SET_NAMES:
        corpus = load_corpus(name, small_root)
        n = len(corpus)
        assert n > 0
        assert corpus.features.shape == (n, 100, 40) and corpus.features.dtype == np.float32
        assert corpus.intent.dtype == np.int64 and set(corpus.intent.tolist()) == {0, 1, 2, 3}
        assert corpus.speaker.shape == corpus.split.shape == (n,)
        expected = {
            "notes": {"train", "unheard-instrument", "unheard-soundfont"},
            "wordset-multilingual": {"train", "unheard-room"}
            | {f"unheard-{language.code}" for language in SOUND_SETS[name].languages},
        }.get(name, {"train", "unheard-easy", "unheard-real-voices"})
        assert set(corpus.splits) == expected
        assert len(corpus.intent_names) == 4
        assert not (np.abs(corpus.features).sum(axis=(1, 2)) == 0).any(), "a clip came out silent"


@needs_synthesizers
def test_manifest_has_no_speaker_in_two_splits(small_root: Path) -> None:
    for name in SET_NAMES:
        splits_of: dict[str, set[str]] = defaultdict(set)
        for record in manifest(small_root, name):
            splits_of[record["speaker"]].add(record["split"])
        shared = {speaker: splits for speaker, splits in splits_of.items() if len(splits) > 1}
        assert not shared, f"{name}: speakers in several splits: {shared}"


@needs_synthesizers
def test_manifest_describes_every_clip(small_root: Path) -> None:
    records = manifest(small_root, "wordset")
    for record in records:
        assert (small_root / "sounds" / "wordset" / record["clip"]).is_file()
        assert record["text"] == record["intent_name"]
        assert record["engine"] in {"espeak-ng", "flite", "festival"}
        assert record["variation"] and record["speaker_params"]["voice"]
    assert {r["engine"] for r in manifest(small_root, "notes")} == {"fluidsynth"}
    mix_engines = {r["engine"] for r in manifest(small_root, "mix")}
    assert "recording" in mix_engines and "espeak-ng" in mix_engines


@needs_synthesizers
def test_mix_commands_house_with_a_jackhammer_and_dog_with_barks(small_root: Path) -> None:
    recordings = [r for r in manifest(small_root, "mix") if r["engine"] == "recording"]
    by_intent = {r["intent_name"] for r in recordings if "jackhammer" in r["speaker"]}
    assert by_intent == {"house"}
    assert {r["intent_name"] for r in recordings if "dog_bark" in r["speaker"]} == {"dog"}
    assert {r["split"] for r in recordings} == {"train", "unheard-real-voices"}


@needs_synthesizers
def test_cached_features_are_what_an_upload_of_the_clip_gives(small_root: Path) -> None:
    for name in ("wordset", "phrases_objects", "notes", "mix"):
        corpus = load_corpus(name, small_root)
        for row in (0, len(corpus) // 2, len(corpus) - 1):
            data = Path(corpus.clip[row]).read_bytes()
            np.testing.assert_allclose(
                features_from_bytes(data, corpus.kind), corpus.features[row], atol=1e-3
            )


@needs_synthesizers
def test_subset_keeps_rows_aligned(small_root: Path) -> None:
    corpus = load_corpus("wordset", small_root)
    unheard = corpus.subset(["unheard-easy", "unheard-real-voices"])
    assert set(unheard.split.tolist()) == {"unheard-easy", "unheard-real-voices"}
    assert len(unheard) + len(corpus.subset("train")) == len(corpus)
    assert unheard.features.shape[0] == len(unheard.speaker) == len(unheard.clip)
    with pytest.raises(ValueError, match="has no split"):
        corpus.subset("unheard-soundfont")


@needs_synthesizers
def test_build_is_deterministic_for_a_seed(small_root: Path, tmp_path: Path) -> None:
    again = build_corpora(
        ["wordset"], profile="small", seed=0, root=tmp_path, progress=False, log=lambda _: None
    )
    assert not again[0].cached
    first, second = load_corpus("wordset", small_root), load_corpus("wordset", tmp_path)
    assert first.manifest_hash == second.manifest_hash
    np.testing.assert_array_equal(first.features, second.features)


@needs_synthesizers
def test_another_seed_gives_other_speakers(tmp_path: Path) -> None:
    build_corpora(["wordset"], profile="small", seed=1, root=tmp_path, progress=False, log=lambda _: None)
    seed0 = {s.id for s in speech_speakers(SMALL, 0)}
    assert set(load_corpus("wordset", tmp_path).speaker.tolist()) != seed0


@needs_synthesizers
def test_rebuild_with_the_same_parameters_does_nothing(small_root: Path) -> None:
    features = small_root / "sounds" / "notes" / "features.npy"
    before = features.stat().st_mtime_ns
    results = build_corpora(
        ["notes", "mix"], profile="small", seed=0, root=small_root, progress=False, log=lambda _: None
    )
    assert all(r.cached for r in results)
    assert features.stat().st_mtime_ns == before


@needs_synthesizers
def test_cli_builds_into_the_data_dir_and_then_is_up_to_date(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path))
    runner = CliRunner()
    first = runner.invoke(app, ["build", "--small", "--sets", "notes"])
    assert first.exit_code == 0, first.output
    assert "notes:" in first.output and (tmp_path / "sounds" / "notes" / MANIFEST).exists()
    second = runner.invoke(app, ["build", "--small", "--sets", "notes"])
    assert "up to date" in second.output
    shown = runner.invoke(app, ["info"])
    assert shown.exit_code == 0 and "notes" in shown.output and "not built" in shown.output


def test_unknown_set_is_refused_with_the_choices(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"Unknown sound set 'digits'.*wordset"):
        build_corpora(["digits"], profile="small", root=tmp_path, progress=False)


def test_missing_corpus_says_how_to_build_it(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="varbot sounds build --sets objects"):
        load_corpus("objects", tmp_path)


def test_missing_synthesizer_names_the_debian_package(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(sound_engines.shutil, "which", lambda _name: None)
    with pytest.raises(sound_engines.EngineMissingError, match=r"espeak-ng.*apt-get install"):
        build_corpora(["wordset"], profile="small", root=tmp_path, progress=False)
    assert not (tmp_path / "sounds" / "wordset").exists()


def test_missing_soundfont_names_the_debian_package(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(sound_engines, "SOUNDFONT_DIR", tmp_path / "no-soundfonts")
    with pytest.raises(sound_engines.EngineMissingError, match="fluid-soundfont-gm"):
        build_corpora(["notes"], profile="small", root=tmp_path, progress=False)


@needs_synthesizers
def test_festival_renders_a_batch_in_one_process() -> None:
    clips = sound_engines.festival_batch([("kal_diphone", "zero.", 1.0), ("kal_diphone", "three?", 1.2)])
    assert len(clips) == 2 and all(c[:4] == b"RIFF" for c in clips)
