"""The scene follows a training run live: a world's mirror state poses another instance of that world
exactly, the scene reads exactly what the worker publishes, and a running scene shows a published rollout
(through a real Redis) while messages come, then goes back to looking around on its own."""

import json
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from scene_helpers import SceneHousehold, eventually

import sim
from learning.rl.ppo import RolloutStep
from scene.live import RolloutMessageError, decode_rollout
from scene.service import SceneService
from scene.world import SimWorld
from worker.live import RolloutPublisher

IMAGE = 32


class TrainingEnv:
    """One real env standing in for env 0 of a training run."""

    def __init__(self, world: str, seed: int, steps: int = 6) -> None:
        self.env = gymnasium.make(sim.world_id(world), image_size=IMAGE)
        self.observation, _ = self.env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(steps):
            self.step(rng.uniform(-1, 1, 2))

    def step(self, action: np.ndarray) -> None:
        self.observation, *_ = self.env.step(np.asarray(action, dtype=np.float32))

    def mirror_state(self) -> dict:
        return json.loads(json.dumps(self.env.unwrapped.mirror_state()))  # as it travels: JSON

    def rollout_step(self, global_step: int, reward: float, goal_clip: int = 1) -> RolloutStep:
        state = self.mirror_state()
        return RolloutStep(global_step, self.observation["image"], reward, False, goal_clip, lambda: state)

    def close(self) -> None:
        self.env.close()


def assert_same_pose(mine: dict, theirs: dict) -> None:
    for part in (0, 1):
        np.testing.assert_allclose(mine["base"][part], theirs["base"][part], atol=1e-6)
    assert mine["joints"].keys() == theirs["joints"].keys()
    for name, value in theirs["joints"].items():
        assert mine["joints"][name] == pytest.approx(value, abs=1e-6), name
    assert [b[:2] for b in mine["bodies"]] == [b[:2] for b in theirs["bodies"]]
    for a, b in zip(mine["bodies"], theirs["bodies"], strict=True):
        np.testing.assert_allclose(a[2], b[2], atol=1e-6)
        np.testing.assert_allclose(a[3], b[3], atol=1e-6)


@pytest.mark.parametrize("world", ["kuka", "kinova", "turtlebot"])
def test_a_mirror_state_poses_a_fresh_world_of_the_same_kind_exactly(world: str) -> None:
    training = TrainingEnv(world, seed=11)
    scene_world = SimWorld(world, image_size=IMAGE, seed=2)  # another layout, another robot pose
    try:
        state = training.mirror_state()
        before = scene_world.mirror.state()
        assert before["joints"] != state["joints"] or before["base"] != state["base"]
        scene_world.follow(state)
        assert_same_pose(scene_world.mirror.state(), state)
    finally:
        scene_world.close()
        training.close()


def test_the_scene_reads_exactly_what_the_worker_publishes_and_refuses_what_it_cannot_show() -> None:
    training = TrainingEnv("kuka", seed=4)
    try:
        step = training.rollout_step(800, 0.42)
    finally:
        training.close()
    publisher = RolloutPublisher(1, 9, 3, "kuka", "policy_improve", goal_clip_ids=[20, 21, 22])
    message = publisher.message(step)
    live = decode_rollout(json.dumps(message), sequence=1, received_at=0.0)
    assert (live.run_id, live.robot_id, live.world, live.step, live.goal_clip_id) == (9, 3, "kuka", 800, 21)
    assert live.reward == pytest.approx(0.42) and live.stage_name == "policy stage"
    assert np.array_equal(live.image, step.image), "the image arrives losslessly"
    assert live.mirror == step.mirror()
    assert len(json.dumps(message)) < 12_000, "a message stays small"
    for broken, reason in [
        ({**message, "type": "run"}, "not a rollout"),
        ({**message, "image_png": "not base64!"}, "unreadable"),
        ({**message, "mirror": {"base": []}}, "mirror state"),
        ({k: v for k, v in message.items() if k != "run_id"}, "run_id"),
    ]:
        with pytest.raises(RolloutMessageError, match=reason):
            decode_rollout(json.dumps(broken), sequence=2, received_at=0.0)


def var_bytes(image_size: int) -> bytes:
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig

    torch.manual_seed(0)
    with tempfile.TemporaryDirectory() as folder:
        return save_var(VAR(VARConfig(image_size=image_size)), Path(folder) / "var.pt").read_bytes()


@pytest.fixture
def scene(scene_household: SceneHousehold) -> Iterator[SceneService]:
    """A running scene service of the household, with an active model's VAR."""
    from scene.brain import Brain

    service = SceneService(scene_household.household_id, fps=15, follow_timeout_s=1.0)
    service.model.brain = Brain(var_bytes(IMAGE), None)  # as if the household had an active model
    thread = threading.Thread(target=service.run, name="scene-under-test", daemon=True)
    thread.start()
    try:

        def ready() -> bool:
            return service.world is not None and service.run_following.feed.subscribed.is_set()

        eventually(ready, 60, "the scene")
        yield service
    finally:
        service.stop()
        thread.join(30)


class LiveRun:
    """A training run's live view: env 0's newest step published 20 times a second from a thread (the
    publisher keeps ~10 of them), as the PPO hook does while the run trains."""

    def __init__(self, training: TrainingEnv, publisher: RolloutPublisher) -> None:
        self.training, self.publisher = training, publisher
        self.current: RolloutStep | None = None
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def show(self, global_step: int, reward: float) -> RolloutStep:
        self.current = self.training.rollout_step(global_step, reward)
        return self.current

    def _run(self) -> None:
        while not self.stopping.wait(0.05):
            if self.current is not None:
                self.publisher(self.current)

    def stop(self) -> None:
        if not self.stopping.is_set():
            self.stopping.set()
            self.thread.join(5)
            self.publisher.close()
            self.training.close()


@pytest.fixture
def live_run(scene_household: SceneHousehold) -> Iterator[Callable[[int, str, int], LiveRun]]:
    runs: list[LiveRun] = []

    def start(run_id: int, world: str, seed: int) -> LiveRun:
        home, robot = scene_household.household_id, scene_household.robot_id
        runs.append(
            LiveRun(TrainingEnv(world, seed), RolloutPublisher(home, run_id, robot, world, "policy_improve"))
        )
        return runs[-1]

    yield start
    for run in runs:
        run.stop()


def test_a_running_scene_follows_a_published_rollout_and_returns_to_exploring_when_it_stops(
    scene: SceneService, live_run: Callable[[int, str, int], LiveRun]
) -> None:
    run = live_run(7, "kuka", 5)
    step = run.show(4000, 0.25)
    eventually(lambda: scene.following is not None, 10, "the scene to follow run 7")
    eventually(lambda: np.array_equal(scene.panel.camera.image, step.image), 5, "the run's camera image")
    # The scene's loop writes the status line last: once it names the run, the rest is in place.
    following = "Following training run 7 live (policy stage), step 4000"
    eventually(lambda: following in scene.panel.status.content, 5, "the status to name the run")
    assert scene.panel.reward_number.value == pytest.approx(0.25)
    assert_same_pose(scene.world.mirror.state(), run.training.mirror_state())
    expected = scene.model.brain.embed_images(step.image[None])[0] * scene.sphere_view.radius * 1.02
    np.testing.assert_allclose(scene.sphere_view.current_marker.position, expected, atol=1e-5)
    assert scene.sphere_view.current_marker.visible

    run.training.step(np.array([1.0, 1.0]))
    moved = run.show(4008, -0.1)
    eventually(lambda: np.array_equal(scene.panel.camera.image, moved.image), 5, "the next image")
    assert_same_pose(scene.world.mirror.state(), run.training.mirror_state())

    run.stop()
    eventually(lambda: scene.following is None, 5, "the scene to stop following")
    eventually(lambda: "Following" not in scene.panel.status.content, 5, "the status to drop the run")
    eventually(lambda: not np.array_equal(scene.panel.camera.image, moved.image), 5, "the scene's own camera")
    assert scene.world.world == "kuka"


def test_a_run_in_another_world_is_shown_in_that_world_and_the_robots_world_comes_back(
    live_run: Callable[[int, str, int], LiveRun], scene: SceneService
) -> None:
    run = live_run(8, "turtlebot", 6)
    run.show(100, 0.5)
    eventually(lambda: scene.following is not None and scene.world.world == "turtlebot", 20, "arena")
    eventually(lambda: scene.following.step == 100, 5, "the arena's rollout")
    assert_same_pose(scene.world.mirror.state(), run.training.mirror_state())
    run.stop()
    eventually(lambda: scene.following is None and scene.world.world == "kuka", 20, "the robot's world")
