"""Training-time augmentation: batched, seeded, shape- and dtype-preserving, silence stays silence."""

import math

import numpy as np
import pytest
import torch
import torchaudio

from learning.audio import SILENCE
from learning.augment import (
    EmbeddingAugment,
    FeatureAugment,
    WaveAugment,
    add_noise,
    augment_embeddings,
    augment_features,
    augment_waveforms,
    perturb_speed,
    shift_time,
    spec_augment,
    warp_vocal_tract,
)


def generator(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def tones(batch: int = 6, length: int = 16_000) -> torch.Tensor:
    t = torch.arange(length) / 16_000
    pitches = torch.linspace(150, 400, batch)[:, None]
    return 0.5 * torch.sin(2 * torch.pi * pitches * t[None, :])


def mfcc_batch(batch: int = 6) -> torch.Tensor:
    features = torch.randn(batch, 100, 40, generator=generator(7)) * 5
    features[:, 60:] = 0  # the sound ends after 60 frames
    features[0] = torch.from_numpy(SILENCE.copy())
    return features


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_waveform_augmentation_keeps_shape_and_dtype(dtype: torch.dtype) -> None:
    waves = tones().to(dtype)
    augmented = augment_waveforms(waves, generator(), WaveAugment())
    assert augmented.shape == waves.shape and augmented.dtype == dtype
    assert torch.isfinite(augmented).all()
    assert not torch.equal(augmented, waves)


def test_feature_augmentation_keeps_shape_dtype_and_silence() -> None:
    features = mfcc_batch()
    augmented = augment_features(features, generator(), FeatureAugment())
    assert augmented.shape == (6, 100, 40) and augmented.dtype == torch.float32
    assert not augmented[0].any(), "the no-sound matrix must stay all zero"
    assert not augmented[:, 70:].any(), "frames after the sound must stay silent (shift is at most 8 frames)"


def test_augmentation_is_reproducible_for_a_seed_and_varies_across_seeds() -> None:
    waves, features = tones(), mfcc_batch()
    assert torch.equal(augment_waveforms(waves, generator(3)), augment_waveforms(waves, generator(3)))
    assert not torch.equal(augment_waveforms(waves, generator(3)), augment_waveforms(waves, generator(4)))
    assert torch.equal(augment_features(features, generator(3)), augment_features(features, generator(3)))


def test_each_row_gets_its_own_random_draw() -> None:
    same = tones(batch=1).repeat(8, 1)
    augmented = augment_waveforms(same, generator())
    assert len({round(float(row.abs().sum()), 3) for row in augmented}) == 8


def test_speed_one_is_the_identity_and_faster_speech_ends_earlier() -> None:
    waves = tones()
    torch.testing.assert_close(perturb_speed(waves, generator(), (1.0, 1.0)), waves)
    faster = perturb_speed(waves, generator(), (1.25, 1.25))
    assert not faster[:, -3000:].any()  # 1 s played 1.25× faster lasts 0.8 s
    spectrum = torch.fft.rfft(faster[-1, :12_000]).abs()
    assert int(spectrum.argmax()) * 16_000 / 12_000 == pytest.approx(400 * 1.25, abs=3)


def vowel(formants_hz: tuple[float, ...], pitch_hz: float = 120.0) -> torch.Tensor:
    """One second of a pulse train at `pitch_hz` through a two-pole resonance at each formant."""
    pulses = torch.zeros(16_000, dtype=torch.float64)
    pulses[:: round(16_000 / pitch_hz)] = 1.0
    sound = pulses
    for formant in formants_hz:
        radius = math.exp(-math.pi * 100 / 16_000)
        angle = 2 * math.pi * formant / 16_000
        b = torch.tensor([1 - radius, 0.0, 0.0], dtype=torch.float64)
        a = torch.tensor([1.0, -2 * radius * math.cos(angle), radius**2], dtype=torch.float64)
        sound = torchaudio.functional.lfilter(sound, a, b, clamp=False)
    return (sound / sound.abs().max()).float()[None]


def formant_peaks(wave: torch.Tensor) -> tuple[float, float]:
    """The smoothed spectrum's peak below and above 1.2 kHz, in Hz."""
    spectrum = torch.fft.rfft(wave[0, 4_000:12_000] * torch.hann_window(8_000)).abs()
    smooth = torch.nn.functional.avg_pool1d(spectrum[None, None], 151, 1, 75)[0, 0]
    hz_per_bin = 16_000 / 8_000
    split = int(1_200 / hz_per_bin)
    return float(smooth[:split].argmax()) * hz_per_bin, (
        split + float(smooth[split:1_500].argmax())
    ) * hz_per_bin


def pitch_hz(wave: torch.Tensor) -> float:
    frame = wave[0, 4_000:6_000]
    correlation = torch.stack([(frame[:-lag] * frame[lag:]).sum() for lag in range(60, 400)])
    return 16_000 / (60 + int(correlation.argmax()))


def test_a_vocal_tract_warp_moves_the_formants_and_keeps_the_pitch() -> None:
    """A vowel with formants at 700 and 1,800 Hz and a 120 Hz pitch: warped by 1.2 its formants move up by
    about a fifth, warped by 0.85 down, and its pitch stays; a warp of 1 gives the sound back."""
    sound = vowel((700.0, 1_800.0))
    torch.testing.assert_close(warp_vocal_tract(sound, generator(), (1.0, 1.0)), sound, atol=1e-5, rtol=0)
    first, second = formant_peaks(sound)
    for factor in (1.2, 0.85):
        warped = warp_vocal_tract(sound, generator(), (factor, factor))
        moved_first, moved_second = formant_peaks(warped)
        assert moved_first == pytest.approx(first * factor, rel=0.06)
        assert moved_second == pytest.approx(second * factor, rel=0.06)
        assert pitch_hz(warped) == pytest.approx(pitch_hz(sound), rel=0.02)


def test_time_shift_moves_the_sound_and_fills_with_zeros() -> None:
    waves = torch.zeros(4, 1_000)
    waves[:, 500] = 1.0
    shifted = shift_time(waves, generator(), max_shift=100)
    positions = shifted.argmax(dim=1)
    assert ((positions >= 400) & (positions <= 600)).all()
    assert torch.equal(shifted.sum(dim=1), torch.ones(4))


@pytest.mark.parametrize("snr_db", [0.0, 10.0, 30.0])
def test_noise_is_added_at_the_requested_snr(snr_db: float) -> None:
    waves = tones(batch=4)
    noisy = add_noise(waves, generator(), (snr_db, snr_db), probability=1.0)
    noise = noisy - waves
    audible = waves.abs() > 1e-4  # signal power is measured where there is signal
    signal_power = (waves**2).sum(dim=1) / audible.sum(dim=1)
    measured = 10 * torch.log10(signal_power / (noise**2).mean(dim=1))
    torch.testing.assert_close(measured, torch.full((4,), snr_db), atol=0.2, rtol=0)


def test_noise_can_come_from_a_bank_of_recordings() -> None:
    bank = torch.randn(3, 5_000, generator=generator(1))
    noisy = add_noise(tones(batch=2), generator(), (20.0, 20.0), noise_bank=bank)
    assert noisy.shape == (2, 16_000)


def test_spec_augment_zeroes_whole_bands() -> None:
    features = torch.ones(16, 100, 40)
    masked = spec_augment(features, generator(), time_masks=1, time_mask_frames=10, coefficient_masks=1,
                          coefficient_mask_width=5)  # fmt: skip
    zero_frames = (masked == 0).all(dim=2).sum(dim=1)
    zero_coefficients = (masked == 0).all(dim=1).sum(dim=1)
    assert (zero_frames <= 10).all() and (zero_coefficients <= 5).all()
    assert zero_frames.sum() > 0 and zero_coefficients.sum() > 0
    assert torch.isin(masked, torch.tensor([0.0, 1.0])).all()


def test_feature_gain_moves_only_the_energy_coefficient() -> None:
    features = mfcc_batch()
    config = FeatureAugment(gain_db=(6.0, 6.0), shift_frames=0, time_masks=0, coefficient_masks=0)
    augmented = augment_features(features, generator(), config)
    torch.testing.assert_close(augmented[1:, :60, 1:], features[1:, :60, 1:])
    shift = augmented[1:, :60, 0] - features[1:, :60, 0]
    np.testing.assert_allclose(shift.numpy(), 6 * np.log(10) / 10 * np.sqrt(40), rtol=1e-4)


def embedding_batch(batch: int = 64, frames: int = 11, heard: int = 6) -> torch.Tensor:
    features = torch.zeros(batch, frames, 96)
    features[:, :heard] = torch.randn(batch, heard, 96, generator=generator(5)) * 4 + 2
    features[0] = 0  # silence
    return features


def test_embedding_augmentation_drops_heard_frames_adds_noise_and_keeps_silence() -> None:
    features = embedding_batch()
    augmented = augment_embeddings(features, generator(), EmbeddingAugment(frame_drop=0.25, noise=0.3))
    assert augmented.shape == features.shape and augmented.dtype == features.dtype
    heard_before, heard_after = (features != 0).any(dim=2), (augmented != 0).any(dim=2)
    assert not augmented[0].any() and not heard_after[:, 6:].any()  # silence and padding stay zero
    assert (heard_after <= heard_before).all() and heard_after[1:].any(dim=1).all()  # a clip keeps a frame
    assert 0.15 < 1 - heard_after[1:].sum() / heard_before[1:].sum() < 0.35
    kept = heard_after & heard_before
    noise = (augmented - features)[kept] / features[heard_before].std(dim=0)
    assert 0.25 < float(noise.std()) < 0.35


def test_embedding_augmentation_never_empties_a_clip_of_one_frame() -> None:
    features = embedding_batch(heard=1)
    augmented = augment_embeddings(features, generator(), EmbeddingAugment(frame_drop=0.9, noise=0.0))
    torch.testing.assert_close(augmented, features)
