"""Sound-command corpora built offline (`varbot sounds build`) and loaded as arrays (`load_corpus`)."""

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from learning.front_ends import DEFAULT_FRONT_END
from learning.sounds.sets import DEFAULT_SETS, SET_NAMES, SOUND_SETS, sound_set
from learning.sounds.speakers import NOTE_SPLITS, SPEECH_SPLITS

__all__ = [
    "DEFAULT_SETS",
    "NOTE_SPLITS",
    "SET_NAMES",
    "SOUND_SETS",
    "SPEECH_SPLITS",
    "SoundCorpus",
    "load_corpus",
]


@dataclass(frozen=True)
class SoundCorpus:
    """One built sound set; every array has one row per clip."""

    name: str
    kind: str  # the feature kind its clips were featurised with (learning.audio.FEATURE_KINDS)
    features: np.ndarray  # (N, frames, values) float32 features of the front end, e.g. (N, 100, 40) MFCC
    intent: np.ndarray  # (N,) int64
    speaker: np.ndarray  # (N,) str
    split: np.ndarray  # (N,) str
    clip: np.ndarray  # (N,) str, absolute paths of the 16 kHz WAV clips
    intent_names: list[str]
    manifest_hash: str
    front_end: str = DEFAULT_FRONT_END  # learning.front_ends: what `features` are

    def __len__(self) -> int:
        return len(self.intent)

    @property
    def splits(self) -> list[str]:
        """The splits present, in the order train, then the unheard tiers."""
        order = (*SPEECH_SPLITS, *NOTE_SPLITS)
        return sorted(
            set(self.split.tolist()), key=lambda s: (order.index(s) if s in order else len(order), s)
        )

    def subset(self, split: str | list[str]) -> "SoundCorpus":
        wanted = [split] if isinstance(split, str) else list(split)
        unknown = sorted(set(wanted) - set(self.splits))
        if unknown:
            raise ValueError(
                f"{self.name} has no split {', '.join(unknown)}; it has {', '.join(self.splits)}."
            )
        return self._rows(np.isin(self.split, wanted))

    def by_speakers(self, speakers: list[str] | tuple[str, ...], keep: bool = True) -> "SoundCorpus":
        """The clips of these speakers (`keep`), or of every other speaker."""
        return self._rows(np.isin(self.speaker, list(speakers)) == keep)

    def _rows(self, rows: np.ndarray) -> "SoundCorpus":
        return replace(
            self,
            features=self.features[rows],
            intent=self.intent[rows],
            speaker=self.speaker[rows],
            split=self.split[rows],
            clip=self.clip[rows],
        )


def load_corpus(
    name: str, data_dir: Path | None = None, front_end: str = DEFAULT_FRONT_END, progress: bool = False
) -> SoundCorpus:
    """Load a built set from `data_dir/sounds/<name>/` (default: the varbot data dir), with the features of
    `front_end` (computed once from the clips and cached there, for any front end but MFCC)."""
    from learning.sounds.build import BUILD_INFO, MANIFEST, sounds_root
    from learning.sounds.features import cached_features

    sound_set(name)
    folder = sounds_root(data_dir) / name
    if not (folder / BUILD_INFO).exists():
        raise FileNotFoundError(
            f"The sound set {name!r} is not built in {folder.parent}: "
            f"run `varbot sounds build --sets {name}` "
            "(add --small for a quick test corpus)."
        )
    info = json.loads((folder / BUILD_INFO).read_text())
    records = [json.loads(line) for line in (folder / MANIFEST).read_text().splitlines()]
    clips = [str(r["clip"]) for r in records]
    features = cached_features(folder, clips, info["kind"], front_end, progress)
    if len(features) != len(records):
        raise RuntimeError(
            f"{folder} is inconsistent ({len(features)} features, {len(records)} clips): rebuild it."
        )
    return SoundCorpus(
        name=name,
        kind=info["kind"],
        features=features,
        intent=np.array([r["intent"] for r in records], dtype=np.int64),
        speaker=np.array([r["speaker"] for r in records], dtype=str),
        split=np.array([r["split"] for r in records], dtype=str),
        clip=np.array([str(folder / r["clip"]) for r in records], dtype=str),
        intent_names=list(info["intent_names"]),
        manifest_hash=info["manifest_hash"],
        front_end=front_end,
    )
