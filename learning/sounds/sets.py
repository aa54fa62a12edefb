"""What each sound set says or plays. Intent k of a set = intent k of the world (Kuka slot k ↔ "zero"… ↔ C4…;
TurtleBot object k ↔ "house"… ↔ the k-th shape)."""

from dataclasses import dataclass


@dataclass(frozen=True)
class Language:
    """One language of a multilingual set: the espeak-ng voice that speaks it and its words per intent."""

    code: str  # espeak-ng language voice; names the language's unheard tier, unheard-<code>
    name: str
    words: tuple[str, ...]  # per intent
    train_accents: tuple[str, ...]  # espeak-ng voices of this language the training speakers use
    held_out_accents: tuple[str, ...]  # and those of the unheard speakers (the same when it has one)


@dataclass(frozen=True)
class SoundSet:
    name: str
    kind: str  # feature kind (learning.audio.FEATURE_KINDS)
    intent_names: tuple[str, ...]
    wordings: tuple[tuple[str, ...], ...] = ()  # per intent; empty for notes
    description: str = ""
    languages: tuple[Language, ...] = ()  # a multilingual set: every speaker speaks one of these


WORDSET = SoundSet(
    "wordset",
    "speech",
    ("zero", "one", "two", "three"),
    (("zero",), ("one",), ("two",), ("three",)),
    "the digits zero..three (Kuka/Kinova slots left to right)",
)

OBJECTS = SoundSet(
    "objects",
    "speech",
    ("house", "tree", "bird", "dog"),
    (("house",), ("tree",), ("bird",), ("dog",)),
    "the paper's object words (TurtleBot intents)",
)

PHRASES_BLOCKS = SoundSet(
    "phrases_blocks",
    "phrase",
    ("slot 0", "slot 1", "slot 2", "slot 3"),
    (
        (
            "block zero",
            "go to block zero",
            "the first block",
            "the left-most block",
            "go to the block on the far left",
            "number zero please",
        ),
        (
            "block one",
            "go to block one",
            "the second block",
            "the second block from the left",
            "go to the left middle block",
            "number one please",
        ),
        (
            "block two",
            "go to block two",
            "the third block",
            "the second block from the right",
            "go to the right middle block",
            "number two please",
        ),
        (
            "block three",
            "go to block three",
            "the fourth block",
            "the right-most block",
            "go to the block on the far right",
            "number three please",
        ),
    ),
    "household wordings for the Kuka/Kinova slots",
)

PHRASES_OBJECTS = SoundSet(
    "phrases_objects",
    "phrase",
    ("cube", "sphere", "cone", "cylinder"),
    (
        (
            "the cube",
            "go to the cube",
            "find the box",
            "drive to the square block",
            "where is the cube",
            "cube please",
        ),
        (
            "the sphere",
            "go to the ball",
            "find the ball",
            "drive to the round ball",
            "where is the sphere",
            "sphere please",
        ),
        (
            "the cone",
            "go to the cone",
            "find the cone",
            "drive to the pointy cone",
            "where is the cone",
            "cone please",
        ),
        (
            "the cylinder",
            "go to the cylinder",
            "find the can",
            "drive to the tall cylinder",
            "where is the cylinder",
            "cylinder please",
        ),
    ),
    "household wordings for the TurtleBot objects (cube, sphere, cone, cylinder)",
)

NOTES = SoundSet(
    "notes",
    "sound",
    ("C4", "D4", "E4", "F4"),
    description="C4, D4, E4, F4 played by General-MIDI instruments (fluidsynth)",
)

MIX = SoundSet(
    "mix",
    "speech",
    ("house", "tree", "bird", "dog"),
    (("house",), ("tree",), ("bird",), ("dog",)),
    'the Objects set, plus a jackhammer for "house" and dog barks for "dog" (real recordings)',
)

# The Wordset's four intents in six languages. Mandarin is written in digits: this espeak-ng's cmn dictionary
# reads 零 and 三 as English letters, and reads 0 1 2 3 as líng yī èr sān.
LANGUAGES = (
    Language(
        "en",
        "English",
        ("zero", "one", "two", "three"),
        ("en-us", "en-gb-x-rp"),
        ("en-gb-scotland", "en-029"),
    ),
    Language("de", "German", ("null", "eins", "zwei", "drei"), ("de",), ("de",)),
    Language("es", "Spanish", ("cero", "uno", "dos", "tres"), ("es",), ("es-419",)),
    # "fr", not "fr-fr": espeak-ng 1.51 resolves "fr-fr+m1" among several voices claiming fr-fr and drops the
    # variant, so every "fr-fr" speaker had the same voice (tests/learning/test_sounds_multilingual.py)
    Language("fr", "French", ("zéro", "un", "deux", "trois"), ("fr",), ("fr-be", "fr-ch")),
    Language("cmn", "Mandarin", ("0", "1", "2", "3"), ("cmn",), ("cmn",)),
    Language("ru", "Russian", ("ноль", "один", "два", "три"), ("ru",), ("ru-lv",)),
)

WORDSET_MULTILINGUAL = SoundSet(
    "wordset-multilingual",
    "speech",
    ("zero", "one", "two", "three"),
    tuple(tuple(language.words[intent] for language in LANGUAGES) for intent in range(4)),
    "the Wordset's zero..three in English, German, Spanish, French, Mandarin and Russian (espeak-ng), "
    "with unheard speakers per language and in simulated rooms",
    LANGUAGES,
)

SOUND_SETS: dict[str, SoundSet] = {
    s.name: s for s in (WORDSET, OBJECTS, PHRASES_BLOCKS, PHRASES_OBJECTS, NOTES, MIX, WORDSET_MULTILINGUAL)
}
SET_NAMES: tuple[str, ...] = tuple(SOUND_SETS)
# the paper's sets (and Objects, which Mix builds on); the phrase sets are built on request (`--sets all`)
DEFAULT_SETS: tuple[str, ...] = ("wordset", "objects", "notes", "mix")

NOTE_MIDI = {"C4": 60, "D4": 62, "E4": 64, "F4": 65}


def sound_set(name: str) -> SoundSet:
    try:
        return SOUND_SETS[name]
    except KeyError:
        raise ValueError(f"Unknown sound set {name!r}: use one of {', '.join(SET_NAMES)}.") from None
