"""The scene's parts without a browser: the 3D view follows the simulated joints, snapshots join the nearest
command on the sphere, the brain loads checkpoint bytes and drives the robot, the reward is f_I · f_S."""

import io
import tempfile
from pathlib import Path

import numpy as np
import pytest
import soundfile
import torch
import yourdfpy

from core.robots import world_of_kind
from scene.world import DISPLAY_URDFS, SimWorld


@pytest.mark.parametrize("world", ["kuka", "kinova", "turtlebot"])
def test_the_display_robot_follows_the_simulated_joints(world: str) -> None:
    names = tuple(yourdfpy.URDF.load(str(DISPLAY_URDFS[world]), load_meshes=False).actuated_joint_names)
    sim_world = SimWorld(world, image_size=32, seed=1)
    try:
        before, base_before = sim_world.joint_values(names), sim_world.robot_base()
        for _ in range(15):
            sim_world.explore_step()
        after, base_after = sim_world.joint_values(names), sim_world.robot_base()
        assert before.shape == after.shape == (len(names),)
        moved = np.abs(after - before).max() > 1e-3 or base_before != base_after
        assert moved, "the robot did not move with the simulation"
        assert sim_world.image.shape == (32, 32, 3)
        assert sim_world.other_shapes(), "the table, blocks or room are missing"
    finally:
        sim_world.close()


def test_every_robot_kind_has_a_world_and_unknown_kinds_are_refused() -> None:
    assert {world_of_kind(k) for k in ("kuka-sim", "kinova-sim", "turtlebot-sim")} == {
        "kuka",
        "kinova",
        "turtlebot",
    }
    with pytest.raises(ValueError, match="no simulated world"):
        world_of_kind("vacuum-cleaner")


def test_snapshots_join_the_command_whose_clips_are_closest() -> None:
    from scene.household import ClipInfo, HouseholdView
    from scene.sphere import nearest_commands

    view = HouseholdView(household_id=1, robot=None)
    view.clips = [
        ClipInfo(1, "a", "name:left", "x"),
        ClipInfo(2, "b", "name:left", "x"),
        ClipInfo(3, "c", "name:right", "x"),
    ]
    clips = {1: np.array([1.0, 0, 0]), 2: np.array([0.9, 0.1, 0]), 3: np.array([0.0, 0, 1])}
    points = np.array([[0.8, 0.2, 0.1], [0.1, 0.0, 0.99]])
    assert nearest_commands(points, clips, view) == ["name:left", "name:right"]
    assert nearest_commands(points, {}, view) == [None, None]


def _checkpoints(front_end: str = "mfcc") -> tuple[bytes, bytes]:
    from learning.rl.policy import Policy, PolicyConfig
    from learning.rl.ppo import CHECKPOINT_KIND
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig

    torch.manual_seed(0)
    policy_buffer = io.BytesIO()
    model = VAR(VARConfig(image_size=32, front_end=front_end))
    with tempfile.TemporaryDirectory() as folder:
        var_bytes = save_var(model, Path(folder) / "var.pt").read_bytes()
    policy = Policy(PolicyConfig(image_size=32, state_dim=2))
    torch.save(
        {"kind": CHECKPOINT_KIND, "policy_config": policy.config.to_dict(), "policy": policy.state_dict()},
        policy_buffer,
    )
    return var_bytes, policy_buffer.getvalue()


def test_the_brain_embeds_on_the_unit_sphere_and_drives_the_robot_toward_a_goal() -> None:
    from scene.brain import Brain, Goal
    from scene.sphere import reward

    var_bytes, policy_bytes = _checkpoints()
    brain = Brain(var_bytes, policy_bytes)
    world = SimWorld("kuka", image_size=brain.image_size, seed=2)
    try:
        embedding = brain.embed_images(world.image[None])[0]
        assert np.isclose(np.linalg.norm(embedding), 1.0, atol=1e-4)
        goal = -embedding
        assert reward(embedding, goal) == pytest.approx(-1.0, abs=1e-4)
        brain.start_episode(Goal(clip_id=1, embedding=goal))
        for _ in range(3):
            action = brain.act(world.image, brain.embed_images(world.image[None])[0], world.state)
            assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
            world.step(action)
    finally:
        world.close()


def test_unreadable_clips_are_left_off_the_sphere() -> None:
    from scene.brain import Brain

    var_bytes, _ = _checkpoints()
    brain = Brain(var_bytes, None)
    t = np.arange(16000) / 16000
    buffer = io.BytesIO()
    soundfile.write(buffer, 0.3 * np.sin(2 * np.pi * 300 * t), 16000, format="WAV", subtype="PCM_16")
    vectors = brain.embed_clip_bytes([buffer.getvalue(), b"not audio at all"])
    assert vectors[1] is None and vectors[0] is not None
    assert np.isclose(np.linalg.norm(vectors[0]), 1.0, atol=1e-4)
    with pytest.raises(RuntimeError, match="no policy episode"):
        brain.act(np.zeros((32, 32, 3), np.uint8), vectors[0], np.zeros(2, np.float32))


def test_a_clip_reaches_the_sphere_through_the_front_end_the_var_was_trained_with() -> None:
    from learning.audio import features_from_bytes
    from scene.brain import Brain

    var_bytes, _ = _checkpoints(front_end="speech-embedding")
    brain = Brain(var_bytes, None)
    t = np.arange(16000) / 16000
    buffer = io.BytesIO()
    soundfile.write(buffer, 0.3 * np.sin(2 * np.pi * 300 * t), 16000, format="WAV", subtype="PCM_16")
    [vector] = brain.embed_clip_bytes([buffer.getvalue()])
    features = features_from_bytes(buffer.getvalue(), front_end="speech-embedding")
    with torch.inference_mode():
        expected = brain.var.encode_sound(torch.from_numpy(features[None])).float().numpy()[0]
    assert vector is not None and np.allclose(vector, expected, atol=1e-5)


def test_try_a_command_offers_each_command_once_in_the_households_words() -> None:
    from scene.household import ClipInfo, HouseholdView
    from scene.trial import clip_for, command_choices

    view = HouseholdView(household_id=1, robot=None)
    view.clips = [
        ClipInfo(1, "left (Alice, #1)", "name:left", "Alice"),
        ClipInfo(2, "Left (Bob, #2)", "name:left", "Bob"),
        ClipInfo(3, "recording 3 (Bob, #3)", "clip:3", "Bob"),
    ]
    assert command_choices(view) == ["recording 3", "left"]
    chosen = clip_for("left", view)
    assert chosen is not None and chosen.command == "name:left"
    assert clip_for("right", view) is None
