"""Google's speech_embedding over a whole clip at once: 96 values every 80 ms over 32-bin log-mels.

The wheel's own interface streams 80 ms chunks and runs the embedding model once per window; here the
melspectrogram model runs once over the padded clip and the embedding model once over every 76-frame
window of it (one batch), with the XNNPACK kernels on one thread (bench/front_ends.py times it).

The melspectrogram model floors each call's log-mels 80 dB under the call's loudest value. Called once per
clip (as openWakeWord's own batch feature path does), a clip's silence is floored relative to the clip;
the streaming interface floors each 110 ms chunk on its own, so the two differ where a window meets
silence and agree wherever the sound is loud throughout (tests/learning/test_audio_front_ends.py).
"""

import threading
from functools import lru_cache

import numpy as np

from learning.front_ends import EDGE_PAD_SAMPLES, SPEECH_EMBEDDING, VALUES_PER_FRAME
from learning.front_ends.tflite import Interpreter, wheel_file

EMBEDDING_DIM = VALUES_PER_FRAME[SPEECH_EMBEDDING]
MEL_BINS = 32
MEL_WINDOW_SAMPLES = 512  # the melspectrogram model gives 1 + (samples - 512) // 160 frames
MEL_HOP_SAMPLES = 160  # 10 ms at 16 kHz
WINDOW_MELS = 76  # one embedding sees 76 mel frames (775 ms)
STEP_MELS = 8  # and the next starts 80 ms later
INT16_SCALE = 32767.0  # the models were trained on 16-bit sample values
MIN_SAMPLES = MEL_WINDOW_SAMPLES + (WINDOW_MELS - 1) * MEL_HOP_SAMPLES  # one whole embedding window
_lock = threading.Lock()  # one interpreter pair per process; TFLite interpreters are not thread-safe


def frames_for(samples: int, front_end: str = SPEECH_EMBEDDING) -> int:
    """How many embedding frames a sound of `samples` samples (before padding) gives."""
    padded = samples + sum(_padding(samples, front_end))
    mels = 1 + (padded - MEL_WINDOW_SAMPLES) // MEL_HOP_SAMPLES
    return 1 + (mels - WINDOW_MELS) // STEP_MELS


def embed(sound: np.ndarray, front_end: str = SPEECH_EMBEDDING) -> np.ndarray:
    """A trimmed, peak-normalised 16 kHz float waveform in [-1, 1] → float32 (frames_for(len), 96).
    `front_end`: speech-embedding or speech-embedding-fast, which differ only in the edge padding."""
    padded = np.pad(np.asarray(sound, dtype=np.float32) * INT16_SCALE, _padding(len(sound), front_end))
    mel_model, embedding_model = _models()
    with _lock:
        mels = mel_model.run(padded[None]).reshape(-1, MEL_BINS) / 10 + 2  # the wheel's rescaling
        starts = np.arange(0, len(mels) - WINDOW_MELS + 1, STEP_MELS)
        windows = mels[starts[:, None] + np.arange(WINDOW_MELS)]
        embeddings = embedding_model.run(windows[..., None])
    return embeddings.reshape(len(starts), EMBEDDING_DIM)


def _padding(samples: int, front_end: str) -> tuple[int, int]:
    """Silence before and after: the front end's edge pads, and what a sound shorter than one window lacks,
    half on each side where both edges are padded (the full front end), else after it (so that the fast
    front end's windows stay the full one's first windows)."""
    before, after = EDGE_PAD_SAMPLES[front_end]
    lacking = max(0, MIN_SAMPLES - samples - before - after)
    if after:
        return before + -(-lacking // 2), after + -(-lacking // 2)
    return before, lacking


@lru_cache(maxsize=1)
def _models() -> tuple[Interpreter, Interpreter]:
    return (
        Interpreter(wheel_file("models", "melspectrogram.tflite")),
        Interpreter(wheel_file("models", "embedding_model.tflite")),
    )
