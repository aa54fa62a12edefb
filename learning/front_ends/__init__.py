"""Sound front ends: what a clip becomes before the VAR's f_S head sees it.

`mfcc` is the paper's (learning.audio, torchaudio). `speech-embedding` is Google's speech_embedding model
(96 values every 80 ms over 32-bin log-mels) as shipped in the pyopen-wakeword wheel, run by the TFLite C
library bundled there (learning.front_ends.speech_embedding; numpy only, nothing downloaded). Only that
wheel's melspectrogram and embedding models are ever loaded; its wake-word heads are not ours to use.
`speech-embedding-fast` is the same model without the 320 ms of silence after the clip: 7 embedding windows
for a 1 s clip instead of 11, the first 7 of the full front end's. The model was made for wake words, which
end a window, so the windows that reach into the trailing silence add cost and little else (bench/voices.py
measures both). Its features differ, so it is a front end of its own and a VAR trained on one refuses the
other's features.
"""

MFCC = "mfcc"
SPEECH_EMBEDDING = "speech-embedding"
SPEECH_EMBEDDING_FAST = "speech-embedding-fast"
FRONT_END_NAMES: tuple[str, ...] = (MFCC, SPEECH_EMBEDDING, SPEECH_EMBEDDING_FAST)
DEFAULT_FRONT_END = MFCC
VALUES_PER_FRAME = {MFCC: 40, SPEECH_EMBEDDING: 96, SPEECH_EMBEDDING_FAST: 96}
# Silence added before and after a clip (16 kHz samples): the first windows end inside the clip's start
EDGE_PAD_SAMPLES = {SPEECH_EMBEDDING: (5120, 5120), SPEECH_EMBEDDING_FAST: (5120, 0)}


def check_front_end(name: str) -> str:
    if name not in FRONT_END_NAMES:
        raise ValueError(f"Unknown sound front end {name!r}: use one of {', '.join(FRONT_END_NAMES)}.")
    return name
