"""Sound front ends: what a clip becomes before the VAR's f_S head sees it.

`mfcc` is the paper's (learning.audio, torchaudio). `speech-embedding` is Google's speech_embedding model
(96 values every 80 ms over 32-bin log-mels) as shipped in the pyopen-wakeword wheel, run by the TFLite C
library bundled there (learning.front_ends.speech_embedding; numpy only, nothing downloaded). Only that
wheel's melspectrogram and embedding models are ever loaded; its wake-word heads are not ours to use.
"""

MFCC = "mfcc"
SPEECH_EMBEDDING = "speech-embedding"
FRONT_END_NAMES: tuple[str, ...] = (MFCC, SPEECH_EMBEDDING)
DEFAULT_FRONT_END = MFCC
VALUES_PER_FRAME = {MFCC: 40, SPEECH_EMBEDDING: 96}


def check_front_end(name: str) -> str:
    if name not in FRONT_END_NAMES:
        raise ValueError(f"Unknown sound front end {name!r}: use one of {', '.join(FRONT_END_NAMES)}.")
    return name
