"""The offline synthesizers (Debian packages) behind the corpora: espeak-ng, flite, festival, fluidsynth."""

import atexit
import contextlib
import functools
import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import mido
import numpy as np

from learning.audio import SAMPLE_RATE, decode_audio

SOUNDFONT_DIR = Path("/usr/share/sounds/sf2")
SOUNDFONT_PACKAGES = {"FluidR3_GM": "fluid-soundfont-gm", "TimGM6mb": "timgm6mb-soundfont"}
FESTIVAL_VOICE_DIRS = Path("/usr/share/festival/voices")
FESTIVAL_VOICE_PACKAGES = {
    "kal_diphone": "festvox-kallpc16k",
    "ked_diphone": "festvox-kdlpc16k",
    "cmu_us_slt_arctic_hts": "festvox-us-slt-hts",
}
ENGINE_PACKAGES = {
    "espeak-ng": "espeak-ng",
    "flite": "flite",
    "festival": "festival",
    "fluidsynth": "fluidsynth",
}

NOTE_RELEASE_S = 0.5  # kept after the note-off: the instrument's natural decay
NOTE_GAP_S = 1.0  # silence between notes in one rendering, longer than any release tail
SUBPROCESS_TIMEOUT_S = 600
BATCH_MAX_S = 3600.0  # one fluidsynth rendering holds many notes


class EngineMissingError(RuntimeError):
    """A synthesizer, voice or soundfont is not installed; the message names the Debian package."""


@dataclass(frozen=True)
class NoteRequest:
    program: int
    midi_note: int
    velocity: int
    duration_s: float


def missing_packages(
    engines: set[str], festival_voices: set[str] = frozenset(), soundfonts: set[str] = frozenset()
) -> list[str]:
    """Debian packages that must be installed before these engines, voices and soundfonts can render."""
    missing = [
        ENGINE_PACKAGES[e] for e in sorted(engines) if e in ENGINE_PACKAGES and shutil.which(e) is None
    ]
    missing += [
        FESTIVAL_VOICE_PACKAGES[v]
        for v in sorted(festival_voices)
        if not any(FESTIVAL_VOICE_DIRS.glob(f"*/{v}"))
    ]
    missing += [SOUNDFONT_PACKAGES[s] for s in sorted(soundfonts) if not soundfont_path(s).exists()]
    return missing


def require(
    engines: set[str], festival_voices: set[str] = frozenset(), soundfonts: set[str] = frozenset()
) -> None:
    missing = missing_packages(engines, festival_voices, soundfonts)
    if missing:
        raise EngineMissingError(
            f"Missing Debian package(s) {', '.join(missing)} needed to render the sound corpora: install "
            f"them with `sudo apt-get install -y {' '.join(missing)}` "
            "(or `sudo bash scripts/install-system-packages.sh`)."
        )


def soundfont_path(name: str) -> Path:
    return SOUNDFONT_DIR / f"{name}.sf2"


def espeak(
    text: str, variant: str, accent: str, pitch: int, speed: int, word_gap: int = 0, variant_text: str = ""
) -> bytes:
    """`variant` names one of espeak-ng's voice variants, or, with `variant_text`, a variant file of our own
    (a mixed voice, `learning.sounds.speakers.mixed_variant`)."""
    # One process per clip (~15 ms of CPU, mostly start-up). libespeak-ng in-process would be faster but its
    # output depends on what it synthesised before (state carried between utterances): not deterministic.
    data_path: list[str] = []
    if variant_text:
        root, variant = _own_variant(variant_text)
        data_path = [f"--path={root}"]
    command = ["espeak-ng", *data_path, "-v", f"{accent}+{variant}", "-p", str(pitch), "-s", str(speed)]
    return _run([*command, "-g", str(word_gap), "--stdout", text])


def _own_variant(variant_text: str) -> tuple[Path, str]:
    """espeak-ng reads variants only from its data folder: a private data folder per variant (links to the
    system's files, the variant as the only file of `voices/!v`: espeak-ng lists at most 349 voices)."""
    name = "varbot-" + hashlib.sha256(variant_text.encode()).hexdigest()[:16]
    root = _private_espeak_folder() / name
    if not root.exists():
        system = _system_espeak_data()
        partial = root.with_suffix(f".{os.getpid()}.part")
        shutil.rmtree(partial, ignore_errors=True)
        for folder in ("", "voices"):
            (partial / "espeak-ng-data" / folder).mkdir(parents=True)
            for entry in (system / folder).iterdir():
                if entry.name not in ("voices", "!v"):
                    (partial / "espeak-ng-data" / folder / entry.name).symlink_to(entry)
        (partial / "espeak-ng-data" / "voices" / "!v").mkdir()
        (partial / "espeak-ng-data" / "voices" / "!v" / name).write_text(variant_text)
        # workers forked after the folder was made share it: another may have made this variant first
        with contextlib.suppress(OSError):
            partial.rename(root)
        shutil.rmtree(partial, ignore_errors=True)
    return root, name


@functools.cache
def _private_espeak_folder() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="varbot-espeak-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


def _system_espeak_data() -> Path:
    """Where this espeak-ng keeps its data ("Data at: …" in `espeak-ng --version`)."""
    version = _run(["espeak-ng", "--version"]).decode()
    found = re.search(r"Data at:\s*(\S+)", version)
    if found is None:
        raise EngineMissingError(f"espeak-ng does not say where its data is: {version.strip()!r}")
    return Path(found.group(1))


def flite(text: str, voice: str, duration_stretch: float = 1.0) -> bytes:
    command = ["flite", "-voice", voice, "--setf", f"duration_stretch={duration_stretch:.3f}"]
    return _run([*command, "-t", text, "-o", "/dev/stdout"])


def festival_batch(requests: list[tuple[str, str, float]]) -> list[bytes]:
    """Render (voice, text, duration stretch) requests in one festival process (~45 ms a clip, not ~0.9 s)."""
    with tempfile.TemporaryDirectory(prefix="varbot-festival-") as work:
        outputs = [Path(work) / f"{index:05d}.wav" for index in range(len(requests))]
        lines, current_voice = [], None
        for (voice, text, stretch), output in zip(requests, outputs, strict=True):
            if voice != current_voice:
                lines.append(f"(voice_{voice})")
                current_voice = voice
            lines.append(f"(Parameter.set 'Duration_Stretch {stretch:.3f})")
            lines.append(
                f'(utt.save.wave (utt.synth (Utterance Text "{_scheme_string(text)}")) "{output}" \'riff)'
            )
        script = Path(work) / "render.scm"
        script.write_text("\n".join(lines) + "\n")
        _run(["festival", "-b", str(script)])
        missing = [str(o) for o in outputs if not o.exists()]
        if missing:
            raise RuntimeError(f"festival rendered no audio for {len(missing)} of {len(outputs)} requests")
        return [o.read_bytes() for o in outputs]


def fluidsynth_notes(soundfont: str, notes: list[NoteRequest]) -> list[np.ndarray]:
    """Render many notes in one fluidsynth run (one MIDI file, notes separated by silence) and cut them apart.

    Returns one 16 kHz mono waveform per note: from its onset to `NOTE_RELEASE_S` after its note-off.
    """
    ticks_per_second = 960  # 480 ticks per beat at 120 bpm
    midi = mido.MidiFile(ticks_per_beat=480)
    track = mido.MidiTrack()
    midi.tracks.append(track)
    track.append(mido.MetaMessage("set_tempo", tempo=500_000, time=0))
    onsets, now_ticks, pending_ticks = [], 0, 0
    for note in notes:
        hold = round(note.duration_s * ticks_per_second)
        gap = round((NOTE_RELEASE_S + NOTE_GAP_S) * ticks_per_second)
        track.append(mido.Message("program_change", program=note.program, channel=0, time=pending_ticks))
        track.append(mido.Message("note_on", note=note.midi_note, velocity=note.velocity, channel=0, time=0))
        track.append(mido.Message("note_off", note=note.midi_note, velocity=0, channel=0, time=hold))
        now_ticks += pending_ticks
        onsets.append(now_ticks / ticks_per_second)
        now_ticks += hold
        pending_ticks = gap
    track.append(mido.MetaMessage("end_of_track", time=pending_ticks))
    with tempfile.TemporaryDirectory(prefix="varbot-fluidsynth-") as work:
        midi_path, wav_path = Path(work) / "notes.mid", Path(work) / "notes.wav"
        midi.save(midi_path)
        options = ["-ni", "-q", "-R", "0", "-C", "0", "-g", "0.5", "-r", str(SAMPLE_RATE), "-T", "wav"]
        _run(["fluidsynth", *options, "-F", str(wav_path), str(soundfont_path(soundfont)), str(midi_path)])
        waveform, _ = decode_audio(wav_path.read_bytes(), max_duration_s=BATCH_MAX_S)
    clips = []
    for note, onset in zip(notes, onsets, strict=True):
        start = round(onset * SAMPLE_RATE)
        end = round((onset + note.duration_s + NOTE_RELEASE_S) * SAMPLE_RATE)
        clips.append(waveform[start:end])
    return clips


def _run(command: list[str]) -> bytes:
    try:
        result = subprocess.run(command, capture_output=True, check=False, timeout=SUBPROCESS_TIMEOUT_S)
    except FileNotFoundError:
        raise EngineMissingError(
            f"`{command[0]}` is not installed: "
            f"`sudo apt-get install -y {ENGINE_PACKAGES.get(command[0], command[0])}`."
        ) from None
    if result.returncode != 0:
        stderr = result.stderr.decode(errors="replace").strip()[-500:]
        raise RuntimeError(f"{command[0]} failed (exit {result.returncode}): {stderr}")
    return result.stdout


def _scheme_string(text: str) -> str:
    return text.replace("\\", "\\\\").replace('"', '\\"')
