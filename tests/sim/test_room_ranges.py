"""Every world trains over randomised rooms: given `RoomRanges` as its domain it draws a new room at every
reset, seeded by the reset's seed, without changing the task that seed gives; the worlds' own looks lie inside
the ranges, and a room that keeps them renders exactly as the training room does."""

import gymnasium as gym
import numpy as np
import pytest

import sim
from core.rooms import HELD_OUT_MARGINS, RoomRanges, outside_by
from sim.blocks import BLOCK_RGBA
from sim.domain import DomainShift
from sim.turtlebot_arena import DEFAULT_FLOOR_RGB, OBJECTS

SMALL = 32
# the worlds' own colours and light; half the surfaces plain, the others mottled or striped
OWN_LOOK_ONLY = RoomRanges(
    own_look_share=1.0, camera_jitter_m=0.0, camera_jitter_deg=0.0,
    object_textures=(None, "noise"), floor_textures=(None, "stripes"),
)  # fmt: skip


def make(world: str, domain: object = None) -> gym.Env:
    return gym.make(sim.WORLDS[world], image_size=SMALL, domain=domain)


def task_of(env: gym.Env, info: dict) -> tuple:
    """What the seed decides about the task: the target, and where things are."""
    unwrapped = env.unwrapped
    if hasattr(unwrapped, "row_origin"):
        return info["intent"], tuple(unwrapped.row_origin), tuple(unwrapped.arm.target_xy)
    return info["intent"], tuple(unwrapped._pose), tuple(tuple(o.xy) for o in unwrapped._objects)


@pytest.mark.parametrize("world", list(sim.WORLDS))
def test_each_reset_draws_a_room_from_its_seed_and_the_seed_still_gives_the_same_task(world: str) -> None:
    randomised, fixed = make(world, RoomRanges()), make(world)
    try:
        rooms, images = [], []
        for seed in (1, 2, 1):
            observation, info = randomised.reset(seed=seed)
            _, fixed_info = fixed.reset(seed=seed)
            assert task_of(randomised, info) == task_of(fixed, fixed_info)
            rooms.append(randomised.unwrapped.domain)
            images.append(observation["image"])
        assert rooms[0] == rooms[2] and np.array_equal(images[0], images[2]), "same seed, same room"
        assert rooms[0] != rooms[1] and not np.array_equal(images[0], images[1]), "another seed, another room"
        assert all(outside_by(RoomRanges(), room) == dict.fromkeys(HELD_OUT_MARGINS, 0.0) for room in rooms)
    finally:
        randomised.close()
        fixed.close()


@pytest.mark.parametrize("world", list(sim.WORLDS))
def test_a_drawn_room_with_the_worlds_own_look_renders_as_the_training_room_even_after_a_textured_one(
    world: str,
) -> None:
    """Textures drawn for one episode are taken off again for the next."""
    randomised, fixed = make(world, OWN_LOOK_ONLY), make(world)
    try:
        plain_seen = textured_seen = textured_shown = 0
        for seed in range(12):
            observation, _ = randomised.reset(seed=seed)
            expected, _ = fixed.reset(seed=seed)
            room = randomised.unwrapped.domain
            if room.object_texture is None and room.floor_texture is None:
                plain_seen += textured_seen > 0
                assert np.array_equal(observation["image"], expected["image"]), seed
            else:
                textured_seen += 1
                textured_shown += not np.array_equal(observation["image"], expected["image"])
        assert plain_seen > 0, "no plain room came after a textured one in 12 seeds"
        assert textured_shown > 0, "the drawn textures show"
    finally:
        randomised.close()
        fixed.close()


def test_the_worlds_own_colours_lie_inside_the_training_ranges() -> None:
    ranges = RoomRanges()
    own_objects = [tuple(BLOCK_RGBA[:3]), *(spec.rgb for spec in OBJECTS)]
    for rgb in own_objects:
        assert not any(outside_by(ranges, DomainShift(object_rgb=rgb)).values()), rgb
    for rgb in (DEFAULT_FLOOR_RGB, (1.0, 1.0, 1.0)):  # the arena's floor; the table's own (white) tint
        assert not any(outside_by(ranges, DomainShift(floor_rgb=rgb)).values()), rgb


def test_a_world_refuses_a_domain_that_is_neither_a_room_nor_ranges() -> None:
    for world in sim.WORLDS:
        with pytest.raises(
            TypeError, match="DomainShift \\(one room\\), RoomRanges \\(a room per episode\\)"
        ):
            make(world, {"floor_rgb": (0, 0, 1)})


def test_the_worlds_draw_every_texture_a_room_names_and_the_training_ranges_hold_back_the_checker() -> None:
    from core.rooms import TEXTURES
    from sim.textures import TEXTURE_KINDS, texture_file

    assert TEXTURE_KINDS == TEXTURES
    for kind in TEXTURES:
        assert texture_file(kind).stat().st_size > 0, kind
    ranges = RoomRanges()
    assert "checker" not in ranges.floor_textures + ranges.object_textures, "the held-out rooms' pattern"
    assert {"noise", "stripes", "speckle", "blotch"} <= set(ranges.floor_textures)
