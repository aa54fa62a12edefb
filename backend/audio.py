"""Checking and normalising uploaded voice clips (no torch in the API process).

Accepts the recordings people have: WAV, FLAC, Ogg (Vorbis or Opus), MP3 and AIFF through soundfile's bundled
libsndfile, and WebM/Matroska (what browsers record) and MP4/M4A through PyAV, imported only to decode one.
Any rate from 4 kHz to 384 kHz and any channel count; produces a 16 kHz mono 16-bit PCM WAV. Every rejection
is an `AudioRejected` with an HTTP status and a message saying what was wrong and what to do.
"""

import io
import struct
from dataclasses import dataclass
from functools import lru_cache
from math import ceil, gcd

import numpy as np
import soundfile

TARGET_RATE = 16_000
MIN_RATE, MAX_RATE = 4_000, 384_000
SILENCE_DBFS = -50.0
_ZERO_CROSSINGS = 12
_KAISER_BETA = 8.6
_FRAME_S = 0.025

ACCEPTED = "WAV, FLAC, Ogg (Vorbis or Opus), WebM (Opus), MP4/M4A, MP3 or AIFF"
_RECORD_AGAIN = "record the command again (or export it again from the app that recorded it)"

# Containers soundfile (libsndfile) reads, then those only PyAV (FFmpeg) demuxes.
_SOUNDFILE_FORMATS: list[tuple[bytes, int, str]] = [
    (b"fLaC", 0, "FLAC"),
    (b"OggS", 0, "Ogg"),
    (b"ID3", 0, "MP3"),
    (b"FORM", 0, "AIFF"),
]
_PYAV_FORMATS: list[tuple[bytes, int, str]] = [
    (b"\x1aE\xdf\xa3", 0, "WebM"),
    (b"ftyp", 4, "MP4"),
]
_NOT_AUDIO: list[tuple[bytes, int, str]] = [
    (b"\x89PNG", 0, "a PNG image"),
    (b"\xff\xd8\xff", 0, "a JPEG image"),
    (b"GIF8", 0, "a GIF image"),
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


@dataclass(frozen=True)
class Decoded:
    samples: np.ndarray  # (frames, channels) float32, at most max_seconds (plus one frame) of it
    rate: int
    channels: int


def _matches(data: bytes, signatures: list[tuple[bytes, int, str]]) -> str | None:
    return next((name for magic, at, name in signatures if data[at : at + len(magic)] == magic), None)


def _is_mpeg_audio(data: bytes) -> bool:
    """An MPEG audio frame header without an ID3 tag: 11 sync bits and a layer (AAC's ADTS has layer 0)."""
    return len(data) >= 2 and data[0] == 0xFF and data[1] & 0xE0 == 0xE0 and data[1] & 0x06 != 0


def container_of(data: bytes) -> str:
    """The recording's container (WAV, FLAC, Ogg, MP3, AIFF, WebM, MP4); 415 for anything else."""
    if data[:4] in (b"RIFF", b"RF64") and data[8:12] == b"WAVE":
        return "WAV"
    found = _matches(data, _SOUNDFILE_FORMATS) or _matches(data, _PYAV_FORMATS)
    if found:
        return found
    if _is_mpeg_audio(data):
        return "MP3"
    what = _matches(data, _NOT_AUDIO)
    raise AudioRejected(
        f"this is {what}, not a sound recording; upload the command as {ACCEPTED}"
        if what
        else f"this file is not a sound recording we can read; upload the command as {ACCEPTED}",
        status_code=415,
    )


MEDIA_TYPES = {
    "WAV": "audio/wav",
    "FLAC": "audio/flac",
    "Ogg": "audio/ogg",
    "MP3": "audio/mpeg",
    "AIFF": "audio/aiff",
    "WebM": "audio/webm",
    "MP4": "audio/mp4",
}


def media_type_of(data: bytes) -> str:
    """The MIME type to serve an accepted recording with, as uploaded."""
    try:
        return MEDIA_TYPES[container_of(data)]
    except AudioRejected:
        return "application/octet-stream"


def check_rate_and_channels(rate: int, channels: int, where: str) -> None:
    if channels < 1:
        raise AudioRejected(
            f"{where} says the recording has {channels} channels, so it holds no sound: the file is damaged; "
            f"{_RECORD_AGAIN}"
        )
    if not MIN_RATE <= rate <= MAX_RATE:
        raise AudioRejected(
            f"{where} gives a sample rate of {rate:,} Hz, but recordings are made at {MIN_RATE // 1000} kHz "
            f"to {MAX_RATE // 1000} kHz (16 or 48 kHz is usual): the file is damaged; {_RECORD_AGAIN}"
        )


def check_wav_header(data: bytes) -> None:
    """Refuse a WAV whose format is impossible (no channels, a 4 GHz rate) or whose header promises more
    audio than the file holds (cut-off upload, forged header), before libsndfile reads it."""
    if data[:4] != b"RIFF":
        return  # RF64 keeps sizes in a ds64 chunk; libsndfile checks those itself
    offset, block_align, rate = 12, 0, 0
    while offset + 8 <= len(data):
        chunk_id, size = data[offset : offset + 4], struct.unpack_from("<I", data, offset + 4)[0]
        body = offset + 8
        if chunk_id == b"fmt " and size >= 16 and body + 16 <= len(data):
            _fmt, channels, rate, _byte_rate, block_align = struct.unpack_from("<HHIIH", data, body)
            check_rate_and_channels(rate, channels, "the WAV header")
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


def _cannot_decode(container: str) -> AudioRejected:
    return AudioRejected(
        f"the {container} file cannot be decoded: it is damaged, cut off or not really {container}; "
        f"{_RECORD_AGAIN}"
    )


def decode_with_soundfile(data: bytes, container: str, max_seconds: float) -> Decoded:
    try:
        with soundfile.SoundFile(io.BytesIO(data)) as sound:
            rate, channels, frames = sound.samplerate, sound.channels, sound.frames
            check_rate_and_channels(rate, channels, f"the {container} file")
            if frames / rate > max_seconds:
                raise AudioRejected(_too_long(frames / rate, max_seconds))
            samples = sound.read(frames=int(max_seconds * rate) + 1, dtype="float32", always_2d=True)
    except (soundfile.LibsndfileError, RuntimeError, ValueError, TypeError) as exc:
        if isinstance(exc, AudioRejected):
            raise
        raise _cannot_decode(container) from exc
    return Decoded(samples, rate, channels)


def decode_with_pyav(data: bytes, container: str, max_seconds: float) -> Decoded:
    """WebM/Matroska and MP4 through FFmpeg: the first audio stream, as float32 at its own rate."""
    import av  # only here: the API process loads FFmpeg when someone sends such a recording

    chunks: list[np.ndarray] = []
    try:
        with av.open(io.BytesIO(data), mode="r") as media:
            if not media.streams.audio:
                raise AudioRejected(f"the {container} file holds no sound track; {_RECORD_AGAIN}")
            stream = media.streams.audio[0]
            rate, channels = stream.codec_context.sample_rate, stream.codec_context.channels
            check_rate_and_channels(rate, channels, f"the {container} file")
            to_float = av.AudioResampler(format="flt", layout=stream.codec_context.layout, rate=rate)
            held, limit = 0, int(max_seconds * rate) + 1
            for frame in media.decode(stream):
                for converted in to_float.resample(frame):
                    chunks.append(converted.to_ndarray().reshape(-1, channels))
                    held += chunks[-1].shape[0]
                if held > limit:  # stop decoding: a few MB of Opus can hold hours of sound
                    raise AudioRejected(_too_long(held / rate, max_seconds, "more than "))
            chunks += [converted.to_ndarray().reshape(-1, channels) for converted in to_float.resample(None)]
    except (av.FFmpegError, ValueError, IndexError) as exc:
        if isinstance(exc, AudioRejected):
            raise
        raise _cannot_decode(container) from exc
    if not chunks:
        raise _cannot_decode(container)
    return Decoded(np.concatenate(chunks).astype(np.float32, copy=False), rate, channels)


def decode(data: bytes, max_seconds: float) -> Decoded:
    container = container_of(data)
    if container == "WAV":
        check_wav_header(data)
    if container in ("WebM", "MP4"):
        return decode_with_pyav(data, container, max_seconds)
    return decode_with_soundfile(data, container, max_seconds)


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
    decoded = decode(data, max_seconds)
    samples, rate = decoded.samples, decoded.rate
    duration = samples.shape[0] / rate
    if duration < min_seconds:
        raise AudioRejected(
            f"the clip lasts {duration:.2f} s; a command must last at least {min_seconds} s — "
            "hold the button while you speak"
        )
    if duration > max_seconds:
        raise AudioRejected(_too_long(duration, max_seconds))
    if not np.isfinite(samples).all():
        raise AudioRejected("the recording contains invalid (NaN or infinite) samples; record it again")
    mono = resample(samples.mean(axis=1), rate, TARGET_RATE)
    if loudest_frame_dbfs(mono) < SILENCE_DBFS:
        raise AudioRejected(
            "the clip is silent; check that the right microphone is selected and not muted, "
            "then speak closer to it"
        )
    return NormalisedClip(
        wav=encode_wav16(mono), duration_s=duration, sample_rate=rate, channels=decoded.channels
    )


def _too_long(duration: float, max_seconds: float, more_than: str = "") -> str:
    return (
        f"the clip lasts {more_than}{duration:.1f} s; a command may last at most {max_seconds:.0f} s — "
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
