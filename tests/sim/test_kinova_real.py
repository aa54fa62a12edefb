"""The real-arm env over the Kortex driver, against the Kortex stand-in (which moves the PyBullet Gen3)."""

from collections.abc import Iterator

import numpy as np
import pytest
from kortex_standin import StandInArm

from sim.arm import STEP_M
from sim.kinova_blocks import KinovaBlocksEnv
from sim.kinova_real import KinovaRealEnv
from sim.kortex_driver import HOME_XY_M, CameraError, KortexArmDriver, KortexMotionError

SIZE = 32


@pytest.fixture
def arm() -> Iterator[StandInArm]:
    arm = StandInArm(image_size=SIZE)
    yield arm
    arm.close()


@pytest.fixture
def env(arm: StandInArm) -> Iterator[KinovaRealEnv]:
    driver = KortexArmDriver(
        "10.0.0.2", camera=0, image_size=SIZE, api=arm.api(), open_capture=arm.video_capture
    )
    env = KinovaRealEnv(driver, image_size=SIZE, max_steps=5)
    yield env
    env.close()


def test_the_real_arm_has_the_simulated_gen3s_observation_and_action_contract(env: KinovaRealEnv) -> None:
    simulated = KinovaBlocksEnv(image_size=SIZE)
    try:
        assert env.observation_space == simulated.observation_space
        assert env.action_space == simulated.action_space
        assert (env.num_intents, env.intent_names) == (simulated.num_intents, simulated.intent_names)
        observation, info = env.reset(seed=3, options={"intent": 2})
        assert env.observation_space.contains(observation) and info["intent"] == 2
    finally:
        simulated.close()


def test_every_episode_starts_by_homing_the_arm(env: KinovaRealEnv, arm: StandInArm) -> None:
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([1.0, 1.0], np.float32))
    homes_before = arm.methods().count("ExecuteActionFromReference")
    observation, _ = env.reset(seed=1)
    assert arm.methods().count("ExecuteActionFromReference") == homes_before + 1
    assert observation["state"] == pytest.approx(HOME_XY_M, abs=1e-3)
    assert arm.violations == []


def test_a_step_moves_the_arm_one_step_at_most_and_shows_its_camera(
    env: KinovaRealEnv, arm: StandInArm
) -> None:
    env.reset(seed=0)
    observation, reward, terminated, truncated, info = env.step(np.array([5.0, -0.5], np.float32))
    assert info["target_xy"] == pytest.approx((HOME_XY_M[0] + STEP_M, HOME_XY_M[1] - STEP_M / 2))
    assert observation["state"] == pytest.approx(info["target_xy"], abs=1e-3)
    assert np.array_equal(observation["image"], arm.world.render())  # the camera, centre-cropped back
    assert (reward, terminated, truncated, info["heard"], info["success"]) == (0.0, False, False, None, False)
    assert arm.violations == []


def test_the_episode_ends_after_max_steps(env: KinovaRealEnv) -> None:
    env.reset(seed=0)
    ends = [env.step(np.zeros(2, np.float32))[3] for _ in range(5)]
    assert ends == [False] * 4 + [True]


def test_a_camera_that_fails_mid_episode_stops_the_arm(env: KinovaRealEnv, arm: StandInArm) -> None:
    env.reset(seed=0)
    env.driver.camera._capture.release()  # unplugged
    with pytest.raises(CameraError, match="no frame"):
        env.step(np.array([0.5, 0.5], np.float32))
    assert arm.methods()[-1] == "Stop"


def test_a_link_lost_mid_episode_fails_plainly_and_the_arm_stops(env: KinovaRealEnv, arm: StandInArm) -> None:
    env.reset(seed=0)
    env.step(np.array([0.5, 0.0], np.float32))
    arm.moves_until_disconnect = 1
    sent_before = len(arm.sent)
    with pytest.raises(KortexMotionError, match=r"link to the arm at 10\.0\.0\.2 was lost"):
        env.step(np.array([0.5, 0.0], np.float32))
    assert arm.stopped_by_controller  # the session's connection timeout: Stop cannot cross a dead link
    assert arm.methods()[sent_before:] == ["OnNotificationActionTopic"]  # the link dropped at the move
    with pytest.raises(KortexMotionError, match="lost"):
        env.step(np.array([0.5, 0.0], np.float32))
