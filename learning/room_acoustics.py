"""A clip as a browser would record it in someone's room: reverberation, background noise, a cheap microphone.

`record_in_room(waveform, rng)` plays a clean 16 kHz clip in a simulated shoebox room and returns what a
microphone there hears:

- the room's impulse response: pyroomacoustics' image-source method up to `ISM_ORDER` reflections (the early
  part, exact for a shoebox), continued by a late tail of exponentially decaying noise at the room's RT60
  (Sabine's absorption from `pyroomacoustics.inverse_sabine`). The full image-source response of a long RT60
  takes seconds per room, and pyroomacoustics' ray tracer is not reproducible; this is milliseconds and
  depends on `rng` alone;
- background noise (1/f^α, and sometimes mains hum) at a random signal-to-noise ratio, starting a little
  before the command as a recording does;
- a cheap microphone's band: a high-pass and a low-pass Butterworth filter at random corners.

Every draw comes from `rng`, so a seed gives the same recording. The work is numpy, scipy and pyroomacoustics
(learning.audio gives only the sample rate and the peak level).
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from learning.audio import PEAK_LEVEL, SAMPLE_RATE

ISM_ORDER = 8
SPEED_OF_SOUND_M_S = 343.0
WALL_CLEARANCE_M = 0.4  # talker and microphone stay this far from any wall
JOIN_WINDOW_S = 0.010  # the late tail's level is matched to the image-source response over this window


@dataclass(frozen=True)
class RoomRanges:
    """What rooms, noise and microphones are drawn from (uniformly within each range)."""

    length_m: tuple[float, float] = (3.0, 8.0)
    width_m: tuple[float, float] = (2.5, 6.0)
    height_m: tuple[float, float] = (2.4, 3.2)
    rt60_s: tuple[float, float] = (0.2, 0.8)
    distance_m: tuple[float, float] = (0.4, 3.0)  # talker to microphone
    snr_db: tuple[float, float] = (5.0, 30.0)
    noise_colour: tuple[float, float] = (0.0, 2.0)  # α of 1/f^α noise: 0 white, 1 pink, 2 brown
    hum_probability: float = 0.3
    hum_hz: tuple[float, ...] = (50.0, 60.0)
    low_cut_hz: tuple[float, float] = (80.0, 400.0)
    high_cut_hz: tuple[float, float] = (3000.0, 7500.0)
    lead_s: tuple[float, float] = (0.05, 0.2)  # noise before the command starts


def record_in_room(
    waveform: np.ndarray, rng: np.random.Generator, ranges: RoomRanges = RoomRanges()
) -> np.ndarray:
    """The clip as heard by a microphone in a room drawn from `ranges`: float32, peak at PEAK_LEVEL."""
    reverberant = signal.fftconvolve(
        np.asarray(waveform, dtype=np.float64), room_impulse_response(rng, ranges)
    )
    lead = round(_uniform(rng, ranges.lead_s) * SAMPLE_RATE)
    recorded = np.concatenate([np.zeros(lead), reverberant])
    recorded = recorded + background_noise(recorded, rng, ranges)
    recorded = microphone_band(recorded, rng, ranges)
    peak = float(np.abs(recorded).max(initial=0.0))
    return (recorded * (PEAK_LEVEL / peak if peak > 0 else 1.0)).astype(np.float32)


def room_impulse_response(rng: np.random.Generator, ranges: RoomRanges = RoomRanges()) -> np.ndarray:
    """Impulse response (16 kHz) from a talker to a microphone in a shoebox room drawn from `ranges`."""
    import pyroomacoustics

    size = np.array(
        [_uniform(rng, ranges.length_m), _uniform(rng, ranges.width_m), _uniform(rng, ranges.height_m)]
    )
    rt60 = _uniform(rng, ranges.rt60_s)
    talker, microphone = _positions(size, rng, ranges.distance_m)
    absorption, _ = pyroomacoustics.inverse_sabine(rt60, size.tolist())
    room = pyroomacoustics.ShoeBox(
        size.tolist(), fs=SAMPLE_RATE, materials=pyroomacoustics.Material(absorption), max_order=ISM_ORDER
    )
    room.add_source(talker.tolist())
    room.add_microphone(microphone.tolist())
    room.compute_rir()
    early = np.asarray(room.rir[0][0], dtype=np.float64)
    return _with_late_tail(early, rt60, float(size.min()), rng)


def background_noise(recording: np.ndarray, rng: np.random.Generator, ranges: RoomRanges) -> np.ndarray:
    """Noise for the whole recording, at a random SNR against the recording's audible part."""
    length = len(recording)
    noise = _coloured_noise(rng, length, _uniform(rng, ranges.noise_colour))
    if rng.random() < ranges.hum_probability:
        noise = noise + _hum(rng, length, float(rng.choice(ranges.hum_hz)))
    audible = np.abs(recording) > 1e-4 * np.abs(recording).max(initial=0.0)
    signal_power = float((recording[audible] ** 2).mean()) if audible.any() else 0.0
    noise_power = float((noise**2).mean()) or 1.0
    snr_db = _uniform(rng, ranges.snr_db)
    return noise * math.sqrt(signal_power / (noise_power * 10 ** (snr_db / 10)))


def microphone_band(recording: np.ndarray, rng: np.random.Generator, ranges: RoomRanges) -> np.ndarray:
    """A cheap microphone's band: high-pass and low-pass at random corners and orders."""
    low = _uniform(rng, ranges.low_cut_hz)
    high = min(_uniform(rng, ranges.high_cut_hz), 0.45 * SAMPLE_RATE)
    order = int(rng.integers(2, 5))
    sections = signal.butter(order, [low, high], btype="bandpass", fs=SAMPLE_RATE, output="sos")
    return signal.sosfilt(sections, recording)


def _with_late_tail(
    early: np.ndarray, rt60: float, smallest_side_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Keep the image-source response where it is complete (every image of order ≤ ISM_ORDER has arrived)
    and continue it with Gaussian noise decaying 60 dB per RT60, at the level it had there."""
    complete = round(ISM_ORDER * smallest_side_m / SPEED_OF_SOUND_M_S * SAMPLE_RATE)
    complete = int(np.clip(complete, 2 * round(JOIN_WINDOW_S * SAMPLE_RATE), len(early)))
    window = round(JOIN_WINDOW_S * SAMPLE_RATE)
    level = math.sqrt(float((early[complete - window : complete] ** 2).mean()))
    length = complete + round(rt60 * SAMPLE_RATE)  # to 60 dB down
    decay = np.exp(-math.log(1000.0) * np.arange(length - complete) / (rt60 * SAMPLE_RATE))
    tail = rng.standard_normal(length - complete) * level * decay
    return np.concatenate([early[:complete], tail])


def _positions(
    size: np.ndarray, rng: np.random.Generator, distance_m: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """A talker and a microphone inside the room, at least WALL_CLEARANCE_M from the walls, the microphone
    at a distance within `distance_m` where the room allows it."""
    low, high = np.full(3, WALL_CLEARANCE_M), size - WALL_CLEARANCE_M
    talker = np.array(
        [rng.uniform(low[0], high[0]), rng.uniform(low[1], high[1]), rng.uniform(1.1, min(1.8, high[2]))]
    )
    for _ in range(32):  # a direction at random; retried until the microphone falls inside
        direction = rng.standard_normal(3)
        direction[2] *= 0.3  # microphones sit on desks and shelves, near the talker's height
        microphone = talker + direction / np.linalg.norm(direction) * _uniform(rng, distance_m)
        if (microphone >= low).all() and (microphone <= high).all():
            return talker, microphone
    return talker, np.clip(talker + np.array([distance_m[0], 0.0, 0.0]), low, high)


def _coloured_noise(rng: np.random.Generator, length: int, alpha: float) -> np.ndarray:
    spectrum = np.fft.rfft(rng.standard_normal(length))
    frequencies = np.fft.rfftfreq(length).clip(min=1.0 / length)
    return np.fft.irfft(spectrum * frequencies ** (-alpha / 2), n=length)


def _hum(rng: np.random.Generator, length: int, mains_hz: float) -> np.ndarray:
    """Mains hum: the fundamental and a few harmonics of random strength and phase."""
    time = np.arange(length) / SAMPLE_RATE
    harmonics = range(1, 6)
    return sum(
        rng.uniform(0.2, 1.0)
        / harmonic
        * np.sin(2 * np.pi * mains_hz * harmonic * time + rng.uniform(0, 2 * np.pi))
        for harmonic in harmonics
    )


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))
