"""Build the sound corpora offline: plan every clip (deterministic for a seed), render in parallel, write
clips, a JSON-lines manifest and a features cache under `data_dir()/sounds/<set>/`.

A set is rebuilt only when its recipe (profile, seed, wordings, builder version) changed; it is written to a
`.partial` folder and moved into place at the end, so an interrupted build never looks finished.
"""

import hashlib
import json
import os
import shutil
import time
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from core.paths import data_dir
from learning.audio import PEAK_LEVEL, SAMPLE_RATE, decode_audio, encode_wav, features_from_bytes
from learning.room_acoustics import ISM_ORDER, RoomRanges, record_in_room
from learning.sounds import engines
from learning.sounds.recordings import RECORDING_PARTS, crop_plan, varied_recordings
from learning.sounds.sets import MIX, NOTE_MIDI, NOTES, OBJECTS, SoundSet, sound_set
from learning.sounds.speakers import (
    MULTILINGUAL_SIZES,
    PROFILES,
    UNHEARD_ROOM,
    Profile,
    Speaker,
    instruments,
    multilingual_speakers,
    speech_speakers,
)

BUILDER_VERSION = 2
MANIFEST = "manifest.jsonl"
FEATURES = "features.npy"
BUILD_INFO = "build.json"
UNIT_SIZES = {"espeak-ng": 24, "flite": 24, "festival": 80, "fluidsynth": 72, "recording": 1_000_000}
PUNCTUATION = (".", "!", "?", "")  # changes espeak-ng's and the diphone voices' intonation


@dataclass
class ClipPlan:
    index: int
    clip: str  # path relative to the set folder
    intent: int
    speaker: Speaker
    text: str | None = None
    note: str | None = None
    variation: dict[str, object] = field(default_factory=dict)
    language: str | None = None  # multilingual sets only (never read by the VAR)

    def record(self, set_: SoundSet, duration_s: float) -> dict[str, object]:
        language = {} if self.language is None else {"language": self.language}
        return language | {
            "clip": self.clip,
            "set": set_.name,
            "intent": self.intent,
            "intent_name": set_.intent_names[self.intent],
            "text": self.text,
            "note": self.note,
            "speaker": self.speaker.id,
            "engine": self.speaker.engine,
            "split": self.speaker.split,
            "speaker_params": self.speaker.params(),
            "variation": self.variation,
            "duration_s": round(duration_s, 4),
        }


@dataclass(frozen=True)
class BuildResult:
    name: str
    folder: Path
    clips: int
    seconds: float
    cached: bool


def sounds_root(root: Path | None = None) -> Path:
    return (root or data_dir()) / "sounds"


def build_corpora(
    sets: list[str] | tuple[str, ...],
    profile: str = "default",
    seed: int = 0,
    root: Path | None = None,
    workers: int = 2,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> list[BuildResult]:
    """Build (or find cached) every set in `sets` under `root/sounds/` (root: the data dir by default)."""
    chosen = [sound_set(name) for name in sets]
    if MIX in chosen and OBJECTS not in chosen:  # the mix set reuses the objects clips
        chosen.insert(chosen.index(MIX), OBJECTS)
    chosen.sort(key=lambda s: s is MIX)
    settings = PROFILES.get(profile)
    if settings is None:
        raise ValueError(f"Unknown profile {profile!r}: use one of {', '.join(PROFILES)}.")
    _require_engines(chosen, settings)
    base = sounds_root(root)
    base.mkdir(parents=True, exist_ok=True)
    results: list[BuildResult] = []
    for set_ in chosen:
        recipe = _recipe(set_, settings, seed, base)
        folder = base / set_.name
        if _is_cached(folder, recipe):
            log(f"{set_.name}: up to date ({folder})")
            results.append(BuildResult(set_.name, folder, _clip_count(folder), 0.0, cached=True))
            continue
        results.append(_build_set(set_, settings, seed, recipe, folder, workers, progress, log))
    return results


def _build_set(
    set_: SoundSet,
    profile: Profile,
    seed: int,
    recipe: dict[str, object],
    folder: Path,
    workers: int,
    progress: bool,
    log: Callable[[str], None],
) -> BuildResult:
    started = time.perf_counter()
    partial = folder.with_name(folder.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    records: list[dict[str, object]] = []
    features: list[np.ndarray] = []
    if set_ is MIX:
        records, features = _reuse_objects_clips(folder.parent / OBJECTS.name, partial)
    plans = _plan(set_, profile, seed)
    for plan in plans:
        plan.index += len(records)
    rendered = _render(set_, plans, partial, seed, workers, progress)
    for plan, (clip_features, duration_s) in zip(plans, rendered, strict=True):
        records.append(plan.record(set_, duration_s))
        features.append(clip_features)
    _write_outputs(partial, set_, recipe, records, np.stack(features), time.perf_counter() - started)
    shutil.rmtree(folder, ignore_errors=True)
    partial.rename(folder)
    seconds = time.perf_counter() - started
    log(f"{set_.name}: {len(records)} clips in {seconds:.1f} s ({folder})")
    return BuildResult(set_.name, folder, len(records), seconds, cached=False)


# ---------------------------------------------------------------- planning


def _plan(set_: SoundSet, profile: Profile, seed: int) -> list[ClipPlan]:
    rng = np.random.default_rng([seed, zlib.crc32(set_.name.encode())])
    if set_ is NOTES:
        return _plan_notes(profile)
    if set_ is MIX:
        return _plan_recordings(profile, rng)
    if set_.languages:
        return _plan_multilingual(set_, profile, seed)
    return _plan_speech(set_, profile, seed, rng)


def _plan_speech(set_: SoundSet, profile: Profile, seed: int, rng: np.random.Generator) -> list[ClipPlan]:
    phrases = set_.kind == "phrase"
    repeats = profile.phrase_variations if phrases else profile.variations
    plans = []
    for speaker in speech_speakers(profile, seed):
        for intent, wordings in enumerate(set_.wordings):
            for wording_index, text in enumerate(wordings):
                for repeat in range(repeats):
                    clip = f"clips/{_slug(speaker.id)}/{intent}-{wording_index}-{repeat}.wav"
                    variation = _speech_variation(speaker, rng, phrases)
                    plans.append(ClipPlan(len(plans), clip, intent, speaker, text=text, variation=variation))
    return plans


def _plan_multilingual(set_: SoundSet, profile: Profile, seed: int) -> list[ClipPlan]:
    """Each speaker says its own language's word for every intent; the unheard-room tier's clips are recorded
    in a simulated room of their own (variation "room": the seed of its draw). Each speaker's clips vary
    from a stream of its own, so a tier's size changes no other tier's clips."""
    size = MULTILINGUAL_SIZES[profile.name]
    plans = []
    for language, speaker in multilingual_speakers(set_.languages, size, seed):
        rng = np.random.default_rng([seed, 3, zlib.crc32(speaker.id.encode())])
        for intent, text in enumerate(language.words):
            for repeat in range(size.variations):
                clip = f"clips/{_slug(speaker.id)}/{intent}-{repeat}.wav"
                variation = _speech_variation(speaker, rng, phrases=False)
                if speaker.split == UNHEARD_ROOM:
                    variation["room"] = int(rng.integers(2**31))
                plans.append(
                    ClipPlan(
                        len(plans), clip, intent, speaker, text, variation=variation, language=language.code
                    )
                )
    return plans


def _speech_variation(speaker: Speaker, rng: np.random.Generator, phrases: bool) -> dict[str, object]:
    variation: dict[str, object] = {"punctuation": PUNCTUATION[int(rng.integers(len(PUNCTUATION)))]}
    if speaker.engine == "espeak-ng":
        variation["pitch"] = int(np.clip(speaker.pitch + rng.integers(-6, 7), 0, 99))
        variation["speed"] = round(speaker.speed * rng.uniform(0.9, 1.1))
        variation["word_gap"] = int(rng.integers(0, 3)) if phrases else 0
    else:  # recorded voices: tempo from the engine, a small pitch+tempo change afterwards
        variation["duration_stretch"] = round(float(rng.uniform(0.85, 1.2)), 3)
        variation["speed_factor"] = round(float(rng.uniform(0.94, 1.06)), 3)
    return variation


def _plan_notes(profile: Profile) -> list[ClipPlan]:
    plans = []
    for instrument in instruments(profile):
        for intent, note in enumerate(NOTES.intent_names):
            for velocity in profile.velocities:
                for duration_s in profile.note_durations_s:
                    clip = f"clips/{_slug(instrument.id)}/{note}-v{velocity}-d{round(duration_s * 1000)}.wav"
                    variation = {"velocity": velocity, "duration_s": duration_s, "midi_note": NOTE_MIDI[note]}
                    plans.append(
                        ClipPlan(len(plans), clip, intent, instrument, note=note, variation=variation)
                    )
    return plans


def _plan_recordings(profile: Profile, rng: np.random.Generator) -> list[ClipPlan]:
    plans = []
    for part in RECORDING_PARTS:
        speaker = Speaker(id=part.speaker, engine="recording", voice=part.file, split=part.split)
        for crop in crop_plan(part, profile.recording_variations.get(part.split, 0), rng):
            clip = f"clips/{_slug(part.speaker)}/{len(plans):04d}.wav"
            plans.append(ClipPlan(len(plans), clip, part.intent, speaker, variation=dict(crop)))
    return plans


# ---------------------------------------------------------------- rendering


def _render(
    set_: SoundSet, plans: list[ClipPlan], folder: Path, seed: int, workers: int, progress: bool
) -> list[tuple[np.ndarray, float]]:
    """Render every plan; returns (features, duration) in plan order whatever order the work finishes in."""
    results: list[tuple[np.ndarray, float] | None] = [None] * len(plans)
    offset = plans[0].index if plans else 0
    units = list(_units(plans))
    with (
        ThreadPoolExecutor(max_workers=max(1, workers)) as pool,
        tqdm(total=len(plans), desc=set_.name, unit="clip", disable=not progress) as bar,
    ):
        futures = [pool.submit(_render_unit, set_, unit, folder, seed) for unit in units]
        for future in as_completed(futures):
            for plan, result in future.result():
                results[plan.index - offset] = result
            bar.update(len(future.result()))
    return [r for r in results if r is not None]


def _units(plans: list[ClipPlan]) -> Iterator[list[ClipPlan]]:
    """Group plans into units of work: same engine and voice or soundfont (a batch renderer loads it once)."""
    groups: dict[tuple[str, str], list[ClipPlan]] = {}
    for plan in plans:
        speaker = plan.speaker
        renderer_input = speaker.id if speaker.engine == "recording" else speaker.soundfont or speaker.voice
        groups.setdefault((speaker.engine, renderer_input), []).append(plan)
    for (engine, _), group in groups.items():
        size = UNIT_SIZES[engine]
        for start in range(0, len(group), size):
            yield group[start : start + size]


def _render_unit(
    set_: SoundSet, unit: list[ClipPlan], folder: Path, seed: int
) -> list[tuple[ClipPlan, tuple[np.ndarray, float]]]:
    waveforms = _synthesize(unit, seed)
    finished = []
    for plan, waveform in zip(unit, waveforms, strict=True):
        speed_factor = float(plan.variation.get("speed_factor", 1.0))  # type: ignore[arg-type]
        if speed_factor != 1.0:
            waveform = _change_speed(waveform, speed_factor)
        if "room" in plan.variation:
            waveform = record_in_room(waveform, np.random.default_rng([seed, int(plan.variation["room"])]))  # type: ignore[call-overload]
        data = encode_wav(_peak_normalised(waveform))
        path = folder / plan.clip
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        # the corpus goes through exactly the path an upload of this file would take
        finished.append((plan, (features_from_bytes(data, set_.kind), len(waveform) / SAMPLE_RATE)))
    return finished


def _synthesize(unit: list[ClipPlan], seed: int) -> list[np.ndarray]:
    engine = unit[0].speaker.engine
    if engine == "fluidsynth":
        requests = [_note_request(p) for p in unit]
        return engines.fluidsynth_notes(unit[0].speaker.soundfont, requests)
    if engine == "recording":
        part = next(p for p in RECORDING_PARTS if p.speaker == unit[0].speaker.id)
        return varied_recordings(
            part, [p.variation for p in unit], seed=seed * 1000 + RECORDING_PARTS.index(part)
        )
    if engine == "festival":
        requests = [(p.speaker.voice, _spoken(p), float(p.variation["duration_stretch"])) for p in unit]  # type: ignore[arg-type]
        return [decode_audio(data)[0] for data in engines.festival_batch(requests)]
    return [_speak_one(p) for p in unit]


def _note_request(plan: ClipPlan) -> engines.NoteRequest:
    variation = plan.variation
    return engines.NoteRequest(
        program=plan.speaker.program,
        midi_note=int(variation["midi_note"]),  # type: ignore[call-overload]
        velocity=int(variation["velocity"]),  # type: ignore[call-overload]
        duration_s=float(variation["duration_s"]),  # type: ignore[arg-type]
    )


def _speak_one(plan: ClipPlan) -> np.ndarray:
    s, v = plan.speaker, plan.variation
    if s.engine == "espeak-ng":
        data = engines.espeak(
            _spoken(plan),
            s.voice,
            s.accent,
            int(v["pitch"]),
            int(v["speed"]),
            int(v["word_gap"]),  # type: ignore[arg-type]
            variant_text=s.variant_text,
        )
    else:
        data = engines.flite(_spoken(plan), s.voice, float(v["duration_stretch"]))  # type: ignore[arg-type]
    return decode_audio(data)[0]


def _spoken(plan: ClipPlan) -> str:
    return f"{plan.text}{plan.variation.get('punctuation', '')}"


def _change_speed(waveform: np.ndarray, factor: float) -> np.ndarray:
    """Play `factor` times faster (pitch and tempo together), by linear interpolation."""
    positions = np.arange(0.0, len(waveform) - 1, factor)
    return np.interp(positions, np.arange(len(waveform)), waveform).astype(np.float32)


def _peak_normalised(waveform: np.ndarray) -> np.ndarray:
    peak = float(np.abs(waveform).max(initial=0.0))
    return waveform if peak == 0 else waveform * (PEAK_LEVEL / peak)


# ---------------------------------------------------------------- outputs and cache


def _reuse_objects_clips(objects: Path, partial: Path) -> tuple[list[dict[str, object]], list[np.ndarray]]:
    """The mix set's speech is the objects set: hard-link its clips (copy across file systems)."""
    records = [json.loads(line) for line in (objects / MANIFEST).read_text().splitlines()]
    for record in records:
        target = partial / str(record["clip"])
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(objects / str(record["clip"]), target)
        except OSError:
            shutil.copyfile(objects / str(record["clip"]), target)
        record["set"] = MIX.name
    features = np.load(objects / FEATURES)
    return records, list(features)


def _write_outputs(
    folder: Path,
    set_: SoundSet,
    recipe: dict[str, object],
    records: list[dict[str, object]],
    features: np.ndarray,
    seconds: float,
) -> None:
    manifest = "".join(json.dumps(r, sort_keys=True) + "\n" for r in records)
    (folder / MANIFEST).write_text(manifest)
    np.save(folder / FEATURES, features.astype(np.float32))
    info = {
        "set": set_.name,
        "kind": set_.kind,
        "intent_names": list(set_.intent_names),
        "clips": len(records),
        "recipe": recipe,
        "recipe_hash": _hash(json.dumps(recipe, sort_keys=True)),
        "manifest_hash": _hash(manifest),
        "build_seconds": round(seconds, 2),
    }
    (folder / BUILD_INFO).write_text(json.dumps(info, indent=2) + "\n")


def _recipe(set_: SoundSet, profile: Profile, seed: int, base: Path) -> dict[str, object]:
    recipe: dict[str, object] = {
        "builder": BUILDER_VERSION,
        "set": set_.name,
        "kind": set_.kind,
        "profile": asdict(profile),
        "seed": seed,
        "intent_names": list(set_.intent_names),
        "wordings": [list(w) for w in set_.wordings],
    }
    if set_ is MIX:
        recipe["objects"] = _recipe(OBJECTS, profile, seed, base)
    if set_.languages:
        recipe["languages"] = [asdict(language) for language in set_.languages]
        recipe["multilingual_size"] = asdict(MULTILINGUAL_SIZES[profile.name])
        recipe["draws"] = "one stream per tier and per speaker"
        recipe["rooms"] = asdict(RoomRanges()) | {"ism_order": ISM_ORDER}
    return recipe


def _is_cached(folder: Path, recipe: dict[str, object]) -> bool:
    info_path = folder / BUILD_INFO
    if not (info_path.exists() and (folder / MANIFEST).exists() and (folder / FEATURES).exists()):
        return False
    info = json.loads(info_path.read_text())
    return info.get("recipe_hash") == _hash(json.dumps(recipe, sort_keys=True))


def _clip_count(folder: Path) -> int:
    return int(json.loads((folder / BUILD_INFO).read_text())["clips"])


def _require_engines(chosen: list[SoundSet], profile: Profile) -> None:
    speech = any(s is not NOTES and not s.languages for s in chosen)
    needed: set[str] = set()
    voices: set[str] = set()
    soundfonts: set[str] = set()
    if speech:
        speakers = speech_speakers(profile, seed=0)
        needed |= {s.engine for s in speakers}
        voices |= {s.voice for s in speakers if s.engine == "festival"}
    if any(s.languages for s in chosen):
        needed.add("espeak-ng")
    if NOTES in chosen:
        needed.add("fluidsynth")
        soundfonts |= {i.soundfont for i in instruments(profile)}
    engines.require(needed, voices, soundfonts)


def _hash(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)
