"""A robot's room: how its simulated world looks (colours, textures, camera, light), and the rule that reads
it from the robot's settings.

`settings["domain"]` is absent (the training room), the name of a preset ("unseen_room"), or DomainShift
fields. The API checks it when a robot is created or changed; the worker renders captures and evaluations in
it. `DomainShift` lives here, in plain Python, so that the API can check a room without importing the
simulator; `sim.domain` re-exports it for the worlds.
"""

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

TEXTURES = ("checker", "noise")

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


ROOM_PRESETS: dict[str, Callable[[], DomainShift]] = {"unseen_room": DomainShift.unseen_room}

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
