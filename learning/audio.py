"""The audio path: one way from bytes (corpus clip, upload, browser recording) to a clip's features.

decode (soundfile) → mono → 16 kHz (torchaudio) → trim leading/trailing silence → cut to the window the
feature kind covers → peak-normalise → the sound front end → pad with all-zero frames.
Front ends (learning.front_ends): `mfcc` (the default, the paper's: 100 × 40 MFCC by torchaudio),
`speech-embedding` and `speech-embedding-fast` (frames × 96 of Google's speech_embedding model).
An all-zero frame means "no sound", so all zeros (`SILENCE` for MFCC) is the feature of nothing heard.
"""

import io
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import soundfile
import torch
import torchaudio

from learning.front_ends import DEFAULT_FRONT_END, MFCC, check_front_end

SAMPLE_RATE = 16_000
NUM_FRAMES = 100
NUM_COEFFICIENTS = 40

# Bounds on what we accept. A spoken command lasts ~0.3–3 s; anything outside these is a mistake
# (an empty or truncated upload, a whole recording session, a file with a nonsense header).
MIN_DURATION_S = 0.05
MAX_DURATION_S = 30.0
MIN_SAMPLE_RATE = 4_000
MAX_SAMPLE_RATE = 384_000
SILENT_PEAK = 10 ** (-60 / 20)  # below −60 dBFS everywhere: nothing was recorded

TRIM_BELOW_PEAK_DB = 40.0  # frames 40 dB under the loudest frame count as leading/trailing silence
TRIM_FRAME_S = 0.010
TRIM_MARGIN_S = 0.020
PEAK_LEVEL = 0.9

SILENCE = np.zeros((NUM_FRAMES, NUM_COEFFICIENTS), dtype=np.float32)
SILENCE.flags.writeable = False


class AudioError(ValueError):
    """The audio cannot be used; the message says what was wrong and what to do."""


@dataclass(frozen=True)
class FeatureKind:
    """MFCC framing for one kind of sound; 100 frames of `hop_s` cover `covered_s` seconds."""

    name: str
    window_s: float
    hop_s: float
    n_fft: int

    @property
    def window_samples(self) -> int:
        return round(self.window_s * SAMPLE_RATE)

    @property
    def hop_samples(self) -> int:
        return round(self.hop_s * SAMPLE_RATE)

    @property
    def max_samples(self) -> int:
        """Longest waveform that still fits in NUM_FRAMES centred frames (1 + n // hop frames)."""
        return (NUM_FRAMES - 1) * self.hop_samples

    @property
    def covered_s(self) -> float:
        return self.max_samples / SAMPLE_RATE


FEATURE_KINDS: dict[str, FeatureKind] = {
    # the reference's speech features: 25 ms Hamming window, 10 ms hop, 512-point FFT (1 s)
    "speech": FeatureKind("speech", window_s=0.025, hop_s=0.010, n_fft=512),
    # music and environmental sounds: 50 ms window, 40 ms hop, 1024-point FFT (4 s)
    "sound": FeatureKind("sound", window_s=0.050, hop_s=0.040, n_fft=1024),
    # whole spoken phrases ("go to the left-most block") last 1.5–3 s: 32 ms window, 30 ms hop (3 s)
    "phrase": FeatureKind("phrase", window_s=0.032, hop_s=0.030, n_fft=512),
}


def feature_kind(kind: str) -> FeatureKind:
    try:
        return FEATURE_KINDS[kind]
    except KeyError:
        raise ValueError(f"Unknown feature kind {kind!r}: use one of {sorted(FEATURE_KINDS)}.") from None


def decode_audio(data: bytes, *, max_duration_s: float = MAX_DURATION_S) -> tuple[np.ndarray, float]:
    """Decode any format libsndfile reads into float32 mono at 16 kHz; returns (waveform, duration in s).

    Raises AudioError on undecodable, empty, all-silent, too short or too long audio. `max_duration_s` is for
    trusted long renderings only (a synthesizer's batch output that is cut into clips afterwards).
    """
    samples, rate = _read_samples(data, max_duration_s)
    duration_s = samples.shape[0] / rate
    if duration_s < MIN_DURATION_S:
        raise AudioError(
            f"The audio is too short ({duration_s * 1000:.0f} ms; at least {MIN_DURATION_S * 1000:.0f} ms "
            "is needed): record the whole command again."
        )
    if not np.isfinite(samples).all():
        raise AudioError("The audio contains invalid samples (NaN or infinity): export or record it again.")
    mono = samples.mean(axis=1, dtype=np.float32)
    waveform = _resample_to_16k(mono, rate)
    peak = float(np.abs(waveform).max(initial=0.0))
    if peak < SILENT_PEAK:
        level = "-inf" if peak == 0 else f"{20 * np.log10(peak):.0f}"
        raise AudioError(
            f"The audio is silent (loudest sample {level} dBFS): check that the microphone is on and "
            "not muted, then record the command again."
        )
    return waveform, duration_s


def feature_shape(kind: str = "speech", front_end: str = DEFAULT_FRONT_END) -> tuple[int, int]:
    """(frames, values per frame) of every clip's features for this kind and front end."""
    spec = feature_kind(kind)
    if check_front_end(front_end) == MFCC:
        return NUM_FRAMES, NUM_COEFFICIENTS
    from learning.front_ends import speech_embedding

    return speech_embedding.frames_for(spec.max_samples, front_end), speech_embedding.EMBEDDING_DIM


def silence(kind: str = "speech", front_end: str = DEFAULT_FRONT_END) -> np.ndarray:
    """The features of nothing heard: all zeros."""
    return np.zeros(feature_shape(kind, front_end), dtype=np.float32)


def features_from_bytes(data: bytes, kind: str = "speech", front_end: str = DEFAULT_FRONT_END) -> np.ndarray:
    """Bytes of an audio file → float32 features (`feature_shape`). `kind`: "speech", "phrase" or "sound"."""
    feature_shape(kind, front_end)  # fail on a bad kind or front end before decoding
    waveform, _ = decode_audio(data)
    return features_from_waveform(waveform, kind, front_end)


def features_from_waveform(
    waveform: np.ndarray, kind: str = "speech", front_end: str = DEFAULT_FRONT_END
) -> np.ndarray:
    """A decoded 16 kHz mono waveform → float32 features; silence (or nothing) gives all zeros."""
    spec = feature_kind(kind)
    shape = feature_shape(kind, front_end)
    sound = trim_silence(np.asarray(waveform, dtype=np.float32))
    peak = float(np.abs(sound).max(initial=0.0))
    if peak < SILENT_PEAK:
        return np.zeros(shape, dtype=np.float32)
    sound = sound[: spec.max_samples] * (PEAK_LEVEL / peak)
    if front_end == MFCC:
        return _mfcc(sound, kind)
    from learning.front_ends import speech_embedding

    features = np.zeros(shape, dtype=np.float32)
    frames = speech_embedding.embed(sound, front_end)
    features[: len(frames)] = frames
    return features


def _mfcc(sound: np.ndarray, kind: str) -> np.ndarray:
    """A trimmed, cut, peak-normalised sound → (100, 40) MFCC, padded with all-zero frames."""
    spec = FEATURE_KINDS[kind]
    valid_frames = 1 + len(sound) // spec.hop_samples
    if len(sound) < spec.n_fft:  # the centred STFT reflects n_fft/2 samples at each end
        sound = np.pad(sound, (0, spec.n_fft - len(sound)))
    with torch.no_grad():
        coefficients = _mfcc_transform(kind)(torch.from_numpy(np.ascontiguousarray(sound)))
    features = np.zeros((NUM_FRAMES, NUM_COEFFICIENTS), dtype=np.float32)
    frames = coefficients.T[: min(valid_frames, NUM_FRAMES)].numpy()
    features[: len(frames)] = frames
    return features


def trim_silence(waveform: np.ndarray) -> np.ndarray:
    """Cut leading/trailing 10 ms frames 40 dB below the loudest frame (keeping a 20 ms margin)."""
    frame = round(TRIM_FRAME_S * SAMPLE_RATE)
    usable = len(waveform) // frame * frame
    if usable == 0:
        return waveform
    rms = np.sqrt(np.mean(waveform[:usable].reshape(-1, frame) ** 2, axis=1))
    loudest = float(rms.max())
    if loudest < SILENT_PEAK / 10:
        return waveform[:0]
    loud = np.flatnonzero(rms >= loudest * 10 ** (-TRIM_BELOW_PEAK_DB / 20))
    margin = round(TRIM_MARGIN_S * SAMPLE_RATE)
    start = max(0, loud[0] * frame - margin)
    end = min(len(waveform), (loud[-1] + 1) * frame + margin)
    if loud[-1] == len(rms) - 1:  # keep the ragged tail when the sound runs to the end
        end = len(waveform)
    return waveform[start:end]


def encode_wav(waveform: np.ndarray, sample_rate: int = SAMPLE_RATE) -> bytes:
    """16-bit PCM WAV bytes of a float waveform in [-1, 1] (clipped)."""
    buffer = io.BytesIO()
    soundfile.write(buffer, np.clip(waveform, -1.0, 1.0), sample_rate, subtype="PCM_16", format="WAV")
    return buffer.getvalue()


def _read_samples(data: bytes, max_duration_s: float) -> tuple[np.ndarray, int]:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise AudioError(f"Expected the bytes of an audio file, got {type(data).__name__}.")
    if len(data) == 0:
        raise AudioError("The audio is empty (0 bytes): record or upload the command again.")
    try:
        with soundfile.SoundFile(io.BytesIO(bytes(data))) as audio_file:
            rate = audio_file.samplerate
            if not MIN_SAMPLE_RATE <= rate <= MAX_SAMPLE_RATE:
                raise AudioError(
                    f"The audio's sample rate {rate} Hz is outside {MIN_SAMPLE_RATE}–{MAX_SAMPLE_RATE} Hz: "
                    "the file is damaged or not a recording; export it again at 16–48 kHz."
                )
            # read at most one frame past the limit: a streamed header may claim any length
            limit = int(max_duration_s * rate) + 1
            samples = audio_file.read(frames=limit, dtype="float32", always_2d=True)
    except (soundfile.LibsndfileError, RuntimeError, TypeError) as error:
        reason = getattr(error, "error_string", None) or str(error)
        raise AudioError(
            f"Could not decode the audio ({reason}). Send a WAV, FLAC, OGG (Vorbis/Opus) or MP3 file; "
            "WebM/MP4 recordings must be converted to WAV first."
        ) from None
    if samples.shape[0] >= limit:
        raise AudioError(
            f"The audio is too long (more than {max_duration_s:.0f} s): a command lasts a few seconds; "
            "cut the recording to the command and upload it again."
        )
    return samples, rate


def _resample_to_16k(mono: np.ndarray, rate: int) -> np.ndarray:
    if rate == SAMPLE_RATE:
        return mono
    with torch.no_grad():
        return _resampler(rate)(torch.from_numpy(mono)).numpy()


@lru_cache(maxsize=16)
def _resampler(rate: int) -> torchaudio.transforms.Resample:
    return torchaudio.transforms.Resample(orig_freq=rate, new_freq=SAMPLE_RATE, dtype=torch.float32)


@lru_cache(maxsize=len(FEATURE_KINDS))
def _mfcc_transform(kind: str) -> torchaudio.transforms.MFCC:
    spec = FEATURE_KINDS[kind]
    return torchaudio.transforms.MFCC(
        sample_rate=SAMPLE_RATE,
        n_mfcc=NUM_COEFFICIENTS,
        log_mels=True,
        melkwargs={
            "n_fft": spec.n_fft,
            "win_length": spec.window_samples,
            "hop_length": spec.hop_samples,
            "n_mels": NUM_COEFFICIENTS,
            "window_fn": torch.hamming_window,
        },
    )
