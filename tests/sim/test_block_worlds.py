"""The Kuka and Kinova Gen3 block worlds: the reference task, success rules, `heard`, rendering, domains."""

import itertools
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

import sim
from sim.arm import STEP_M, WORKSPACE_X_M, WORKSPACE_Y_M
from sim.blocks import START_STRIPS, START_Y_M, start_strip_bounds, start_strip_of
from sim.domain import DomainShift
from sim.explore import block_end_views, random_views
from sim.oracle import evaluate_oracle, oracle_action

ARM_WORLDS = ["kuka", "kinova"]
SMALL = 32
REPO_ROOT = Path(__file__).resolve().parents[2]


def make(world: str, **kwargs) -> gym.Env:
    kwargs.setdefault("image_size", SMALL)
    return gym.make(sim.WORLDS[world], **kwargs)


def red_pixels(image: np.ndarray) -> np.ndarray:
    r, g, b = (image[..., c].astype(int) for c in range(3))
    return (r > 120) & (g < 0.2 * r) & (b < 0.2 * r)  # the blocks' red, not the Kuka's orange


@pytest.fixture(scope="module", params=ARM_WORLDS)
def world_env(request: pytest.FixtureRequest):
    env = make(request.param)
    yield request.param, env
    env.close()


def test_importing_sim_registers_every_world_without_torch() -> None:
    code = (
        "import sys, gymnasium, sim\n"
        "assert 'torch' not in sys.modules, 'sim imported torch'\n"
        "assert set(sim.WORLDS) == {'kuka', 'kinova', 'turtlebot'}\n"
        "for env_id in sim.WORLDS.values(): gymnasium.spec(env_id)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO_ROOT)


def test_observations_have_the_contracted_shapes_and_dtypes(world_env) -> None:
    _, env = world_env
    observation, info = env.reset(seed=1, options={"intent": 2})
    assert env.observation_space.contains(observation)
    assert observation["image"].shape == (SMALL, SMALL, 3) and observation["image"].dtype == np.uint8
    assert observation["state"].shape == (2,) and observation["state"].dtype == np.float32
    assert info["intent"] == 2 and info["success"] is False
    assert env.unwrapped.num_intents == 4
    assert env.unwrapped.intent_names == ["slot 0", "slot 1", "slot 2", "slot 3"]
    observation, reward, terminated, truncated, info = env.step(np.array([1.0, -1.0], np.float32))
    assert env.observation_space.contains(observation)
    assert isinstance(reward, float) and terminated is False and truncated is False
    assert set(info) >= {"intent", "heard", "success"}


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_the_same_seed_gives_the_same_episode(world: str) -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, size=(12, 2)).astype(np.float32)

    def rollout(env: gym.Env, seed: int) -> list[np.ndarray]:
        observation, _ = env.reset(seed=seed)
        frames = [observation["image"], observation["state"]]
        for action in actions:
            observation, *_ = env.step(action)
            frames += [observation["image"], observation["state"]]
        return frames

    first, second = make(world), make(world)
    try:
        a, b = rollout(first, 7), rollout(second, 7)
        assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
        assert all(np.array_equal(x, y) for x, y in zip(a, rollout(first, 7), strict=True))  # reused env too
        assert not np.array_equal(a[0], rollout(second, 8)[0])
    finally:
        first.close()
        second.close()


@pytest.mark.parametrize("rule", ["final", "hold"])
@pytest.mark.parametrize("world", ARM_WORLDS)
def test_oracle_succeeds_on_every_intent(world: str, rule: str) -> None:
    report = evaluate_oracle(world, episodes=4, rule=rule, seed=100)
    assert report.success_rate == 1.0, report.successes


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_a_do_nothing_policy_fails_unless_it_starts_on_the_target(world: str) -> None:
    env = make(world, success_rule="hold", hold_steps=20, render_images=False)
    failures = 0
    try:
        for seed in range(8):
            _, info = env.reset(seed=seed, options={"intent": seed % 4})
            started_on_target = info["heard"] == info["intent"]
            for _ in range(env.unwrapped.max_steps):
                _, _, _, truncated, info = env.step(np.zeros(2, np.float32))
            assert truncated
            assert info["success"] is started_on_target
            failures += not info["success"]
    finally:
        env.close()
    assert failures >= 6


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_final_needs_the_target_at_the_last_step_and_hold_needs_a_long_enough_stay(world: str) -> None:
    final = make(world, success_rule="final", render_images=False)
    hold = make(world, success_rule="hold", hold_steps=20, render_images=False)
    try:
        for env in (final, hold):
            env.reset(seed=3, options={"intent": 1})
            for step in range(env.unwrapped.max_steps):
                action = oracle_action(env) if step < 70 else np.array([0.0, 1.0], np.float32)  # then leave
                _, _, _, truncated, info = env.step(action)
                if step < env.unwrapped.max_steps - 1:
                    assert info["success"] is (env is hold and env.unwrapped.best_streak >= 20)
            assert truncated and info["heard"] != 1
        assert final.unwrapped.best_streak >= 20
        assert info["success"] is True  # hold: it stayed long enough before leaving
        assert final.unwrapped.success is False  # final: it was not on the target at the end
    finally:
        final.close()
        hold.close()


def test_heard_is_the_block_under_the_gripper_in_hand_placed_scenes(world_env) -> None:
    _, env = world_env
    env.reset(seed=5)
    world = env.unwrapped
    for slot in range(4):
        x, y, _ = world.slot_position(slot)
        world.arm.reset_to(x, y)
        assert world.heard() == slot
        world.arm.reset_to(x + 0.03, y + 0.012)  # still over the block, off centre
        assert world.heard() == slot
    x, y, _ = world.slot_position(0)
    world.arm.reset_to(x, y + 0.05)  # between slot 0 and slot 1
    assert world.heard() is None
    world.arm.reset_to(WORKSPACE_X_M[1], WORKSPACE_Y_M[1])  # far corner: bare table
    assert world.heard() is None


def test_slots_are_numbered_left_to_right_in_the_image(world_env) -> None:
    _, env = world_env
    env.reset(seed=2)
    world = env.unwrapped
    world.arm.reset_to(WORKSPACE_X_M[0], WORKSPACE_Y_M[1])  # out of the way
    world.client.changeVisualShape(world.blocks[0], -1, rgbaColor=[0, 1, 0, 1])
    try:
        image = world.camera.render(world.client)
    finally:
        world.client.changeVisualShape(world.blocks[0], -1, rgbaColor=[1, 0, 0, 1])
    green = (image[..., 1] > 150) & (image[..., 0] < 80)
    assert green.sum() > 0 and red_pixels(image).sum() > 0
    assert np.nonzero(green)[1].mean() < np.nonzero(red_pixels(image))[1].mean()


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_rendering_shows_the_four_blocks(world: str) -> None:
    env = make(world, image_size=96)
    try:
        observation, _ = env.reset(seed=0)
        image = observation["image"]
        assert image.std() > 20  # not blank
        columns_with_red = np.nonzero(red_pixels(image).any(axis=0))[0]
        assert red_pixels(image).sum() > 4 * 15
        runs = np.split(columns_with_red, np.nonzero(np.diff(columns_with_red) > 1)[0] + 1)
        assert len(runs) == 4  # four separate red blocks side by side
    finally:
        env.close()


def test_the_fast_visual_model_looks_like_the_full_model() -> None:
    fast, full = make("kuka", image_size=96), make("kuka", image_size=96, visual_detail="full")
    try:
        for seed in range(3):
            a, b = fast.reset(seed=seed)[0]["image"], full.reset(seed=seed)[0]["image"]
            clearly_different = np.abs(a.astype(int) - b).max(axis=2) > 32
            assert clearly_different.mean() < 0.01
    finally:
        fast.close()
        full.close()


KNOBS = {
    "object_rgb": DomainShift(object_rgb=(0.1, 0.3, 0.9)),
    "object_texture": DomainShift(object_texture="checker"),
    "floor_rgb": DomainShift(floor_rgb=(0.3, 0.6, 0.3)),
    "floor_texture": DomainShift(floor_texture="noise"),
    "floor_texture_stripes": DomainShift(floor_texture="stripes"),
    "floor_texture_speckle": DomainShift(floor_texture="speckle"),
    "floor_texture_blotch": DomainShift(floor_texture="blotch"),
    "floor_texture_checker": DomainShift(floor_texture="checker"),
    "camera_jitter_m": DomainShift(camera_jitter_m=0.03),
    "camera_jitter_deg": DomainShift(camera_jitter_deg=3.0),
    "light_direction": DomainShift(light_direction=(1.0, -1.0, 0.3)),
    "light_ambient": DomainShift(light_ambient=0.9),
    "light_diffuse": DomainShift(light_diffuse=0.1),
}


@pytest.fixture(scope="module")
def plain_kuka_frame() -> np.ndarray:
    env = make("kuka", image_size=48)
    try:
        return env.reset(seed=4, options={"intent": 0})[0]["image"]
    finally:
        env.close()


@pytest.mark.parametrize("knob", KNOBS)
def test_every_domain_knob_changes_the_image(knob: str, plain_kuka_frame: np.ndarray) -> None:
    env = make("kuka", image_size=48, domain=KNOBS[knob])
    try:
        image = env.reset(seed=4, options={"intent": 0})[0]["image"]
    finally:
        env.close()
    assert np.abs(image.astype(int) - plain_kuka_frame).max(axis=2).mean() > 1.0


def test_the_unseen_room_changes_the_kinova_world_but_not_the_task() -> None:
    plain, shifted = make("kinova"), make("kinova", domain=DomainShift.unseen_room())
    try:
        a, info_a = plain.reset(seed=6, options={"intent": 3})
        b, info_b = shifted.reset(seed=6, options={"intent": 3})
        assert not np.array_equal(a["image"], b["image"])
        assert np.array_equal(a["state"], b["state"]) and info_a["heard"] == info_b["heard"]
    finally:
        plain.close()
        shifted.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"success_rule": "sometimes"}, "success_rule"),
        ({"image_size": 3}, "image_size"),
        ({"max_steps": 0}, "max_steps"),
        ({"success_rule": "hold", "hold_steps": 500}, "hold_steps"),
        ({"domain": "unseen"}, "DomainShift"),
        ({"visual_detail": "ultra"}, "visual_detail"),
    ],
)
def test_bad_options_are_refused_with_a_clear_message(kwargs: dict, message: str) -> None:
    with pytest.raises((ValueError, TypeError), match=message):
        make("kuka", **kwargs)


def test_bad_intents_and_actions_are_refused(world_env) -> None:
    _, env = world_env
    with pytest.raises(ValueError, match="intent"):
        env.reset(seed=0, options={"intent": 4})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.unwrapped.step(np.array([np.nan, 0.0]))


def test_a_start_strip_moves_only_the_grippers_start_into_that_strip_of_the_table(world_env) -> None:
    _, env = world_env
    for strip in range(START_STRIPS):
        free, free_info = env.reset(seed=7, options={"intent": 1})
        free_blocks = [env.unwrapped.slot_position(slot) for slot in range(4)]
        placed, placed_info = env.reset(seed=7, options={"intent": 1, "start_strip": strip})
        low, high = start_strip_bounds(strip)
        assert low - 0.01 <= placed["state"][1] <= high + 0.01  # the arm settles within a centimetre
        assert placed["state"][0] == pytest.approx(free["state"][0], abs=0.01)  # x is drawn as without
        assert [env.unwrapped.slot_position(slot) for slot in range(4)] == free_blocks
        assert placed_info["intent"] == free_info["intent"] == 1


def test_start_strips_cover_the_start_area_edge_to_edge() -> None:
    bounds = [start_strip_bounds(strip) for strip in range(START_STRIPS)]
    assert bounds[0][0] == pytest.approx(START_Y_M[0]) and bounds[-1][1] == pytest.approx(START_Y_M[1])
    assert all(a[1] == pytest.approx(b[0]) for a, b in itertools.pairwise(bounds))
    middles = [(low + high) / 2 for low, high in bounds]
    assert start_strip_of(np.array(middles)).tolist() == list(range(START_STRIPS))
    assert start_strip_of(np.array([START_Y_M[0] - 1, START_Y_M[1] + 1])).tolist() == [0, START_STRIPS - 1]


@pytest.mark.parametrize("strip", [-1, START_STRIPS, 1.5, True, "2"])
def test_a_start_strip_outside_the_table_is_refused(world_env, strip: object) -> None:
    _, env = world_env
    with pytest.raises(ValueError, match="start_strip"):
        env.reset(seed=0, options={"start_strip": strip})


def test_actions_move_the_gripper_target_by_two_centimetres_per_unit_and_stay_in_the_workspace(
    world_env,
) -> None:
    _, env = world_env
    env.reset(seed=0)
    world = env.unwrapped
    world.arm.reset_to(0.6, 0.0)
    _, _, _, _, info = env.step(np.array([1.0, -0.5], np.float32))
    assert np.allclose(info["target_xy"], (0.6 + STEP_M, -0.5 * STEP_M))
    _, _, _, _, info = env.step(np.array([5.0, 0.0], np.float32))  # clipped to 1
    assert np.isclose(info["target_xy"][0], 0.6 + 2 * STEP_M)
    for _ in range(20):
        _, _, _, _, info = env.step(np.array([1.0, 1.0], np.float32))
    assert info["target_xy"] == (WORKSPACE_X_M[1], WORKSPACE_Y_M[1])
    for _ in range(10):
        _, _, _, _, info = env.step(np.array([-1.0, -1.0], np.float32))
    assert np.allclose(info["target_xy"], (WORKSPACE_X_M[1] - 0.2, WORKSPACE_Y_M[1] - 0.2))
    for _ in range(15):
        observation, *_ = env.step(np.zeros(2, np.float32))
    assert np.allclose(observation["state"], info["target_xy"], atol=0.01)  # the gripper follows its target


def test_the_simulated_gen3_is_a_drop_in_arm_driver() -> None:
    env = make("kinova")
    try:
        env.reset(seed=0)
        arm = env.unwrapped.arm
        arm.home()
        target = arm.move_target(1.0, -1.0)  # far outside: clipped
        assert target == (WORKSPACE_X_M[1], WORKSPACE_Y_M[0])
        frame = arm.grab_frame()
        assert frame.shape == (SMALL, SMALL, 3) and frame.dtype == np.uint8
        arm.stop()
        held = arm.gripper_xy()
        for _ in range(5):
            arm.client.stepSimulation()
        assert np.allclose(arm.gripper_xy(), held, atol=0.005)
        with pytest.raises(ValueError, match="finite"):
            arm.move_target(float("inf"), 0.0)
        arm.close()
    finally:
        env.close()


def test_the_gen3s_tool_ends_just_above_the_block_it_is_at() -> None:
    """So that the camera sees the tool touch its block: 11 cm above the blocks, no Kinova policy learnt."""
    from sim.blocks import BLOCK_SIZE_M, TABLE_TOP_Z_M
    from sim.kinova_blocks import GEN3_TOOL_LENGTH_M

    env = make("kinova", render_images=False)
    try:
        env.reset(seed=0, options={"intent": 2})
        for _ in range(60):
            _, _, _, _, info = env.step(oracle_action(env))
        tool_tip_z = env.unwrapped.arm.gripper_position()[2] - GEN3_TOOL_LENGTH_M
    finally:
        env.close()
    assert info["on_target"]
    block_top_z = TABLE_TOP_Z_M + BLOCK_SIZE_M[2]
    assert block_top_z < tool_tip_z < block_top_z + 0.03


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_random_views_are_reproducible_and_see_blocks_and_bare_table(world: str) -> None:
    views = list(random_views(world, 40, seed=3, image_size=SMALL))
    again = list(random_views(world, 40, seed=3, image_size=SMALL))
    assert len(views) == 40
    for (image, heard, state), (image2, heard2, state2) in zip(views, again, strict=True):
        assert image.shape == (SMALL, SMALL, 3) and image.dtype == np.uint8 and state.shape == (2,)
        assert heard == heard2 and np.array_equal(image, image2) and np.array_equal(state, state2)
    heard_values = {heard for _, heard, _ in views}
    assert None in heard_values and heard_values - {None}


@pytest.mark.parametrize("world", ARM_WORLDS)
def test_block_end_views_put_the_gripper_around_a_blocks_end_and_the_ray_labels_them(world: str) -> None:
    """In one scene (its seed is the views' first draw): every view's gripper stands within 2.5 cm across of a
    block and within 11 cm along it; a gripper well inside a block is over it for the ray, and about half of
    the views are past an end, where the ray finds nothing. The same arguments give the same views."""
    views = list(block_end_views(world, 48, seed=5, image_size=SMALL, views_per_scene=48))
    again = list(block_end_views(world, 48, seed=5, image_size=SMALL, views_per_scene=48))
    for (image, heard, state), (image2, heard2, state2) in zip(views, again, strict=True):
        assert heard == heard2 and np.array_equal(image, image2) and np.array_equal(state, state2)
    env = make(world)
    try:
        env.reset(seed=int(np.random.default_rng(5).integers(2**31 - 1)))
        blocks = np.array([env.unwrapped.slot_position(slot)[:2] for slot in range(4)])
    finally:
        env.close()
    for _, heard, state in views:
        offsets = np.asarray(state) - blocks
        slot = int(np.argmin(np.abs(offsets[:, 1])))
        dx, dy = offsets[slot]
        assert abs(dy) < 0.026 and abs(dx) < 0.111, (state, offsets)
        if abs(dx) < 0.04 and abs(dy) < 0.01:
            assert heard == slot
        assert heard in (slot, None)
    nothing = sum(heard is None for _, heard, _ in views)
    assert 0.25 < nothing / len(views) < 0.75


def test_block_end_views_are_refused_in_a_world_without_blocks() -> None:
    with pytest.raises(ValueError, match="no blocks"):
        next(block_end_views("turtlebot", 4, seed=0, image_size=SMALL))


def test_varbot_sim_show_writes_a_png(tmp_path: Path) -> None:
    from varbot.cli import app

    out = tmp_path / "frames" / "kuka.png"
    result = CliRunner().invoke(
        app, ["sim", "show", "kuka", "--intent", "1", "--out", str(out), "--size", "40"]
    )
    assert result.exit_code == 0, result.output
    with Image.open(out) as image:
        assert image.size == (40, 40) and image.mode == "RGB"
        assert red_pixels(np.asarray(image)).sum() > 10


def test_varbot_sim_oracle_prints_the_success_rate() -> None:
    from varbot.cli import app

    result = CliRunner().invoke(app, ["sim", "oracle", "kuka", "--episodes", "4", "--rule", "hold"])
    assert result.exit_code == 0, result.output
    assert "100.0 %" in result.output
    result = CliRunner().invoke(app, ["sim", "oracle", "kuka", "--episodes", "3"])
    assert result.exit_code != 0 and "multiple" in result.output


def test_vector_envs_report_nothing_heard_as_minus_one() -> None:
    from sim.vector import make_vector_env

    envs = make_vector_env("kuka", 2, image_size=SMALL, max_steps=3)
    try:
        envs.reset(seed=0)
        heard = []
        for _ in range(6):  # crosses an episode end (autoreset)
            observation, _, _, _, info = envs.step(np.zeros((2, 2), np.float32))
            heard.append(info["heard"])
        assert observation["image"].shape == (2, SMALL, SMALL, 3)
        assert all(h.dtype.kind == "i" and set(h) <= {-1, 0, 1, 2, 3} for h in heard)
    finally:
        envs.close()
