"""The real recordings of the "mix" set and how they are varied (see assets/ATTRIBUTION.md).

There is one jackhammer recording and two dog-bark recordings. Training hears the first 1.5 s of the
jackhammer and `dog_bark_1`; the unheard tier hears only the jackhammer's remaining second and `dog_bark_3`.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from learning.audio import SAMPLE_RATE, decode_audio
from learning.augment import WaveAugment, augment_waveforms
from learning.sounds.speakers import TRAIN, UNHEARD_REAL_VOICES

ASSETS = Path(__file__).resolve().parent / "assets"
CROP_S = (0.6, 1.0)
VARIATION = WaveAugment(
    speed=(0.85, 1.15), shift_s=0.05, noise_probability=0.7, snr_db=(10.0, 35.0), gain_db=(-6.0, 0.0)
)


@dataclass(frozen=True)
class RecordingPart:
    speaker: str  # the part's id: unique, in exactly one split
    file: str
    intent: int
    start_s: float
    end_s: float | None
    split: str


RECORDING_PARTS = (
    RecordingPart("recording:jackhammer-a", "jackhammer.wav", 0, 0.0, 1.5, TRAIN),
    RecordingPart("recording:dog_bark_1", "dog_bark_1.wav", 3, 0.0, None, TRAIN),
    RecordingPart("recording:jackhammer-b", "jackhammer.wav", 0, 1.5, None, UNHEARD_REAL_VOICES),
    RecordingPart("recording:dog_bark_3", "dog_bark_3.wav", 3, 0.0, None, UNHEARD_REAL_VOICES),
)


def recording_waveform(part: RecordingPart) -> np.ndarray:
    waveform, _ = decode_audio((ASSETS / part.file).read_bytes())
    end = None if part.end_s is None else round(part.end_s * SAMPLE_RATE)
    return waveform[round(part.start_s * SAMPLE_RATE) : end]


def crop_plan(part: RecordingPart, count: int, rng: np.random.Generator) -> list[dict[str, float]]:
    """Random crops (start, length in s) inside the part, one per variation."""
    available = len(recording_waveform(part)) / SAMPLE_RATE
    crops = []
    for _ in range(count):
        length = min(available, float(rng.uniform(*CROP_S)))
        start = float(rng.uniform(0.0, available - length))
        crops.append({"crop_start_s": round(start, 3), "crop_length_s": round(length, 3)})
    return crops


def varied_recordings(part: RecordingPart, crops: list[dict[str, float]], seed: int) -> list[np.ndarray]:
    """Cut the crops and vary them in one batch (speed, shift, background noise, gain)."""
    source = recording_waveform(part)
    longest = round((CROP_S[1] / VARIATION.speed[0] + 2 * VARIATION.shift_s) * SAMPLE_RATE)
    batch = torch.zeros(len(crops), longest)
    for row, crop in enumerate(crops):
        start = round(crop["crop_start_s"] * SAMPLE_RATE)
        piece = torch.from_numpy(source[start : start + round(crop["crop_length_s"] * SAMPLE_RATE)].copy())
        offset = round(VARIATION.shift_s * SAMPLE_RATE)
        batch[row, offset : offset + len(piece)] = piece
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        varied = augment_waveforms(batch, generator, VARIATION)
    return [row.numpy() for row in varied]
