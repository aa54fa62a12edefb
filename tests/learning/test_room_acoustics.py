"""Simulated rooms: the reverberation time asked for, noise at the SNR asked for, a microphone's band, one
recording per seed, and room copies of a corpus's clips in a VAR's sound bank."""

import dataclasses
from pathlib import Path

import numpy as np
import pyroomacoustics
import pytest

from learning.audio import PEAK_LEVEL, SAMPLE_RATE, decode_audio, features_from_waveform
from learning.room_acoustics import (
    RoomRanges,
    background_noise,
    microphone_band,
    record_in_room,
    room_impulse_response,
)
from learning.sounds import engines, load_corpus
from learning.sounds.build import build_corpora
from learning.var.dataset import SoundBank

ROOMS = RoomRanges()


def fixed(**ranges: tuple[float, float]) -> RoomRanges:
    return dataclasses.replace(ROOMS, **ranges)


@pytest.fixture(scope="module")
def spoken() -> np.ndarray:
    missing = engines.missing_packages({"espeak-ng"})
    assert not missing, f"Debian packages missing: {missing} (sudo bash scripts/install-system-packages.sh)"
    return decode_audio(engines.espeak("three", "m3", "en-us", 50, 160))[0]


@pytest.mark.parametrize("rt60_s", [0.3, 0.7])
def test_an_impulse_response_decays_at_the_reverberation_time_asked_for(rt60_s: float) -> None:
    measured = [
        pyroomacoustics.experimental.measure_rt60(
            room_impulse_response(np.random.default_rng(seed), fixed(rt60_s=(rt60_s, rt60_s))), fs=SAMPLE_RATE
        )
        for seed in range(4)
    ]
    assert np.median(measured) == pytest.approx(rt60_s, rel=0.3), measured


def test_background_noise_is_at_the_signal_to_noise_ratio_asked_for(spoken: np.ndarray) -> None:
    noise = background_noise(spoken, np.random.default_rng(0), fixed(snr_db=(10.0, 10.0)))
    audible = np.abs(spoken) > 1e-4 * np.abs(spoken).max()
    snr_db = 10 * np.log10((spoken[audible] ** 2).mean() / (noise**2).mean())
    assert snr_db == pytest.approx(10.0, abs=0.01)
    assert len(noise) == len(spoken)


def test_the_microphone_keeps_its_band_and_cuts_what_lies_outside(spoken: np.ndarray) -> None:
    white = np.random.default_rng(1).standard_normal(4 * SAMPLE_RATE)
    band = fixed(low_cut_hz=(300.0, 300.0), high_cut_hz=(3000.0, 3000.0))
    heard = microphone_band(white, np.random.default_rng(2), band)
    power = np.abs(np.fft.rfft(heard)) ** 2
    frequency = np.fft.rfftfreq(len(heard), 1 / SAMPLE_RATE)

    def level_db(low: float, high: float) -> float:
        return 10 * np.log10(power[(frequency >= low) & (frequency < high)].mean())

    inside = level_db(600, 2000)
    assert inside - level_db(6000, 8000) > 20
    assert inside - level_db(20, 80) > 15


def test_a_room_recording_is_one_per_seed_longer_and_still_a_command(spoken: np.ndarray) -> None:
    first = record_in_room(spoken, np.random.default_rng(5))
    np.testing.assert_array_equal(first, record_in_room(spoken, np.random.default_rng(5)))
    other = record_in_room(spoken, np.random.default_rng(6))
    assert not np.array_equal(first[: len(other)], other[: len(first)])
    assert first.dtype == np.float32 and len(first) > len(spoken)  # noise before, reverberation after
    assert np.abs(first).max() == pytest.approx(PEAK_LEVEL, rel=1e-5)
    features = features_from_waveform(first, "speech", "speech-embedding")
    assert (features != 0).any(axis=1).sum() >= 5  # heard frames, not silence


def test_room_copies_add_recordings_of_every_training_clip_to_the_bank(tmp_path: Path) -> None:
    build_corpora(["wordset"], profile="small", root=tmp_path, progress=False, log=lambda _: None)
    corpus = load_corpus("wordset", tmp_path)
    train = corpus.subset("train")
    plain = SoundBank.from_corpus(corpus)
    with_rooms = SoundBank.from_corpus(corpus, room_copies=2, seed=4)
    assert len(with_rooms.intent) == 3 * len(train.intent)
    np.testing.assert_array_equal(with_rooms.counts, 3 * plain.counts)
    again = SoundBank.from_corpus(corpus, room_copies=2, seed=4)
    np.testing.assert_array_equal(with_rooms.features, again.features)
    clean = {row.tobytes() for row in plain.features}
    copies = [row for row in with_rooms.features if row.tobytes() not in clean]
    assert len(copies) == 2 * len(train.intent)  # every copy differs from every clean clip
