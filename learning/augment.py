"""Training-time augmentation, batched on tensors and driven by one seeded `torch.Generator`.

Waveforms (B, T) at 16 kHz: speed perturbation (tempo and pitch together, as `sox speed`), vocal tract
length warping (the spectral envelope's formants moved, pitch and tempo kept), time shift, background noise
at a random SNR, gain. Features (B, 100, 40) MFCC: gain, frame shift and SpecAugment masks.
Frozen embedding frames (B, frames, values) of the speech-embedding front end: frame dropout and noise.
Every function returns a new tensor of the input's shape and dtype; all-zero MFCC frames ("no sound")
stay zero.
"""

import math
from dataclasses import dataclass

import torch

from learning.audio import NUM_COEFFICIENTS, SAMPLE_RATE


@dataclass(frozen=True)
class WaveAugment:
    speed: tuple[float, float] = (0.9, 1.1)
    shift_s: float = 0.1
    noise_probability: float = 0.5
    snr_db: tuple[float, float] = (5.0, 30.0)
    noise_colour: tuple[float, float] = (
        0.0,
        2.0,
    )  # spectral slope α of 1/f^α noise: 0 white, 1 pink, 2 brown
    gain_db: tuple[float, float] = (-6.0, 6.0)


@dataclass(frozen=True)
class FeatureAugment:
    gain_db: tuple[float, float] = (-3.0, 3.0)
    shift_frames: int = 8
    time_masks: int = 2
    time_mask_frames: int = 10
    coefficient_masks: int = 2
    coefficient_mask_width: int = 5


def augment_waveforms(
    waves: torch.Tensor,
    generator: torch.Generator,
    config: WaveAugment = WaveAugment(),
    noise_bank: torch.Tensor | None = None,
) -> torch.Tensor:
    """Augment a batch (B, T) of 16 kHz waveforms. `noise_bank` (K, T') of background recordings, when
    given, is mixed in instead of synthetic coloured noise."""
    waves = perturb_speed(waves, generator, config.speed)
    waves = shift_time(waves, generator, round(config.shift_s * SAMPLE_RATE))
    waves = add_noise(
        waves, generator, config.snr_db, config.noise_probability, config.noise_colour, noise_bank
    )
    return apply_gain(waves, generator, config.gain_db)


def augment_features(
    features: torch.Tensor, generator: torch.Generator, config: FeatureAugment = FeatureAugment()
) -> torch.Tensor:
    """Augment a batch (B, frames, coefficients) of MFCC matrices."""
    silent = (features == 0).all(dim=2, keepdim=True)
    features = _shift_c0(features, generator, config.gain_db).masked_fill(silent, 0.0)
    features = shift_frames(features, generator, config.shift_frames)
    return spec_augment(
        features,
        generator,
        config.time_masks,
        config.time_mask_frames,
        config.coefficient_masks,
        config.coefficient_mask_width,
    )


@dataclass(frozen=True)
class EmbeddingAugment:
    frame_drop: float = 0.25  # each heard frame left out of the clip with this probability
    noise: float = 0.3  # Gaussian noise, in units of each value's spread over the batch's heard frames


def augment_embeddings(
    features: torch.Tensor, generator: torch.Generator, config: EmbeddingAugment = EmbeddingAugment()
) -> torch.Tensor:
    """Augment a batch (B, frames, values) of frozen embedding frames: drop heard frames (a clip keeps at
    least one) and add noise to the rest. All-zero frames ("no sound") stay zero."""
    heard = (features != 0).any(dim=2)
    drop = torch.rand(heard.shape, generator=generator, device=features.device) < config.frame_drop
    kept = heard & ~drop
    kept = torch.where(kept.any(dim=1, keepdim=True), kept, heard)  # never drop a whole clip
    spread = features[heard].std(dim=0) if heard.sum() > 1 else torch.ones(features.shape[2])
    noise = torch.randn(features.shape, generator=generator, device=features.device) * spread * config.noise
    return (features + noise) * kept[:, :, None].to(features.dtype)


def perturb_speed(
    waves: torch.Tensor, generator: torch.Generator, speed: tuple[float, float]
) -> torch.Tensor:
    """Play each row `factor` times faster (linear interpolation); the length T stays, the tail is zero."""
    batch, length = waves.shape
    factors = _uniform(generator, batch, speed, waves)
    positions = torch.arange(length, device=waves.device, dtype=waves.dtype)[None, :] * factors[:, None]
    return _sample_at(waves, positions)


def warp_vocal_tract(
    waves: torch.Tensor, generator: torch.Generator, warp: tuple[float, float], n_fft: int = 512
) -> torch.Tensor:
    """Move each row's formants by a factor drawn from `warp` (above 1: a shorter vocal tract), keeping its
    pitch and timing: the spectral envelope (low-quefrency cepstrum of each STFT frame) is stretched along
    frequency; the harmonics (the rest of the log spectrum) and the phases stay where they were."""
    batch, length = waves.shape
    factors = _uniform(generator, batch, warp, waves)
    window = torch.hann_window(n_fft, device=waves.device, dtype=waves.dtype)
    spectrum = torch.stft(waves, n_fft, n_fft // 4, window=window, return_complex=True)  # (B, F, frames)
    log_magnitude = torch.log(spectrum.abs() + 1e-7)
    envelope = _spectral_envelope(log_magnitude, n_fft)
    bins = spectrum.shape[1]
    source_bins = torch.arange(bins, device=waves.device, dtype=waves.dtype)[None, :] / factors[:, None]
    warped = _interpolate_bins(envelope, source_bins.clamp(max=bins - 1))
    magnitude = torch.exp(warped + log_magnitude - envelope)
    warped_spectrum = torch.polar(magnitude, spectrum.angle())
    return torch.istft(warped_spectrum, n_fft, n_fft // 4, window=window, length=length)


def _spectral_envelope(log_magnitude: torch.Tensor, n_fft: int, lifter: int = 30) -> torch.Tensor:
    """The smooth part of each frame's log spectrum (B, F, frames): its first `lifter` cepstral terms."""
    cepstrum = torch.fft.irfft(log_magnitude, n=n_fft, dim=1)
    cepstrum[:, lifter : n_fft - lifter + 1] = 0
    return torch.fft.rfft(cepstrum, dim=1).real


def _interpolate_bins(values: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """values (B, F, frames) read at fractional bins `positions` (B, F), linearly."""
    left = positions.floor().long()
    right = (left + 1).clamp(max=values.shape[1] - 1)
    fraction = (positions - left.to(positions.dtype))[:, :, None]
    frames = values.shape[2]
    low = torch.gather(values, 1, left[:, :, None].expand(-1, -1, frames))
    high = torch.gather(values, 1, right[:, :, None].expand(-1, -1, frames))
    return low + (high - low) * fraction


def shift_time(waves: torch.Tensor, generator: torch.Generator, max_shift: int) -> torch.Tensor:
    """Delay (or advance) each row by up to `max_shift` samples, filling with zeros."""
    batch, length = waves.shape
    shifts = _integers(generator, batch, -max_shift, max_shift, waves.device)
    positions = torch.arange(length, device=waves.device)[None, :] - shifts[:, None]
    return _take(waves, positions)


def add_noise(
    waves: torch.Tensor,
    generator: torch.Generator,
    snr_db: tuple[float, float],
    probability: float = 1.0,
    colour: tuple[float, float] = (0.0, 2.0),
    noise_bank: torch.Tensor | None = None,
) -> torch.Tensor:
    """Add background noise at a random signal-to-noise ratio to a random `probability` share of the rows."""
    batch, length = waves.shape
    if noise_bank is None:
        noise = _coloured_noise(generator, batch, length, colour, waves)
    else:
        noise = _noise_from_bank(generator, noise_bank.to(waves), batch, length)
    audible = waves.abs() > 1e-4
    signal_power = (waves**2).sum(dim=1) / audible.sum(dim=1).clamp(min=1)
    noise_power = (noise**2).mean(dim=1).clamp(min=1e-12)
    snr = _uniform(generator, batch, snr_db, waves)
    scale = torch.sqrt(signal_power / (noise_power * 10 ** (snr / 10)))
    chosen = torch.rand(batch, generator=generator, device=waves.device) < probability
    return waves + noise * (scale * chosen.to(waves.dtype))[:, None]


def apply_gain(waves: torch.Tensor, generator: torch.Generator, gain_db: tuple[float, float]) -> torch.Tensor:
    gains = 10 ** (_uniform(generator, waves.shape[0], gain_db, waves) / 20)
    return waves * gains[:, None]


def shift_frames(features: torch.Tensor, generator: torch.Generator, max_shift: int) -> torch.Tensor:
    """Move each MFCC matrix by up to `max_shift` frames along time, filling with silent (zero) frames."""
    batch, frames, _ = features.shape
    shifts = _integers(generator, batch, -max_shift, max_shift, features.device)
    source = torch.arange(frames, device=features.device)[None, :] - shifts[:, None]
    inside = (source >= 0) & (source < frames)
    gathered = torch.gather(features, 1, source.clamp(0, frames - 1)[:, :, None].expand_as(features))
    return gathered * inside[:, :, None].to(features.dtype)


def spec_augment(
    features: torch.Tensor,
    generator: torch.Generator,
    time_masks: int = 2,
    time_mask_frames: int = 10,
    coefficient_masks: int = 2,
    coefficient_mask_width: int = 5,
) -> torch.Tensor:
    """SpecAugment: zero `time_masks` bands of up to `time_mask_frames` frames and `coefficient_masks` bands
    of up to `coefficient_mask_width` coefficients in every matrix."""
    batch, frames, coefficients = features.shape
    keep_frames = _band_keep_mask(generator, batch, frames, time_masks, time_mask_frames, features.device)
    keep_coeffs = _band_keep_mask(
        generator, batch, coefficients, coefficient_masks, coefficient_mask_width, features.device
    )
    keep = keep_frames[:, :, None] & keep_coeffs[:, None, :]
    return features * keep.to(features.dtype)


def _shift_c0(
    features: torch.Tensor, generator: torch.Generator, gain_db: tuple[float, float]
) -> torch.Tensor:
    # A gain of g dB adds g·ln(10)/10 to every log-mel band; the orthonormal DCT puts all of it into c0.
    gains = _uniform(generator, features.shape[0], gain_db, features)
    offset = gains * math.log(10) / 10 * math.sqrt(NUM_COEFFICIENTS)
    shifted = features.clone()
    shifted[:, :, 0] += offset[:, None]
    return shifted


def _band_keep_mask(
    generator: torch.Generator, batch: int, size: int, count: int, max_width: int, device: torch.device
) -> torch.Tensor:
    keep = torch.ones(batch, size, dtype=torch.bool, device=device)
    index = torch.arange(size, device=device)[None, :]
    for _ in range(count):  # a handful of masks; each is batched over the whole batch
        widths = _integers(generator, batch, 0, max_width, device)
        starts = (torch.rand(batch, generator=generator, device=device) * (size - widths + 1)).long()
        keep &= ~((index >= starts[:, None]) & (index < (starts + widths)[:, None]))
    return keep


def _coloured_noise(
    generator: torch.Generator, batch: int, length: int, colour: tuple[float, float], like: torch.Tensor
) -> torch.Tensor:
    white = torch.randn(batch, length, generator=generator, device=like.device, dtype=like.dtype)
    alpha = _uniform(generator, batch, colour, like)
    frequencies = torch.fft.rfftfreq(length, device=like.device).to(like.dtype).clamp(min=1.0 / length)
    shaped = torch.fft.rfft(white) * frequencies[None, :] ** (-alpha[:, None] / 2)
    return torch.fft.irfft(shaped, n=length)


def _noise_from_bank(generator: torch.Generator, bank: torch.Tensor, batch: int, length: int) -> torch.Tensor:
    rows = torch.randint(bank.shape[0], (batch,), generator=generator, device=bank.device)
    bank_length = bank.shape[1]
    offsets = (torch.rand(batch, generator=generator, device=bank.device) * bank_length).long()
    positions = (torch.arange(length, device=bank.device)[None, :] + offsets[:, None]) % bank_length
    return torch.gather(bank[rows], 1, positions)


def _sample_at(waves: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of each row at fractional `positions`; zero outside the row."""
    lower = positions.floor()
    fraction = positions - lower
    lower = lower.long()
    left = _take(waves, lower)
    right = _take(waves, lower + 1)
    return left + (right - left) * fraction


def _take(waves: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    inside = (positions >= 0) & (positions < waves.shape[1])
    gathered = torch.gather(waves, 1, positions.clamp(0, waves.shape[1] - 1))
    return gathered * inside.to(waves.dtype)


def _uniform(
    generator: torch.Generator, size: int, bounds: tuple[float, float], like: torch.Tensor
) -> torch.Tensor:
    low, high = bounds
    return low + (high - low) * torch.rand(size, generator=generator, device=like.device, dtype=like.dtype)


def _integers(
    generator: torch.Generator, size: int, low: int, high: int, device: torch.device
) -> torch.Tensor:
    """Uniform integers in [low, high]."""
    return torch.randint(low, high + 1, (size,), generator=generator, device=device)
