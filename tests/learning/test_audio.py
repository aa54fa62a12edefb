"""The audio front end: bytes of any common recording → the reference's 100 × 40 MFCC, or a clear refusal."""

import io

import numpy as np
import pytest
import soundfile

from learning.audio import (
    FEATURE_KINDS,
    MAX_DURATION_S,
    SILENCE,
    AudioError,
    decode_audio,
    features_from_bytes,
    features_from_waveform,
)


def word_like(rate: int = 16_000, seconds: float = 0.6, channels: int = 1, level: float = 0.5) -> np.ndarray:
    """A voiced, word-length sound: harmonics of a gliding pitch under a syllable envelope."""
    t = np.arange(int(rate * seconds)) / rate
    pitch = 140 + 60 * t / seconds
    phase = 2 * np.pi * np.cumsum(pitch) / rate
    voice = sum(np.sin(k * phase) / k for k in range(1, 12))
    envelope = np.sin(np.pi * t / seconds) ** 2
    mono = (level * envelope * voice / np.abs(voice).max()).astype(np.float32)
    return mono if channels == 1 else np.stack([mono] * channels, axis=1)


def wav_bytes(samples: np.ndarray, rate: int = 16_000, fmt: str = "WAV", subtype: str = "PCM_16") -> bytes:
    buffer = io.BytesIO()
    soundfile.write(buffer, samples, rate, format=fmt, subtype=subtype)
    return buffer.getvalue()


def voiced_frames(features: np.ndarray) -> int:
    return int((np.abs(features).sum(axis=1) > 0).sum())


@pytest.mark.parametrize("kind", sorted(FEATURE_KINDS))
def test_features_are_100_by_40_float32_for_every_kind(kind: str) -> None:
    features = features_from_bytes(wav_bytes(word_like()), kind=kind)
    assert features.shape == (100, 40)
    assert features.dtype == np.float32
    assert np.isfinite(features).all()
    assert voiced_frames(features) > 0


def test_speech_frames_follow_the_reference_hop_of_10_ms() -> None:
    features = features_from_bytes(wav_bytes(word_like(seconds=0.6)))
    # ~0.6 s of sound after trimming: about 60 frames of 10 ms, then all-zero frames ("no sound")
    assert 45 <= voiced_frames(features) <= 65
    assert (features[70:] == 0).all()


def test_long_sound_is_cut_to_the_100_frames_its_kind_covers() -> None:
    features = features_from_bytes(wav_bytes(word_like(seconds=2.5)), kind="speech")
    assert voiced_frames(features) == 100


def test_silence_is_the_all_zero_matrix() -> None:
    assert SILENCE.shape == (100, 40) and SILENCE.dtype == np.float32
    assert not SILENCE.any()
    with pytest.raises(ValueError):
        SILENCE[0, 0] = 1.0  # shared constant: read-only
    np.testing.assert_array_equal(features_from_waveform(np.zeros(16_000, np.float32)), SILENCE)
    assert features_from_waveform(np.zeros(0, np.float32)).shape == (100, 40)


def test_silent_recording_is_rejected_with_advice() -> None:
    with pytest.raises(AudioError, match=r"silent.*microphone"):
        features_from_bytes(wav_bytes(np.zeros(16_000, np.float32)))


@pytest.mark.parametrize("rate", [8_000, 22_050, 44_100, 48_000])
def test_common_sample_rates_are_resampled_to_16k(rate: int) -> None:
    tone = (0.5 * np.sin(2 * np.pi * 440 * np.arange(rate) / rate)).astype(np.float32)
    waveform, duration = decode_audio(wav_bytes(tone, rate))
    assert waveform.dtype == np.float32
    assert duration == pytest.approx(1.0)
    assert len(waveform) == pytest.approx(16_000, abs=2)
    spectrum = np.abs(np.fft.rfft(waveform))
    assert np.argmax(spectrum) * 16_000 / len(waveform) == pytest.approx(440, abs=2)


@pytest.mark.parametrize("rate", [8_000, 22_050, 44_100, 48_000])
def test_features_barely_depend_on_the_source_rate(rate: int) -> None:
    reference = features_from_bytes(wav_bytes(word_like(16_000)))
    other = features_from_bytes(wav_bytes(word_like(rate), rate))
    frames = min(voiced_frames(reference), voiced_frames(other))
    # 8 kHz audio has nothing above 4 kHz, so compare the low cepstrum's shape over time
    correlation = np.corrcoef(reference[:frames, 1:13].ravel(), other[:frames, 1:13].ravel())[0, 1]
    assert correlation > 0.9


def test_stereo_is_mixed_to_mono() -> None:
    stereo = word_like(channels=2)
    np.testing.assert_allclose(
        features_from_bytes(wav_bytes(stereo)), features_from_bytes(wav_bytes(stereo[:, 0])), atol=1e-3
    )
    left_only = stereo.copy()
    left_only[:, 1] = 0
    waveform, _ = decode_audio(wav_bytes(left_only, subtype="FLOAT"))
    np.testing.assert_allclose(waveform, stereo[:, 0] / 2, atol=1e-6)


def test_leading_silence_and_level_do_not_change_the_features() -> None:
    word = word_like()
    padded_quiet = np.concatenate([np.zeros(8_000, np.float32), 0.1 * word, np.zeros(4_000, np.float32)])
    np.testing.assert_allclose(
        features_from_bytes(wav_bytes(padded_quiet, subtype="FLOAT")),
        features_from_bytes(wav_bytes(word, subtype="FLOAT")),
        atol=0.05,
    )


@pytest.mark.parametrize("fmt", ["FLAC", "OGG"])
def test_compressed_formats_decode(fmt: str) -> None:
    subtype = "VORBIS" if fmt == "OGG" else "PCM_16"
    features = features_from_bytes(wav_bytes(word_like(), fmt=fmt, subtype=subtype))
    assert voiced_frames(features) > 40


@pytest.mark.parametrize(
    "data",
    [b"this is not audio", bytes(range(256)) * 8, wav_bytes(word_like())[:30]],
    ids=["text", "noise-bytes", "truncated-header"],
)
def test_undecodable_bytes_are_rejected_with_what_to_send(data: bytes) -> None:
    with pytest.raises(AudioError, match=r"Could not decode the audio.*WAV"):
        features_from_bytes(data)


def test_empty_bytes_are_rejected() -> None:
    with pytest.raises(AudioError, match=r"empty \(0 bytes\)"):
        decode_audio(b"")


def test_not_bytes_is_rejected() -> None:
    with pytest.raises(AudioError, match="Expected the bytes"):
        decode_audio("hello.wav")  # type: ignore[arg-type]


def test_too_short_audio_is_rejected() -> None:
    with pytest.raises(AudioError, match="too short"):
        decode_audio(wav_bytes(word_like(seconds=0.02)))


def test_too_long_audio_is_rejected_before_decoding_all_of_it() -> None:
    rate = 4_000
    long_tone = (0.3 * np.sin(np.arange(int(rate * (MAX_DURATION_S + 1))) * 0.3)).astype(np.float32)
    with pytest.raises(AudioError, match=r"too long \(more than 30 s\)"):
        decode_audio(wav_bytes(long_tone, rate))


def test_absurd_sample_rate_is_rejected() -> None:
    with pytest.raises(AudioError, match="sample rate"):
        decode_audio(wav_bytes(word_like(1_000, seconds=0.5), 1_000))


def test_audio_error_is_a_value_error() -> None:
    assert issubclass(AudioError, ValueError)


def test_unknown_kind_is_refused() -> None:
    with pytest.raises(ValueError, match="Unknown feature kind 'music'"):
        features_from_bytes(wav_bytes(word_like()), kind="music")
