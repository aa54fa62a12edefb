"""A robot's room (core.rooms): `settings["domain"]` is absent (the training room), a preset's name, or
DomainShift fields; anything else is refused with a message that says what is wrong. Base models train over
rooms drawn from `RoomRanges`; the held-out presets lie outside every room those ranges can draw."""

import colorsys
import dataclasses
import json
import math
import random
import re

import pytest

from core.rooms import (
    HELD_OUT_MARGINS,
    HELD_OUT_ROOMS,
    ROOM_PRESETS,
    DomainShift,
    RoomRanges,
    held_out_knobs,
    outside_by,
    ranges_from_fields,
    ranges_setting,
    room_of,
    sample_room,
    world_room,
)


def test_a_robot_without_a_room_is_in_the_training_room() -> None:
    assert room_of({}) is None
    assert room_of({"domain": None}) is None
    assert room_of({"domain": {}}) is None
    assert DomainShift() == DomainShift(), "every knob at its default is the training room"


def test_a_preset_names_a_ready_made_room() -> None:
    assert room_of({"domain": "unseen_room"}) == DomainShift.unseen_room()
    assert room_of({"domain": "lamplit_room"}) == DomainShift.lamplit_room()
    assert set(ROOM_PRESETS) == {"unseen_room", "lamplit_room"} == set(HELD_OUT_ROOMS)


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
        ("kitchen", "unknown room 'kitchen' in settings.domain; presets: unseen_room, lamplit_room"),
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
            "settings.domain.floor_texture is one of checker, noise, stripes, speckle, blotch (or null for "
            "plain)",
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


def test_the_training_ranges_draw_a_different_room_each_time_and_the_same_room_from_the_same_seed() -> None:
    ranges = RoomRanges()
    rooms = [sample_room(ranges, random.Random(seed)) for seed in range(50)]
    assert rooms[7] == sample_room(ranges, random.Random(7))
    assert len({room.object_rgb for room in rooms}) > 30, "object colours vary"
    assert len({room.floor_rgb for room in rooms}) > 30, "floor colours vary"
    assert {room.floor_texture for room in rooms} == {None, "noise", "stripes", "speckle", "blotch"}
    assert {room.object_texture for room in rooms} == {None, "noise", "stripes", "speckle", "blotch"}
    assert None in {room.light_direction for room in rooms}, "some rooms keep the world's own light"
    assert all(outside_by(ranges, room) == dict.fromkeys(HELD_OUT_MARGINS, 0.0) for room in rooms)


def test_each_held_out_room_lies_outside_the_training_ranges_by_a_margin() -> None:
    ranges = RoomRanges()
    assert set(held_out_knobs(ranges, DomainShift.unseen_room())) == {
        "object_hue_deg", "floor_hue_deg", "floor_texture"
    }  # fmt: skip
    assert set(held_out_knobs(ranges, DomainShift.lamplit_room())) >= {
        "object_hue_deg", "floor_hue_deg", "object_texture", "camera_jitter_m", "camera_jitter_deg",
        "light_ambient", "light_diffuse", "light_elevation_deg",
    }  # fmt: skip
    assert held_out_knobs(ranges, DomainShift()) == {}, "the training room is inside"


@pytest.mark.parametrize("preset", HELD_OUT_ROOMS)
def test_no_room_the_ranges_draw_comes_within_the_margin_of_a_held_out_room_in_every_knob(
    preset: str,
) -> None:
    """The same claim checked against the sampler itself: every drawn room differs from the preset in at least
    one knob by at least that knob's margin."""
    held_out = ROOM_PRESETS[preset]()
    rng = random.Random(0)
    for _ in range(3000):
        drawn = sample_room(RoomRanges(own_look_share=0.0), rng)
        differences = _differences(drawn, held_out)
        assert any(differences[knob] >= HELD_OUT_MARGINS[knob] for knob in differences), (drawn, differences)


def test_rooms_by_name_are_the_training_room_the_training_ranges_or_a_preset() -> None:
    assert world_room("training") is None
    assert world_room("randomised") == RoomRanges()
    assert world_room("lamplit_room") == DomainShift.lamplit_room()
    with pytest.raises(
        ValueError, match="unknown room 'attic': choose one of training, randomised, unseen_room"
    ):
        world_room("attic")


def test_ranges_a_record_kept_are_read_back_as_those_ranges_even_after_todays_ranges_grew() -> None:
    older = RoomRanges(object_textures=(None, "noise"), floor_textures=(None, "noise"), own_look_share=0.3)
    setting = json.loads(json.dumps(ranges_setting(older)))  # as a run's config.json keeps it
    assert world_room(setting) == older != RoomRanges()
    assert sample_room(world_room(setting), random.Random(4)) == sample_room(older, random.Random(4))


def test_ranges_with_a_knob_todays_ranges_lack_are_refused_saying_which() -> None:
    fields = {**ranges_setting(RoomRanges())["ranges"], "ceiling_colour": [0, 1]}
    with pytest.raises(ValueError, match=r"unknown room range field\(s\) \['ceiling_colour'\]"):
        ranges_from_fields(fields)


def test_a_room_name_can_change_a_presets_numeric_knobs_to_find_which_one_makes_it_hard() -> None:
    still = world_room("lamplit_room[camera_jitter_m=0,camera_jitter_deg=0]")
    lamplit = DomainShift.lamplit_room()
    assert still == dataclasses.replace(lamplit, camera_jitter_m=0.0, camera_jitter_deg=0.0)
    assert world_room("training[light_ambient=0.4]") == DomainShift(light_ambient=0.4)


def test_a_room_name_can_change_a_presets_colours_textures_and_light_or_set_them_to_the_worlds_own() -> None:
    plain = world_room("unseen_room[floor_texture=none,object_rgb=none]")
    assert plain == dataclasses.replace(DomainShift.unseen_room(), floor_texture=None, object_rgb=None)
    assert world_room("training[object_texture=checker,floor_rgb=0.2/0.3/0.9]") == DomainShift(
        object_texture="checker", floor_rgb=(0.2, 0.3, 0.9)
    )
    assert world_room("lamplit_room[light_direction=0/0/1]").light_direction == (0.0, 0.0, 1.0)


@pytest.mark.parametrize(
    ("name", "says"),
    [
        ("randomised[camera_jitter_m=0]", "knobs change one room"),
        ("lamplit_room[shine=1]", "'shine' is not a knob; these are: object_rgb, floor_rgb"),
        ("lamplit_room[object_rgb=1]", "a list of three numbers, not [1.0]"),
        ("lamplit_room[object_rgb=red]", "object_rgb takes a number, not 'red'"),
        ("lamplit_room[floor_texture=tiles]", "(or null for plain), not 'tiles'"),
        ("lamplit_room[camera_jitter_m=far]", "takes a number, not 'far'"),
        ("lamplit_room[camera_jitter_m=-1]", "at least 0"),
        ("attic[camera_jitter_m=0]", "unknown room 'attic'"),
    ],
)
def test_a_room_name_with_knobs_it_cannot_take_says_what_is_wrong(name: str, says: str) -> None:
    with pytest.raises(ValueError, match=re.escape(says)):
        world_room(name)


def _differences(drawn: DomainShift, held_out: DomainShift) -> dict[str, float]:
    """Knob by knob, how far `held_out` is from `drawn` (the camera: how much further it can move)."""
    differences = {
        "object_texture": float(drawn.object_texture != held_out.object_texture),
        "floor_texture": float(drawn.floor_texture != held_out.floor_texture),
        "camera_jitter_m": held_out.camera_jitter_m - drawn.camera_jitter_m,
        "camera_jitter_deg": held_out.camera_jitter_deg - drawn.camera_jitter_deg,
        "light_ambient": abs(held_out.light_ambient - drawn.light_ambient),
        "light_diffuse": abs(held_out.light_diffuse - drawn.light_diffuse),
    }
    for name in ("object", "floor"):
        (h1, s1, v1), (h2, s2, v2) = (
            colorsys.rgb_to_hsv(*getattr(room, f"{name}_rgb")) for room in (drawn, held_out)
        )
        hue = abs(h1 - h2) * 360.0
        differences[f"{name}_hue_deg"] = min(hue, 360.0 - hue) if s2 >= 0.25 and v2 >= 0.25 else 0.0
        differences[f"{name}_saturation"], differences[f"{name}_value"] = abs(s1 - s2), abs(v1 - v2)
    (a1, e1), (a2, e2) = (_angles(room.light_direction) for room in (drawn, held_out))
    azimuth = abs(a1 - a2) % 360.0
    differences["light_azimuth_deg"] = min(azimuth, 360.0 - azimuth)
    differences["light_elevation_deg"] = abs(e1 - e2)
    return differences


def _angles(direction: tuple[float, float, float]) -> tuple[float, float]:
    x, y, z = direction
    return math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))
