"""Who speaks (or plays) in each split. Splits are by speaker / instrument, never by clip.

- train: espeak-ng speakers (variant × base pitch × speed, drawn with the seed) from the training variants and
  accents, plus recorded voices (flite kal, kal16, slt; festival kal_diphone, slt-hts).
- unheard-easy: espeak-ng speakers built only from variants *and* accents that training never uses.
- unheard-real-voices: flite awb and rms, festival ked — real people's voices no training step heard.
- wordset-multilingual: espeak-ng speakers of each language; train from the training variants and that
  language's training accents, plus mixed voices (espeak-ng variants drawn for training only, below);
  unheard-<language> (e.g. unheard-de) from the held-out variants and accents; unheard-room: further
  held-out speakers of every language, recorded in simulated rooms (learning.room_acoustics) with seeds
  no training copy uses.
- notes: train = training instruments of FluidR3; unheard-instrument = held-out instruments of FluidR3;
  unheard-soundfont = every instrument of TimGM6mb, a soundfont training never used.
"""

from dataclasses import dataclass, field

import numpy as np

from learning.sounds.sets import Language

TRAIN = "train"
UNHEARD_EASY = "unheard-easy"
UNHEARD_REAL_VOICES = "unheard-real-voices"
UNHEARD_INSTRUMENT = "unheard-instrument"
UNHEARD_SOUNDFONT = "unheard-soundfont"
UNHEARD_ROOM = "unheard-room"
SPEECH_SPLITS = (TRAIN, UNHEARD_EASY, UNHEARD_REAL_VOICES)
NOTE_SPLITS = (TRAIN, UNHEARD_INSTRUMENT, UNHEARD_SOUNDFONT)

# espeak-ng: the variant and base pitch change the voice; the accent barely does, so it is varied on top.
# klatt6 and caleb are left out: they render identically to klatt.
TRAIN_VARIANTS = (
    "m1", "m2", "m3", "m4", "m5", "m6", "m8", "f1", "f2", "f3", "f4", "klatt", "klatt2", "klatt3",
    "Andy", "Annie", "Alicia", "david", "ed", "linda", "steph", "max", "paul", "robert",
)  # fmt: skip
HELD_OUT_VARIANTS = (
    "m7",
    "f5",
    "klatt4",
    "belinda",
    "benjamin",
    "travis",
    "victor",
    "Michael",
    "Lee",
    "norbert",
)
TRAIN_ACCENTS = ("en-us", "en", "en-gb-x-rp")
HELD_OUT_ACCENTS = ("en-gb-scotland", "en-029", "en-us-nyc", "en-gb-x-gbclan", "en-gb-x-gbcwmd")
ESPEAK_PITCH = (25, 75)  # espeak-ng -p, 0..99
ESPEAK_SPEED = (135, 195)  # words per minute

SOUNDFONT_TRAIN = "FluidR3_GM"
SOUNDFONT_HELD_OUT = "TimGM6mb"
GM_PROGRAMS = {
    0: "acoustic grand piano", 1: "bright piano", 4: "electric piano", 6: "harpsichord", 8: "celesta",
    11: "vibraphone", 12: "marimba", 16: "drawbar organ", 19: "church organ", 21: "accordion",
    24: "nylon guitar", 25: "steel guitar", 26: "jazz guitar", 40: "violin", 41: "viola", 42: "cello",
    48: "string ensemble", 56: "trumpet", 60: "french horn", 65: "alto sax", 68: "oboe", 71: "clarinet",
    73: "flute", 80: "square lead", 105: "banjo", 108: "kalimba",
}  # fmt: skip


@dataclass(frozen=True)
class Profile:
    """How big a corpus is. `default` is the real corpus; `small` builds in seconds for tests."""

    name: str
    espeak_train: int
    espeak_unheard: int
    recorded_train: tuple[tuple[str, str], ...]  # (engine, voice)
    recorded_unheard: tuple[tuple[str, str], ...]
    variations: int  # per speaker and word
    phrase_variations: int  # per speaker and wording
    train_programs: tuple[int, ...]
    held_out_programs: tuple[int, ...]
    velocities: tuple[int, ...]
    note_durations_s: tuple[float, ...]
    recording_variations: dict[str, int] = field(default_factory=dict)  # per recording "speaker" and split


DEFAULT = Profile(
    name="default",
    espeak_train=32,
    espeak_unheard=10,
    recorded_train=(
        ("flite", "kal"),
        ("flite", "kal16"),
        ("flite", "slt"),
        ("festival", "kal_diphone"),
        ("festival", "cmu_us_slt_arctic_hts"),
    ),
    recorded_unheard=(("flite", "awb"), ("flite", "rms"), ("festival", "ked_diphone")),
    variations=5,
    phrase_variations=2,
    train_programs=(0, 4, 6, 11, 12, 16, 21, 24, 26, 40, 42, 48, 56, 65, 71, 73, 80, 105),
    held_out_programs=(1, 8, 19, 25, 41, 60, 68, 108),
    velocities=(50, 80, 110),
    note_durations_s=(0.3, 0.6, 1.0),
    recording_variations={TRAIN: 60, UNHEARD_REAL_VOICES: 20},
)

SMALL = Profile(
    name="small",
    espeak_train=4,
    espeak_unheard=2,
    recorded_train=(("flite", "slt"), ("festival", "kal_diphone")),
    recorded_unheard=(("flite", "awb"), ("festival", "ked_diphone")),
    variations=2,
    phrase_variations=1,
    train_programs=(0, 40, 73),
    held_out_programs=(41,),
    velocities=(90,),
    note_durations_s=(0.3, 0.6),
    recording_variations={TRAIN: 4, UNHEARD_REAL_VOICES: 2},
)

PROFILES = {p.name: p for p in (DEFAULT, SMALL)}


@dataclass(frozen=True)
class MixedVoices:
    """Mixed voices: espeak-ng variants written for training only. Each formant's frequency, strength and
    width (in % of espeak-ng's defaults) and the pitch range are drawn from ranges about as wide as the
    training variants' own, so training hears voices between and around its 24 named variants."""

    formants: tuple[int, ...] = (1, 2, 3, 4, 5)
    frequency: tuple[int, int] = (70, 140)
    strength: tuple[int, int] = (60, 120)
    width: tuple[int, int] = (75, 150)
    pitch_low_hz: tuple[int, int] = (65, 170)  # the high end of the pitch range is 1.3-1.6 times the low end


@dataclass(frozen=True)
class MultilingualSize:
    """Speakers per language of a multilingual set (kept apart from Profile, whose fields are in every other
    set's recipe)."""

    train: int
    unheard: int
    room: int
    variations: int  # per speaker and word
    mixed: int = 0  # training speakers with a mixed voice, on top of `train`
    mixed_voices: MixedVoices = MixedVoices()  # what they are drawn from (in the recipe, as every field here)


MULTILINGUAL_SIZES = {
    "default": MultilingualSize(train=32, unheard=12, room=4, variations=3, mixed=64),
    "small": MultilingualSize(train=2, unheard=1, room=1, variations=1, mixed=1),
}


def unheard_language(code: str) -> str:
    """The tier of a language's unheard speakers."""
    return f"unheard-{code}"


@dataclass(frozen=True)
class Speaker:
    """One voice (or instrument): `id` is unique across the corpus and names exactly one split."""

    id: str
    engine: str  # "espeak-ng", "flite", "festival", "fluidsynth" or "recording"
    voice: str  # engine voice / variant, GM program, or recording file
    split: str
    accent: str = ""
    pitch: int = 0
    speed: int = 0
    soundfont: str = ""
    program: int = -1
    variant_text: str = ""  # a mixed voice's espeak-ng variant file (its `voice` is then only its name)

    def params(self) -> dict[str, object]:
        params: dict[str, object] = {"voice": self.voice}
        if self.engine == "espeak-ng":
            params.update(accent=self.accent, pitch=self.pitch, speed=self.speed)
        if self.variant_text:
            params["variant_text"] = self.variant_text
        if self.engine == "fluidsynth":
            params.update(soundfont=self.soundfont, program=self.program)
        return params


def speech_speakers(profile: Profile, seed: int) -> list[Speaker]:
    """Every speaker of the speech sets, deterministic for `seed`."""
    rng = np.random.default_rng([seed, 1])
    speakers = _espeak_speakers(rng, profile.espeak_train, TRAIN_VARIANTS, TRAIN_ACCENTS, TRAIN, "t")
    speakers += _espeak_speakers(
        rng, profile.espeak_unheard, HELD_OUT_VARIANTS, HELD_OUT_ACCENTS, UNHEARD_EASY, "u"
    )
    for split, voices in ((TRAIN, profile.recorded_train), (UNHEARD_REAL_VOICES, profile.recorded_unheard)):
        speakers += [
            Speaker(id=f"{engine}:{voice}", engine=engine, voice=voice, split=split)
            for engine, voice in voices
        ]
    return speakers


def multilingual_speakers(
    languages: tuple[Language, ...], size: MultilingualSize, seed: int
) -> list[tuple[Language, Speaker]]:
    """Every speaker of a multilingual set with the language it speaks, deterministic for `seed` (its accent
    is one of that language's espeak-ng voices). Each tier draws from its own stream, so one tier's size
    never changes another tier's speakers."""
    speakers = []
    for index, language in enumerate(languages):
        tiers = (
            (TRAIN_VARIANTS, language.train_accents, TRAIN, size.train, "t"),
            (
                HELD_OUT_VARIANTS,
                language.held_out_accents,
                unheard_language(language.code),
                size.unheard,
                "u",
            ),
            (HELD_OUT_VARIANTS, language.held_out_accents, UNHEARD_ROOM, size.room, "r"),
        )
        for stream, (variants, accents, split, count, tag) in enumerate(tiers):
            rng = np.random.default_rng([seed, 2, index, stream])
            drawn = _espeak_speakers(rng, count, variants, accents, split, f"{language.code}-{tag}")
            speakers += [(language, speaker) for speaker in drawn]
        rng = np.random.default_rng([seed, 2, index, len(tiers)])
        mixed = _mixed_speakers(rng, size, language.train_accents, f"{language.code}-x")
        speakers += [(language, speaker) for speaker in mixed]
    return speakers


def mixed_variant(rng: np.random.Generator, name: str, ranges: MixedVoices) -> str:
    """An espeak-ng voice variant file with formants and pitch drawn from `ranges`."""
    low = int(rng.integers(*ranges.pitch_low_hz, endpoint=True))
    lines = ["language variant", f"name {name}", f"pitch {low} {round(low * rng.uniform(1.3, 1.6))}"]
    for formant in ranges.formants:
        bounds = (ranges.frequency, ranges.strength, ranges.width)
        settings = (int(rng.integers(*low_high, endpoint=True)) for low_high in bounds)
        lines.append(f"formant {formant} {' '.join(map(str, settings))}")
    return "\n".join(lines) + "\n"


def _mixed_speakers(
    rng: np.random.Generator, size: MultilingualSize, accents: tuple[str, ...], tag: str
) -> list[Speaker]:
    speakers = []
    for index in range(size.mixed):
        name = f"mix{index:02d}"
        variant_text = mixed_variant(rng, name, size.mixed_voices)
        speakers.append(_espeak_speaker(rng, f"{tag}{index:02d}", name, accents, TRAIN, variant_text))
    return speakers


def instruments(profile: Profile) -> list[Speaker]:
    """The notes set's "speakers": one per (soundfont, GM program)."""

    def instrument(soundfont: str, program: int, split: str) -> Speaker:
        return Speaker(
            id=f"{soundfont}:{program:03d}",
            engine="fluidsynth",
            voice=GM_PROGRAMS[program],
            split=split,
            soundfont=soundfont,
            program=program,
        )

    every_program = sorted(profile.train_programs + profile.held_out_programs)
    return (
        [instrument(SOUNDFONT_TRAIN, p, TRAIN) for p in profile.train_programs]
        + [instrument(SOUNDFONT_TRAIN, p, UNHEARD_INSTRUMENT) for p in profile.held_out_programs]
        + [instrument(SOUNDFONT_HELD_OUT, p, UNHEARD_SOUNDFONT) for p in every_program]
    )


def _espeak_speakers(
    rng: np.random.Generator,
    count: int,
    variants: tuple[str, ...],
    accents: tuple[str, ...],
    split: str,
    tag: str,
) -> list[Speaker]:
    order = rng.permutation(len(variants))
    return [
        _espeak_speaker(rng, f"{tag}{index:02d}", variants[order[index % len(variants)]], accents, split)
        for index in range(count)
    ]


def _espeak_speaker(
    rng: np.random.Generator,
    label: str,
    variant: str,
    accents: tuple[str, ...],
    split: str,
    variant_text: str = "",
) -> Speaker:
    accent = accents[int(rng.integers(len(accents)))]
    pitch = int(rng.integers(ESPEAK_PITCH[0], ESPEAK_PITCH[1] + 1))
    speed = int(rng.integers(ESPEAK_SPEED[0], ESPEAK_SPEED[1] + 1))
    return Speaker(
        id=f"espeak-ng:{label}-{variant}-{accent}-p{pitch}-s{speed}",
        engine="espeak-ng",
        voice=variant,
        split=split,
        accent=accent,
        pitch=pitch,
        speed=speed,
        variant_text=variant_text,
    )
