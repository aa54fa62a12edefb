"""TurtleBot arena: the robot drives to the commanded object; `heard` names what fills its camera view."""

import math

import gymnasium as gym
import numpy as np
import pytest

import sim
from sim.domain import DomainShift
from sim.turtlebot_arena import (
    ARENA_HALF_M,
    CONTROL_PERIOD_S,
    HEARD_MAX_CLEARANCE_M,
    OBJECTS,
    ROBOT_RADIUS_M,
    STAND_STILL_ACTION,
    SUCCESS_CLEARANCE_M,
    SUCCESS_HOLD_STEPS,
    TurtleBotArenaEnv,
    action_to_velocity,
)

SMALL = 32  # pixels: enough for shapes, colours and the segmentation shares `heard` uses
TARGET_XY = (0.5, 0.0)
BEHIND_THE_ROBOT = [(-0.75, -0.75), (-0.75, 0.75), (-0.75, 0.0)]


def make_env(**kwargs) -> TurtleBotArenaEnv:
    kwargs.setdefault("image_size", SMALL)
    return TurtleBotArenaEnv(**kwargs)


def scene_with(target: int, others: list[tuple[float, float]] | None = None) -> list[tuple[float, float]]:
    """Object `target` at TARGET_XY, the others out of sight behind a robot looking along +x."""
    spare = list(others or BEHIND_THE_ROBOT)
    return [TARGET_XY if k == target else spare.pop() for k in range(len(OBJECTS))]


def run_episode(env: TurtleBotArenaEnv, seed: int, intent: int, policy) -> list[dict]:
    env.reset(seed=seed, options={"intent": intent})
    infos, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(policy(env))
        infos.append(info)
        done = terminated or truncated
    return infos


@pytest.fixture(scope="module")
def env():
    arena = make_env()
    yield arena
    arena.close()


def test_registered_id_makes_the_arena():
    made = gym.make(sim.TURTLEBOT_ARENA, image_size=SMALL, success_rule="final", max_steps=7)
    try:
        assert made.unwrapped.num_intents == 4
        assert made.unwrapped.intent_names == ["cube", "sphere", "cone", "cylinder"]
        assert made.unwrapped.max_steps == 7
    finally:
        made.close()


def test_observations_have_the_contract_shapes_and_dtypes():
    arena = make_env(image_size=48)
    observation, info = arena.reset(seed=3, options={"intent": 2})
    assert observation["image"].shape == (48, 48, 3) and observation["image"].dtype == np.uint8
    assert observation["state"].shape == (4,) and observation["state"].dtype == np.float32
    assert arena.observation_space.contains(observation)
    _, sin_heading, cos_heading = observation["state"][1:]
    assert sin_heading**2 + cos_heading**2 == pytest.approx(1.0, abs=1e-5)
    assert info["intent"] == 2 and info["success"] is False and info["heard"] in (None, 0, 1, 2, 3)
    arena.close()


def test_the_same_seed_replays_the_same_episode():
    first, second = make_env(), make_env()
    actions = np.random.default_rng(0).uniform(-1, 1, size=(15, 2)).astype(np.float32)
    for arena in (first, second):
        arena.reset(seed=11)
    for action in actions:
        obs_a, _, _, _, info_a = first.step(action)
        obs_b, _, _, _, info_b = second.step(action)
        np.testing.assert_array_equal(obs_a["image"], obs_b["image"])
        np.testing.assert_array_equal(obs_a["state"], obs_b["state"])
        assert info_a == info_b
    other, _ = second.reset(seed=12)
    again, _ = first.reset(seed=11)
    assert not np.array_equal(other["state"], again["state"])
    first.close()
    second.close()


def test_the_commanded_intent_does_not_change_the_room(env):
    rooms = [env.reset(seed=5, options={"intent": k})[0] for k in range(4)]
    for room in rooms[1:]:
        np.testing.assert_array_equal(room["image"], rooms[0]["image"])
        np.testing.assert_array_equal(room["state"], rooms[0]["state"])


def test_actions_map_linearly_onto_the_speed_and_turn_ranges():
    assert action_to_velocity(np.array([-1.0, -1.0])) == pytest.approx((-0.1, -1.1))
    assert action_to_velocity(np.array([1.0, 1.0])) == pytest.approx((0.25, 1.1))
    assert action_to_velocity(np.array([5.0, -5.0])) == pytest.approx((0.25, -1.1))  # clipped
    assert action_to_velocity(STAND_STILL_ACTION) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_full_speed_drives_a_quarter_metre_per_second(env):
    env.reset(seed=0)
    observation, *_ = env.arrange(
        (0.0, 0.0, math.pi / 2), [(0.7, -0.7), (-0.7, -0.7), (0.7, 0.7), (-0.7, 0.7)]
    )
    observation, *_, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert not info["blocked"]
    assert observation["state"][:2] == pytest.approx((0.0, 0.25 * CONTROL_PERIOD_S), abs=1e-6)


def test_walls_and_objects_stop_the_robot(env):
    env.reset(seed=1)
    env.arrange((0.1, 0.0, 0.0), scene_with(0))  # the cube straight ahead, close
    for _ in range(20):
        observation, *_, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert info["blocked"]
    assert env.object_clearance(0) >= 0.0
    env.arrange((0.0, 0.5, math.pi / 2), scene_with(0))  # facing the +y wall
    for _ in range(30):
        observation, *_, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    x, y = observation["state"][:2]
    assert info["blocked"] and max(abs(x), abs(y)) <= ARENA_HALF_M - ROBOT_RADIUS_M + 1e-6


def drive_into_the_wall_at_45_degrees(arena: TurtleBotArenaEnv) -> list[np.ndarray]:
    """Full speed towards the +y wall at 45°, from 5 cm short of touching it; the robot's (x, y) each step."""
    arena.reset(seed=1)
    start_y = ARENA_HALF_M - ROBOT_RADIUS_M - 0.05
    arena.arrange((-0.5, start_y, math.pi / 4), [(0.6, -0.6), (-0.6, -0.6), (0.0, -0.7), (-0.7, 0.0)])
    return [arena.step(np.array([1.0, 0.0], dtype=np.float32))[0]["state"][:2] for _ in range(10)]


def test_a_robot_blocked_at_an_angle_stands_still_under_the_stop_rule(env):
    path = drive_into_the_wall_at_45_degrees(env)
    assert path[-1] == pytest.approx(path[-2], abs=1e-9)


def test_a_robot_blocked_at_an_angle_slides_along_the_wall_under_the_slide_rule():
    arena = make_env(contact="slide")
    path = drive_into_the_wall_at_45_degrees(arena)
    x, y = path[-1]
    # 10 steps of 5 cm: the first ~7 cm along the diagonal, the rest along the wall at cos 45° of full speed,
    # within one integration slice (1.25 cm) of touching it
    assert ARENA_HALF_M - ROBOT_RADIUS_M - 0.0125 <= y <= ARENA_HALF_M - ROBOT_RADIUS_M
    assert x - path[-2][0] == pytest.approx(0.25 * CONTROL_PERIOD_S * math.cos(math.pi / 4), abs=1e-3)
    arena.step(np.array([1.0, 0.0], dtype=np.float32))
    arena.arrange((0.0, 0.5, math.pi / 2))  # head-on into the wall: nothing to slide along
    for _ in range(10):
        observation, *_, info = arena.step(np.array([1.0, 0.0], dtype=np.float32))
    assert info["blocked"] and observation["state"][0] == pytest.approx(0.0, abs=1e-9)
    arena.close()


def test_a_robot_sliding_round_an_object_keeps_its_distance():
    arena = make_env(contact="slide")
    arena.reset(seed=1)
    arena.arrange((0.1, 0.05, 0.0), scene_with(1))  # the sphere ahead, a little to the right of the heading
    for _ in range(15):
        *_, info = arena.step(np.array([1.0, 0.0], dtype=np.float32))
        assert arena.object_clearance(1) >= -1e-9
    # it has slid round the sphere's side instead of standing still in front of it
    assert info["blocked"] and arena.object_bearing(1) < -math.radians(30)
    arena.close()


@pytest.mark.parametrize("target", range(4))
def test_heard_names_the_object_the_robot_faces_from_40_cm(env, target):
    env.reset(seed=2)
    _, info = env.arrange((TARGET_XY[0] - 0.4, TARGET_XY[1], 0.0), scene_with(target))
    assert info["heard"] == target


def test_heard_is_none_facing_an_empty_wall(env):
    env.reset(seed=2)
    _, info = env.arrange((0.0, 0.4, math.pi / 2), [(0.6, -0.6), (-0.6, -0.6), (0.0, -0.7), (-0.7, 0.0)])
    assert info["heard"] is None


def test_heard_is_none_for_a_far_object_or_two_objects_side_by_side(env):
    env.reset(seed=2)
    _, info = env.arrange((-0.4, 0.0, 0.0), scene_with(0))  # the cube 0.9 m away
    assert info["heard"] is None
    side_by_side = [(0.4, 0.2), (0.4, -0.2), *BEHIND_THE_ROBOT[:2]]
    _, info = env.arrange((-0.1, 0.0, 0.0), side_by_side)
    assert info["heard"] is None


def face_the_cylinder_from(arena: TurtleBotArenaEnv, clearance_m: float) -> dict:
    cylinder = 3
    centre_distance = clearance_m + ROBOT_RADIUS_M + OBJECTS[cylinder].footprint_radius_m
    _, info = arena.arrange((TARGET_XY[0] - centre_distance, TARGET_XY[1], 0.0), scene_with(cylinder))
    return info


def test_the_heard_reach_sets_how_close_a_named_view_must_be():
    default, tight = make_env(), make_env(heard_reach_m=SUCCESS_CLEARANCE_M)
    for arena in (default, tight):
        arena.reset(seed=2)
    assert default.heard_reach_m == HEARD_MAX_CLEARANCE_M
    assert face_the_cylinder_from(default, 0.45)["heard"] == 3  # it fills the view from 45 cm ...
    assert face_the_cylinder_from(tight, 0.45)["heard"] is None  # ... but is out of reach
    assert face_the_cylinder_from(tight, 0.3)["heard"] == 3
    for arena in (default, tight):
        arena.close()


def test_rendering_shows_the_object_in_front_in_its_colour(env):
    env.reset(seed=4)
    observation, _ = env.arrange((TARGET_XY[0] - 0.35, 0.0, 0.0), scene_with(0))  # the red cube
    image = observation["image"].astype(int)
    assert image.std() > 10  # not a blank frame
    red = (image[..., 0] > 150) & (image[..., 1] < 80) & (image[..., 2] < 80)
    assert red.mean() > 0.1
    assert (
        red[:, SMALL // 3 : 2 * SMALL // 3].mean() > red[:, : SMALL // 6].mean()
    )  # in the middle of the view


@pytest.mark.parametrize(
    "knob",
    [
        {"object_rgb": (0.85, 0.55, 0.1)},
        {"object_texture": "checker"},
        {"floor_rgb": (0.35, 0.45, 0.6)},
        {"floor_texture": "noise"},
        {"camera_jitter_m": 0.03},
        {"camera_jitter_deg": 4.0},
        {"light_direction": (-0.5, 0.8, 1.0)},
        {"light_ambient": 0.3},
        {"light_diffuse": 0.8},
    ],
    ids=lambda knob: next(iter(knob)),
)
def test_every_domain_knob_changes_the_image_but_not_the_room(env, knob):
    plain, _ = env.reset(seed=6)
    plain_image = env.arrange((0.1, 0.0, 0.0), scene_with(0))[0]["image"]
    shifted_env = make_env(domain=DomainShift(**knob))
    shifted, _ = shifted_env.reset(seed=6)
    shifted_image = shifted_env.arrange((0.1, 0.0, 0.0), scene_with(0))[0]["image"]
    shifted_env.close()
    np.testing.assert_array_equal(shifted["state"], plain["state"])
    changed = np.abs(shifted_image.astype(int) - plain_image.astype(int)).max(axis=2) > 8
    assert changed.mean() > 0.005


@pytest.mark.parametrize("rule", ["hold", "final"])
def test_oracle_succeeds_on_every_intent(rule):
    arena = make_env(success_rule=rule)
    for intent in range(4):
        for seed in (100 + intent, 200 + intent):
            infos = run_episode(arena, seed, intent, lambda e: e.oracle_action())
            assert infos[-1]["success"], f"oracle failed intent {intent} seed {seed} under {rule!r}"
    arena.close()


@pytest.mark.parametrize("rule", ["hold", "final"])
def test_standing_still_never_succeeds(rule):
    arena = make_env(success_rule=rule, max_steps=40)
    for intent in range(4):
        infos = run_episode(arena, 300 + intent, intent, lambda e: STAND_STILL_ACTION)
        assert not any(info["success"] for info in infos)
    arena.close()


def test_hold_rule_needs_consecutive_steps_in_reach():
    arena = make_env(success_rule="hold")
    infos = run_episode(arena, 400, 1, lambda e: e.oracle_action())
    first_success = next(t for t, info in enumerate(infos) if info["success"])
    assert all(info["in_reach"] for info in infos[first_success - SUCCESS_HOLD_STEPS + 1 : first_success + 1])
    assert not infos[first_success - 1]["success"]
    assert infos[first_success - SUCCESS_HOLD_STEPS]["in_reach"] is False
    arena.close()


def test_final_rule_judges_only_the_last_step():
    """Reach the target, then back away at the end: "hold" keeps the success, "final" does not."""

    def reach_then_leave(arena: TurtleBotArenaEnv) -> np.ndarray:
        if arena._steps >= arena.max_steps - 8:
            return np.array([-1.0, 1.0], dtype=np.float32)
        return arena.oracle_action()

    for rule, expected in (("hold", True), ("final", False)):
        arena = make_env(success_rule=rule, max_steps=80)
        infos = run_episode(arena, 500, 3, reach_then_leave)
        assert any(info["in_reach"] for info in infos)
        assert infos[-1]["success"] is expected
        arena.close()


def test_wandering_shows_single_objects_up_close_often(env):
    env.reset(seed=7)
    rng = np.random.default_rng(0)
    heard = [env.random_view_step(rng)[4]["heard"] for _ in range(150)]
    assert sum(h is not None for h in heard) >= 0.15 * len(heard)
    assert len({h for h in heard if h is not None}) >= 2


def test_bad_arguments_say_what_is_wrong():
    with pytest.raises(ValueError, match="success_rule"):
        TurtleBotArenaEnv(success_rule="sometimes")
    with pytest.raises(ValueError, match="contact must be one of"):
        TurtleBotArenaEnv(contact="bounce")
    with pytest.raises(ValueError, match="heard_reach_m must be a distance"):
        TurtleBotArenaEnv(heard_reach_m=0.0)
    arena = make_env()
    with pytest.raises(ValueError, match="intent"):
        arena.reset(seed=0, options={"intent": 4})
    arena.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        arena.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(ValueError, match="overlap"):
        arena.arrange((TARGET_XY[0], TARGET_XY[1], 0.0), scene_with(0))
    with pytest.raises(ValueError, match="wall"):
        arena.arrange((0.0, 0.0, 0.0), scene_with(0, [(0.95, 0.0), (-0.75, 0.75), (-0.75, -0.75)]))
    arena.close()
