"""A robot's room: how its simulated world looks (colours, textures, camera, light), and the rule that reads
it from the robot's settings.

`settings["domain"]` is absent (the training room), the name of a preset ("unseen_room", "lamplit_room"),
or DomainShift fields. The API checks it when a robot is created or changed; the worker renders captures and
evaluations in it. `DomainShift` lives here, in plain Python, so that the API can check a room without
importing the simulator; `sim.domain` re-exports it for the worlds.

`RoomRanges` are the rooms base models are trained over (a world given them draws a new room at every
reset); the held-out presets lie outside them, by a margin in at least one knob (`held_out_knobs`).
"""

import colorsys
import dataclasses
import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from core.plain import as_lists

TEXTURES = ("checker", "noise", "stripes", "speckle", "blotch")  # sim.textures draws each

_Rgb = tuple[float, float, float]


@dataclass(frozen=True)
class DomainShift:
    """Every knob at its default reproduces the training room exactly.

    Colours are RGB in [0, 1]; `None` keeps the world's own colour.
    """

    object_rgb: _Rgb | None = None
    floor_rgb: _Rgb | None = None
    floor_texture: str | None = None  # "checker", "noise" or None (plain)
    object_texture: str | None = None  # "checker", "noise" or None (plain)
    camera_jitter_m: float = 0.0  # uniform jitter of the camera eye, per episode
    camera_jitter_deg: float = 0.0  # uniform jitter of the look-at direction, per episode
    light_direction: tuple[float, float, float] | None = None
    light_ambient: float | None = None  # tiny-renderer ambient coefficient
    light_diffuse: float | None = None  # tiny-renderer diffuse coefficient

    @classmethod
    def unseen_room(cls) -> "DomainShift":
        """A ready-made shifted room: other colours and textures, a nudged camera, other light."""
        return cls(
            object_rgb=(0.85, 0.55, 0.1),
            floor_rgb=(0.35, 0.45, 0.6),
            floor_texture="checker",
            camera_jitter_m=0.02,
            camera_jitter_deg=2.0,
            light_direction=(-0.5, 0.8, 1.0),
            light_ambient=0.5,
            light_diffuse=0.45,
        )

    @classmethod
    def lamplit_room(cls) -> "DomainShift":
        """A second held-out room, unlike the first: teal checkered objects on a mottled purple floor, dim
        light from a low lamp at the side, a camera placed further off."""
        return cls(
            object_rgb=(0.1, 0.65, 0.6),
            floor_rgb=(0.45, 0.3, 0.5),
            object_texture="checker",
            floor_texture="noise",
            camera_jitter_m=0.06,
            camera_jitter_deg=5.0,
            light_direction=(0.9, -0.2, 0.25),
            light_ambient=0.3,
            light_diffuse=0.65,
        )


ROOM_PRESETS: dict[str, Callable[[], DomainShift]] = {
    "unseen_room": DomainShift.unseen_room,
    "lamplit_room": DomainShift.lamplit_room,
}
HELD_OUT_ROOMS = ("unseen_room", "lamplit_room")

_FIELDS = [field.name for field in dataclasses.fields(DomainShift)]


def room_of(settings: Mapping[str, Any]) -> DomainShift | None:
    """The room `settings["domain"]` describes, or None for the training room; a ValueError says what is
    wrong with a room that cannot be built."""
    room = settings.get("domain")
    if not room:
        return None
    if isinstance(room, str):
        if room not in ROOM_PRESETS:
            raise ValueError(f"unknown room {room!r} in settings.domain; presets: {', '.join(ROOM_PRESETS)}")
        return ROOM_PRESETS[room]()
    if not isinstance(room, Mapping):
        raise ValueError("settings.domain is a preset name or an object of DomainShift fields")
    unknown = sorted(set(room) - set(_FIELDS))
    if unknown:
        raise ValueError(f"unknown settings.domain field(s) {unknown}; known: {', '.join(_FIELDS)}")
    return DomainShift(**{name: _checked(name, value) for name, value in room.items()})


def _checked(name: str, value: Any) -> Any:
    """One DomainShift field as JSON gives it (lists for tuples), checked; None keeps the default."""
    where = f"settings.domain.{name}"
    if value is None:
        return DomainShift.__dataclass_fields__[name].default
    if name.endswith("_texture"):
        if value not in TEXTURES:
            raise ValueError(f"{where} is one of {', '.join(TEXTURES)} (or null for plain), not {value!r}")
        return value
    if name.endswith(("_rgb", "_direction")):
        if not isinstance(value, list | tuple) or len(value) != 3 or not all(map(_is_number, value)):
            raise ValueError(f"{where} is a list of three numbers, not {value!r}")
        if name.endswith("_rgb") and not all(0.0 <= v <= 1.0 for v in value):
            raise ValueError(f"{where} holds colours in [0, 1], not {value!r}")
        return tuple(float(v) for v in value)
    if not _is_number(value) or value < 0:
        raise ValueError(f"{where} is a number of at least 0, not {value!r}")
    return float(value)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


# --- training ranges: the rooms a base model is trained over ----------------------------------------------

_Interval = tuple[float, float]


@dataclass(frozen=True)
class ColourRange:
    """Colours as HSV: a hue in one of `hues_deg` (intervals, degrees; -30..15 wraps through red), and a
    saturation and value in their intervals."""

    hues_deg: tuple[_Interval, ...]
    saturation: _Interval
    value: _Interval


@dataclass(frozen=True)
class RoomRanges:
    """The rooms a base model is trained over: every episode draws one room from these ranges (plain data).

    They span what a home camera placement plausibly sees: tables and floors of wood, stone, beige, grey
    and green; objects of most colours; plain, mottled, striped (planks), speckled (granite) or blotched (a
    two-tone print) surfaces; light from any side and from high up; a camera a few centimetres and degrees
    off. They leave out on purpose what the held-out rooms show: orange, cyan and magenta objects, blue and
    purple floors, checkered surfaces, dim or side light, a camera further off (`held_out_knobs` measures by
    how much).

    `own_look_share` is the chance that a knob group (object colour, floor colour, light) keeps the world's
    own look, so the training room itself stays in the mix. The camera's jitter is per episode within the
    given amplitudes. The worlds' own colours lie inside the ranges (tests/sim say so).
    """

    object_colour: ColourRange = ColourRange(
        ((-30.0, 15.0), (48.0, 160.0), (200.0, 290.0)), (0.5, 1.0), (0.45, 1.0)
    )
    floor_colour: ColourRange = ColourRange(((0.0, 70.0), (80.0, 170.0)), (0.0, 0.5), (0.35, 1.0))
    object_textures: tuple[str | None, ...] = (None, "noise", "stripes", "speckle", "blotch")
    floor_textures: tuple[str | None, ...] = (None, "noise", "stripes", "speckle", "blotch")
    camera_jitter_m: float = 0.04
    camera_jitter_deg: float = 3.0
    light_azimuth_deg: _Interval = (-180.0, 180.0)
    light_elevation_deg: _Interval = (35.0, 85.0)
    light_ambient: _Interval = (0.45, 0.75)
    light_diffuse: _Interval = (0.2, 0.5)
    own_look_share: float = 0.2


def sample_room(ranges: RoomRanges, rng: random.Random) -> DomainShift:
    """One room drawn from `ranges` (the same `rng` state draws the same room)."""
    own = ranges.own_look_share
    object_rgb = None if rng.random() < own else _sample_colour(ranges.object_colour, rng)
    floor_rgb = None if rng.random() < own else _sample_colour(ranges.floor_colour, rng)
    own_light = rng.random() < own
    azimuth, elevation = rng.uniform(*ranges.light_azimuth_deg), rng.uniform(*ranges.light_elevation_deg)
    ambient, diffuse = rng.uniform(*ranges.light_ambient), rng.uniform(*ranges.light_diffuse)
    return DomainShift(
        object_rgb=object_rgb,
        floor_rgb=floor_rgb,
        object_texture=rng.choice(ranges.object_textures),
        floor_texture=rng.choice(ranges.floor_textures),
        camera_jitter_m=ranges.camera_jitter_m,
        camera_jitter_deg=ranges.camera_jitter_deg,
        light_direction=None if own_light else _direction(azimuth, elevation),
        light_ambient=None if own_light else ambient,
        light_diffuse=None if own_light else diffuse,
    )


def _sample_colour(colours: ColourRange, rng: random.Random) -> _Rgb:
    lengths = [high - low for low, high in colours.hues_deg]
    low, high = rng.choices(colours.hues_deg, weights=lengths)[0]
    hue = rng.uniform(low, high) % 360.0
    red, green, blue = colorsys.hsv_to_rgb(
        hue / 360.0, rng.uniform(*colours.saturation), rng.uniform(*colours.value)
    )
    return (red, green, blue)


def _direction(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (
        math.cos(elevation) * math.cos(azimuth),
        math.cos(elevation) * math.sin(azimuth),
        math.sin(elevation),
    )


# --- held out: how far a room lies outside the training ranges ----------------------------------------------

# A held-out room differs from every room the ranges can produce in at least one knob by at least this much.
HELD_OUT_MARGINS: dict[str, float] = {
    "object_hue_deg": 10.0, "object_saturation": 0.1, "object_value": 0.1,
    "floor_hue_deg": 10.0, "floor_saturation": 0.1, "floor_value": 0.1,
    "object_texture": 1.0, "floor_texture": 1.0,  # a texture the ranges never draw
    "camera_jitter_m": 0.01, "camera_jitter_deg": 1.0,
    "light_azimuth_deg": 10.0, "light_elevation_deg": 10.0, "light_ambient": 0.05, "light_diffuse": 0.05,
}  # fmt: skip
HUE_VISIBLE = 0.25  # below this saturation or value a colour's hue is not seen, so it is not compared


def outside_by(ranges: RoomRanges, room: DomainShift) -> dict[str, float]:
    """For each knob, how far `room` lies outside `ranges` (0 inside, or where the room keeps the world's
    own look, which the ranges hold)."""
    distances = {
        **_colour_outside("object", ranges.object_colour, room.object_rgb),
        **_colour_outside("floor", ranges.floor_colour, room.floor_rgb),
        "object_texture": float(room.object_texture not in ranges.object_textures),
        "floor_texture": float(room.floor_texture not in ranges.floor_textures),
        "camera_jitter_m": max(0.0, room.camera_jitter_m - ranges.camera_jitter_m),
        "camera_jitter_deg": max(0.0, room.camera_jitter_deg - ranges.camera_jitter_deg),
        "light_ambient": _interval_outside(room.light_ambient, ranges.light_ambient),
        "light_diffuse": _interval_outside(room.light_diffuse, ranges.light_diffuse),
    }
    azimuth, elevation = _azimuth_elevation(room.light_direction)
    distances["light_azimuth_deg"] = _hue_outside(azimuth, [ranges.light_azimuth_deg])
    distances["light_elevation_deg"] = _interval_outside(elevation, ranges.light_elevation_deg)
    return distances


def held_out_knobs(ranges: RoomRanges, room: DomainShift) -> dict[str, float]:
    """The knobs in which `room` lies outside `ranges` by at least their margin, with the distance."""
    return {knob: d for knob, d in outside_by(ranges, room).items() if d >= HELD_OUT_MARGINS[knob]}


def _colour_outside(name: str, colours: ColourRange, rgb: _Rgb | None) -> dict[str, float]:
    if rgb is None:
        return {f"{name}_hue_deg": 0.0, f"{name}_saturation": 0.0, f"{name}_value": 0.0}
    hue, saturation, value = colorsys.rgb_to_hsv(*rgb)
    hue_seen = saturation >= HUE_VISIBLE and value >= HUE_VISIBLE
    return {
        f"{name}_hue_deg": _hue_outside(hue * 360.0, colours.hues_deg) if hue_seen else 0.0,
        f"{name}_saturation": _interval_outside(saturation, colours.saturation),
        f"{name}_value": _interval_outside(value, colours.value),
    }


def _interval_outside(value: float | None, interval: _Interval) -> float:
    if value is None:
        return 0.0
    low, high = interval
    return max(0.0, low - value, value - high)


def _hue_outside(angle_deg: float | None, intervals: tuple[_Interval, ...] | list[_Interval]) -> float:
    """Degrees round the circle from `angle_deg` to the nearest interval (0 inside one)."""
    if angle_deg is None:
        return 0.0
    return min(_arc_outside(angle_deg, low, high) for low, high in intervals)


def _arc_outside(angle_deg: float, low: float, high: float) -> float:
    if high - low >= 360.0:
        return 0.0
    offset = (angle_deg - low) % 360.0
    if offset <= high - low:
        return 0.0
    return min(offset - (high - low), 360.0 - offset)


def _azimuth_elevation(direction: tuple[float, float, float] | None) -> tuple[float | None, float | None]:
    if direction is None:
        return None, None
    x, y, z = direction
    return math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))


# --- rooms by name, for commands and configs ----------------------------------------------------------------

TRAINING_ROOM = "training"
RANDOMISED_ROOMS = "randomised"
ROOM_NAMES = (TRAINING_ROOM, RANDOMISED_ROOMS, *ROOM_PRESETS)
# Adapting a model to a room (learning.var.room_adaptation) needs at least this many of its camera views.
MIN_ROOM_VIEWS = 64
ROOM_VIEWS = 400  # how many of a robot's newest views it adapts to by default


def world_room(name: str | Mapping[str, Any]) -> "DomainShift | RoomRanges | None":
    """What a world is given for a room name: None for "training" (the world's own look), the training
    `RoomRanges` for "randomised" (a new room every reset), or a preset's room. A mapping of DomainShift
    fields (`room_setting`: a household robot's own room) is that room; `{"ranges": fields}`
    (`ranges_setting`: the ranges a base model was trained over, as its record keeps them) are those ranges.
    `ROOM[knob=value,...]` is the training room or a preset with some knobs changed (benches: which knob
    makes a room hard)."""
    if isinstance(name, Mapping):
        return ranges_from_fields(name["ranges"]) if set(name) == {"ranges"} else room_of({"domain": name})
    if name.endswith("]") and "[" in name:
        return _room_with_knobs(name)
    if name == TRAINING_ROOM:
        return None
    if name == RANDOMISED_ROOMS:
        return RoomRanges()
    if name in ROOM_PRESETS:
        return ROOM_PRESETS[name]()
    raise ValueError(f"unknown room {name!r}: choose one of {', '.join(ROOM_NAMES)}")


def _room_with_knobs(name: str) -> DomainShift:
    """`lamplit_room[camera_jitter_m=0,floor_texture=none,object_rgb=1/0/0]`: the room with those knobs set.
    A value is a number, a texture name, three numbers joined by `/` (a colour or a light direction), or
    `none` (the world's own colour, a plain surface, the default light)."""
    base_name, knobs = name[:-1].split("[", 1)
    base = world_room(base_name)
    if isinstance(base, RoomRanges):
        raise ValueError(f"{name!r}: knobs change one room, not the ranges of {RANDOMISED_ROOMS!r}")
    fields = dataclasses.asdict(base or DomainShift())
    for knob in filter(None, knobs.split(",")):
        field_name, _, text = knob.partition("=")
        if field_name not in _FIELDS:
            raise ValueError(f"{name!r}: {field_name!r} is not a knob; these are: {', '.join(_FIELDS)}")
        fields[field_name] = _checked(field_name, _knob_value(name, field_name, text))  # a robot's rule
    return DomainShift(**fields)


def _knob_value(name: str, field_name: str, text: str) -> Any:
    if text == "none":
        return None
    if field_name.endswith("_texture"):
        return text
    try:
        if field_name.endswith(("_rgb", "_direction")):
            return [float(part) for part in text.split("/")]
        return float(text)
    except ValueError:
        raise ValueError(f"{name!r}: {field_name} takes a number, not {text!r}") from None


def ranges_setting(ranges: RoomRanges) -> dict[str, Any]:
    """Ranges as a config value that `world_room` reads back, in the lists JSON gives back."""
    return {"ranges": as_lists(dataclasses.asdict(ranges))}


def ranges_from_fields(fields: Mapping[str, Any]) -> RoomRanges:
    """The `RoomRanges` whose fields (as `dataclasses.asdict` and JSON give them) are `fields`; a field that
    today's ranges lack is refused (an older record keeps fewer knobs, a newer one may keep more)."""
    known = {field.name for field in dataclasses.fields(RoomRanges)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise ValueError(f"unknown room range field(s) {unknown}; known: {', '.join(sorted(known))}")
    values: dict[str, Any] = {}
    today = RoomRanges()
    for name, value in fields.items():
        if isinstance(getattr(today, name), ColourRange):
            hues = tuple(tuple(interval) for interval in value["hues_deg"])
            values[name] = ColourRange(hues, tuple(value["saturation"]), tuple(value["value"]))
        else:
            values[name] = tuple(value) if isinstance(value, list) else value
    return RoomRanges(**values)


def room_setting(room: DomainShift | None) -> str | dict[str, Any]:
    """A room as a config value that `world_room` reads back: "training" for None, else its DomainShift
    fields as JSON gives them back (lists, not tuples), so a config read from disk compares equal to it."""
    if room is None:
        return TRAINING_ROOM
    return as_lists(dataclasses.asdict(room))
