"""Checking and normalising uploaded voice clips with numpy + soundfile only (no torch in the API process).

Accepts WAV of any common rate, channel count and sample format; produces a 16 kHz mono 16-bit PCM WAV.
Every rejection is an `AudioRejected` with an HTTP status and a message saying what was wrong and what to do.
"""

import io
import struct
from dataclasses import dataclass
from functools import lru_cache
from math import ceil, gcd

import numpy as np
import soundfile

TARGET_RATE = 16_000
SILENCE_DBFS = -50.0
_ZERO_CROSSINGS = 12
_KAISER_BETA = 8.6
_FRAME_S = 0.025

_OTHER_FORMATS: list[tuple[bytes, int, str]] = [
    (b"\x89PNG", 0, "a PNG image"),
    (b"\xff\xd8\xff", 0, "a JPEG image"),
    (b"GIF8", 0, "a GIF image"),
    (b"ID3", 0, "an MP3 recording"),
    (b"OggS", 0, "an Ogg (Opus/Vorbis) recording"),
    (b"fLaC", 0, "a FLAC recording"),
    (b"\x1aE\xdf\xa3", 0, "a WebM/Matroska recording"),
    (b"ftyp", 4, "an MP4/M4A recording"),
    (b"FORM", 0, "an AIFF recording"),
    (b"%PDF", 0, "a PDF document"),
    (b"PK\x03\x04", 0, "a ZIP archive"),
]


class AudioRejected(ValueError):
    def __init__(self, message: str, status_code: int = 422) -> None:
        super().__init__(message)
        self.status_code = status_code


@dataclass(frozen=True)
class NormalisedClip:
    wav: bytes  # 16 kHz mono 16-bit PCM
    duration_s: float
    sample_rate: int  # of the original
    channels: int  # of the original


def describe_non_wav(data: bytes) -> str | None:
    """What the bytes are when they are not a WAV file (None when they look like one)."""
    if data[:4] in (b"RIFF", b"RF64") and data[8:12] == b"WAVE":
        return None
    for magic, offset, description in _OTHER_FORMATS:
        if data[offset : offset + len(magic)] == magic:
            return description
    if len(data) >= 2 and data[0] == 0xFF and data[1] & 0xE0 == 0xE0:
        return "an MP3 recording"
    return "not a WAV file"


def check_declared_length(data: bytes) -> None:
    """Refuse a WAV whose header promises more audio than the file holds (cut-off upload, forged header)."""
    if data[:4] != b"RIFF":
        return  # RF64 keeps sizes in a ds64 chunk; libsndfile checks those itself
    offset, block_align, rate = 12, 0, 0
    while offset + 8 <= len(data):
        chunk_id, size = data[offset : offset + 4], struct.unpack_from("<I", data, offset + 4)[0]
        body = offset + 8
        if chunk_id == b"fmt " and size >= 16 and body + 16 <= len(data):
            _fmt, _channels, rate, _byte_rate, block_align = struct.unpack_from("<HHIIH", data, body)
        elif chunk_id == b"data":
            available = len(data) - body
            if size in (0, 0xFFFFFFFF) or size <= available:  # 0 / 0xFFFFFFFF: written while streaming
                return
            if block_align and rate:
                claimed_s, held_s = size / block_align / rate, available / block_align / rate
                raise AudioRejected(
                    f"the WAV header says the recording lasts {claimed_s:.2f} s but the file holds only "
                    f"{held_s:.2f} s of audio: the file was cut off or its header is wrong; record it again"
                )
            raise AudioRejected(
                f"the WAV data chunk claims {size} bytes but only {available} follow; record it again"
            )
        offset = body + size + (size & 1)
    raise AudioRejected("the WAV file has no audio data chunk; record it again")


def validate_and_normalise(
    data: bytes, *, min_seconds: float, max_seconds: float, max_bytes: int
) -> NormalisedClip:
    if not data:
        raise AudioRejected("the file is empty (0 bytes); record the command again")
    if len(data) > max_bytes:
        raise AudioRejected(
            f"the file is {len(data) / 2**20:.1f} MB; clips may be at most {max_bytes / 2**20:.0f} MB "
            f"(a {max_seconds:.0f} s command is well under that as 16-bit WAV)",
            status_code=413,
        )
    what = describe_non_wav(data)
    if what is not None:
        raise AudioRejected(
            f"this is {what}, not a WAV recording; upload an uncompressed WAV (16-bit PCM is best)",
            status_code=415,
        )
    check_declared_length(data)
    try:
        with soundfile.SoundFile(io.BytesIO(data)) as sound:
            rate, channels, frames = sound.samplerate, sound.channels, sound.frames
            if frames / max(rate, 1) > max_seconds:
                raise AudioRejected(_too_long(frames / rate, max_seconds))
            samples = sound.read(dtype="float32", always_2d=True)
    except AudioRejected:
        raise
    except (soundfile.LibsndfileError, RuntimeError, ValueError) as exc:
        raise AudioRejected(
            f"the WAV file cannot be decoded ({exc}); record it again as 16-bit PCM WAV"
        ) from exc
    if rate < 4000 or rate > 384_000:
        raise AudioRejected(
            f"a sample rate of {rate} Hz is not a recording rate we accept (4 kHz to 384 kHz)"
        )
    duration = samples.shape[0] / rate
    if duration < min_seconds:
        raise AudioRejected(
            f"the clip lasts {duration:.2f} s; a command must last at least {min_seconds} s — "
            "hold the button while you speak"
        )
    if duration > max_seconds:
        raise AudioRejected(_too_long(duration, max_seconds))
    if not np.isfinite(samples).all():
        raise AudioRejected("the WAV file contains invalid (NaN or infinite) samples; record it again")
    mono = resample(samples.mean(axis=1), rate, TARGET_RATE)
    if loudest_frame_dbfs(mono) < SILENCE_DBFS:
        raise AudioRejected(
            "the clip is silent; check that the right microphone is selected and not muted, "
            "then speak closer to it"
        )
    return NormalisedClip(wav=encode_wav16(mono), duration_s=duration, sample_rate=rate, channels=channels)


def _too_long(duration: float, max_seconds: float) -> str:
    return (
        f"the clip lasts {duration:.1f} s; a command may last at most {max_seconds:.0f} s — "
        "say just the command"
    )


def loudest_frame_dbfs(signal: np.ndarray, rate: int = TARGET_RATE) -> float:
    frame = max(1, int(rate * _FRAME_S))
    usable = (
        signal[: len(signal) // frame * frame].reshape(-1, frame) if len(signal) >= frame else signal[None]
    )
    rms = float(np.sqrt(np.mean(np.square(usable, dtype=np.float64), axis=1)).max())
    return 20 * np.log10(max(rms, 1e-12))


def encode_wav16(signal: np.ndarray, rate: int = TARGET_RATE) -> bytes:
    pcm = np.round(np.clip(signal, -1.0, 1.0) * 32767).astype("<i2")
    buffer = io.BytesIO()
    soundfile.write(buffer, pcm, rate, subtype="PCM_16", format="WAV")
    return buffer.getvalue()


def resample(signal: np.ndarray, source_rate: int, target_rate: int) -> np.ndarray:
    """Band-limited polyphase resampling (Kaiser-windowed sinc); float32 in, float32 out."""
    if source_rate == target_rate:
        return signal.astype(np.float32, copy=False)
    step = gcd(source_rate, target_rate)
    up, down = target_rate // step, source_rate // step
    cutoff = min(1.0, target_rate / source_rate)
    half_width = ceil(_ZERO_CROSSINGS / cutoff)
    offsets = np.arange(-half_width + 1, half_width + 1)
    n_out = ceil(len(signal) * up / down)
    padded = np.concatenate(
        [np.zeros(half_width, np.float32), signal.astype(np.float32), np.zeros(half_width + 1, np.float32)]
    )
    out = np.empty(n_out, np.float32)
    for start in range(0, n_out, 8192):
        n = np.arange(start, min(start + 8192, n_out), dtype=np.int64)
        base, phase = np.divmod(n * down, up)
        taps = _phase_table(up, down)[phase] if up <= 4096 else _kernel(up, down, phase)
        out[start : start + len(n)] = np.einsum(
            "ij,ij->i", padded[base[:, None] + offsets + half_width], taps
        )
    return out


def _kernel(up: int, down: int, phase: np.ndarray) -> np.ndarray:
    cutoff = min(1.0, up / down)
    half_width = ceil(_ZERO_CROSSINGS / cutoff)
    offsets = np.arange(-half_width + 1, half_width + 1)
    distance = offsets[None, :] - phase[:, None] / up  # input samples between each tap and the output instant
    window = np.i0(_KAISER_BETA * np.sqrt(np.clip(1 - (distance / half_width) ** 2, 0, 1))) / np.i0(
        _KAISER_BETA
    )
    return (cutoff * np.sinc(cutoff * distance) * window).astype(np.float32)


@lru_cache(maxsize=32)
def _phase_table(up: int, down: int) -> np.ndarray:
    return _kernel(up, down, np.arange(up))
