"""A robot's room (core.rooms): `settings["domain"]` is absent (the training room), a preset's name, or
DomainShift fields; anything else is refused with a message that says what is wrong."""

import pytest

from core.rooms import ROOM_PRESETS, DomainShift, room_of


def test_a_robot_without_a_room_is_in_the_training_room() -> None:
    assert room_of({}) is None
    assert room_of({"domain": None}) is None
    assert room_of({"domain": {}}) is None
    assert DomainShift() == DomainShift(), "every knob at its default is the training room"


def test_a_preset_names_a_ready_made_room() -> None:
    assert room_of({"domain": "unseen_room"}) == DomainShift.unseen_room()
    assert set(ROOM_PRESETS) == {"unseen_room"}


def test_fields_build_the_room_with_json_lists_as_tuples() -> None:
    room = room_of({"domain": {"floor_rgb": [0.1, 0.2, 0.3], "floor_texture": "noise", "camera_jitter_m": 1}})
    assert room == DomainShift(floor_rgb=(0.1, 0.2, 0.3), floor_texture="noise", camera_jitter_m=1.0)
    assert room_of({"domain": {"light_direction": [-1, 0, 2], "object_rgb": None}}) == DomainShift(
        light_direction=(-1.0, 0.0, 2.0)
    ), "null keeps a knob's default"


def test_the_simulator_renders_the_same_room_type() -> None:
    from sim.domain import DomainShift as SimulatedShift

    assert SimulatedShift is DomainShift


@pytest.mark.parametrize(
    ("domain", "message"),
    [
        ("kitchen", "unknown room 'kitchen' in settings.domain; presets: unseen_room"),
        (["unseen_room"], "settings.domain is a preset name or an object of DomainShift fields"),
        (
            {"wall_rgb": [0, 0, 0]},
            "unknown settings.domain field(s) ['wall_rgb']; known: object_rgb, floor_rgb",
        ),
        ({"floor_rgb": [0.1, 0.2]}, "settings.domain.floor_rgb is a list of three numbers"),
        ({"floor_rgb": "blue"}, "settings.domain.floor_rgb is a list of three numbers"),
        ({"object_rgb": [0, 128, 255]}, "settings.domain.object_rgb holds colours in [0, 1]"),
        (
            {"floor_texture": "marble"},
            "settings.domain.floor_texture is one of checker, noise (or null for plain)",
        ),
        ({"camera_jitter_deg": -1}, "settings.domain.camera_jitter_deg is a number of at least 0"),
        ({"light_ambient": True}, "settings.domain.light_ambient is a number of at least 0"),
        ({"light_diffuse": float("nan")}, "settings.domain.light_diffuse is a number of at least 0"),
    ],
)
def test_a_room_that_cannot_be_built_is_refused_saying_why(domain: object, message: str) -> None:
    with pytest.raises(ValueError) as refusal:
        room_of({"domain": domain})
    assert str(refusal.value).startswith(message)
