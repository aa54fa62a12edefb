"""Each built set's features per sound front end, computed once per clip and cached beside its clips.

The MFCC features are written by the build itself (`features.npy`); any other front end's are computed from
the clips on first use and kept as `features.<front end>-v<version>.npy` in the set's folder. A rebuild
replaces the whole folder, so a cache never outlives the clips it was computed from.
"""

import os
from pathlib import Path

import numpy as np
from tqdm import tqdm

from learning.front_ends import MFCC, check_front_end
from learning.sounds.build import FEATURES as MFCC_FEATURES

# Bump when a front end's featurisation changes, so that stale caches are recomputed.
FRONT_END_VERSIONS = {"speech-embedding": 1, "speech-embedding-fast": 1}


def features_file(front_end: str) -> str:
    if check_front_end(front_end) == MFCC:
        return MFCC_FEATURES
    return f"features.{front_end}-v{FRONT_END_VERSIONS[front_end]}.npy"


def cached_features(
    folder: Path, clips: list[str], kind: str, front_end: str, progress: bool = True
) -> np.ndarray:
    """(N, frames, values) features of these clips (paths relative to `folder`), from the cache if there."""
    path = folder / features_file(front_end)
    if front_end == MFCC:
        return np.load(path)  # written by the build
    if path.exists():
        features = np.load(path)
        if len(features) == len(clips):
            return features
    from learning.audio import features_from_bytes

    rows = [
        features_from_bytes((folder / clip).read_bytes(), kind, front_end)
        for clip in tqdm(clips, desc=f"{folder.name}: {front_end}", unit="clip", disable=not progress)
    ]
    features = np.stack(rows).astype(np.float32)
    temporary = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npy")
    np.save(temporary, features)
    os.replace(temporary, path)  # two processes computing at once both write the same rows
    return features
