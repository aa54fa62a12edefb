"""The real-arm driver, against the Kortex stand-in (`kortex_standin`: it moves the PyBullet Gen3; there is no
arm here)."""

import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from kortex_standin import HOME_HANDLE, KClientException, KServerException, StandInArm

from sim.arm import GEN3_GRIPPER_HEIGHT_M, STEP_M, WORKSPACE_X_M, WORKSPACE_Y_M
from sim.kortex_driver import (
    HOME_XY_M,
    KORTEX_WHEEL,
    SPEED_CEILING_M_S,
    CameraError,
    FixedCamera,
    KortexArmDriver,
    KortexMotionError,
    KortexUnavailableError,
    centre_crop_resize,
    load_kortex_api,
)

VIDEO_SIZE = (160, 120)  # width, height: wider than tall, like a webcam


def write_test_video(folder: Path, frames: int = 5) -> str:
    """A small clip whose frames are red on the left, blue on the right, and a green band in the middle."""
    width, height = VIDEO_SIZE
    frame = np.zeros((height, width, 3), np.uint8)  # BGR
    frame[:, : width // 2] = (0, 0, 255)
    frame[:, width // 2 :] = (255, 0, 0)
    frame[:, width // 2 - 10 : width // 2 + 10] = (0, 255, 0)
    path = folder / "camera.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (width, height))
    if writer.isOpened():
        for _ in range(frames):
            writer.write(frame)
        writer.release()
        return str(path)
    for index in range(
        frames
    ):  # no video encoder in this OpenCV build: an image sequence opens just the same
        cv2.imwrite(str(folder / f"frame_{index:03d}.png"), frame)
    return str(folder / "frame_%03d.png")


@pytest.fixture
def arm() -> Iterator[StandInArm]:
    arm = StandInArm()
    yield arm
    arm.close()


@pytest.fixture
def video(tmp_path: Path) -> str:
    return write_test_video(tmp_path)


@pytest.fixture
def driver(arm: StandInArm, video: str):
    robot = KortexArmDriver("10.0.0.2", camera=video, image_size=32, api=arm.api(), move_timeout_s=2.0)
    robot.connect()
    yield robot
    robot.close()


def test_constructing_the_driver_contacts_nothing(arm: StandInArm, video: str) -> None:
    KortexArmDriver(camera=video, api=arm.api())
    assert arm.sent == []
    assert not arm.transport_connected


def test_an_arm_that_does_not_answer_fails_connect_and_leaves_nothing_open(video: str) -> None:
    arm = StandInArm(link_up=False)
    robot = KortexArmDriver(camera=video, api=arm.api())
    with pytest.raises(KClientException, match="no arm answers"):
        robot.connect()
    assert not robot.connected and robot.camera._capture is None
    assert arm.sent == []
    arm.close()


def test_connecting_opens_a_session_and_moves_nothing(driver: KortexArmDriver, arm: StandInArm) -> None:
    assert arm.methods() == ["CreateSession"]
    assert arm.session_open and arm.motions() == []
    assert arm.sent[0].message.connection_inactivity_timeout > 0
    assert arm.violations == []


def test_home_goes_to_the_stored_home_then_points_down_above_the_workspace_centre(
    driver: KortexArmDriver, arm: StandInArm
) -> None:
    driver.home()
    motions = arm.motions()
    assert motions[0].method == "ExecuteActionFromReference" and motions[0].message == HOME_HANDLE
    assert arm.reach_targets() == [pytest.approx((*HOME_XY_M, GEN3_GRIPPER_HEIGHT_M))]
    gripper = [entry.message for entry in arm.sent if entry.method == "SendGripperCommand"]
    assert len(gripper) == 1 and gripper[0].gripper.finger[0].value == 1.0
    assert driver.gripper_xy() == pytest.approx(HOME_XY_M, abs=1e-3)  # measured: within a millimetre
    assert arm.violations == []


def test_move_target_shifts_the_target_and_waits_for_the_move(
    driver: KortexArmDriver, arm: StandInArm
) -> None:
    driver.home()
    target = driver.move_target(0.01, -0.02)
    assert target == pytest.approx((HOME_XY_M[0] + 0.01, HOME_XY_M[1] - 0.02))
    assert driver.gripper_xy() == pytest.approx(target, abs=1e-3)  # the arm moved before the action ended
    assert arm.violations == []


def test_targets_are_clipped_to_the_workspace_box(driver: KortexArmDriver, arm: StandInArm) -> None:
    driver.home()
    for _ in range(40):
        last = driver.move_target(STEP_M, -STEP_M)
    assert last == pytest.approx((WORKSPACE_X_M[1], WORKSPACE_Y_M[0]))
    for x, y, z in arm.reach_targets():
        assert WORKSPACE_X_M[0] <= x <= WORKSPACE_X_M[1] and WORKSPACE_Y_M[0] <= y <= WORKSPACE_Y_M[1]
        assert z == pytest.approx(GEN3_GRIPPER_HEIGHT_M)
    assert arm.violations == []


def test_one_move_never_jumps_further_than_one_step(driver: KortexArmDriver, arm: StandInArm) -> None:
    driver.home()
    target = driver.move_target(1.0, -1.0)
    assert target == pytest.approx((HOME_XY_M[0] + STEP_M, HOME_XY_M[1] - STEP_M))


def test_every_move_carries_the_speed_limit(arm: StandInArm, video: str) -> None:
    with KortexArmDriver(camera=video, api=arm.api(), max_speed_m_s=0.04) as robot:
        robot.home()
        robot.move_target(0.02, 0.02)
    speeds = [
        entry.message.reach_pose.constraint.speed.translation
        for entry in arm.sent
        if entry.method == "ExecuteAction"
    ]
    assert len(speeds) == 2 and all(speed == pytest.approx(0.04) for speed in speeds)
    assert arm.violations == []


def test_a_speed_above_the_ceiling_is_refused(arm: StandInArm) -> None:
    with pytest.raises(ValueError, match="max_speed_m_s"):
        KortexArmDriver(api=arm.api(), max_speed_m_s=SPEED_CEILING_M_S * 2)


def test_moving_before_connect_or_home_is_refused(arm: StandInArm, video: str) -> None:
    robot = KortexArmDriver(camera=video, api=arm.api())
    with pytest.raises(RuntimeError, match="connect"):
        robot.move_target(0.01, 0.0)
    robot.connect()
    with pytest.raises(RuntimeError, match="home"):
        robot.move_target(0.01, 0.0)
    robot.close()
    assert arm.motions() == []


def test_an_error_from_the_arm_stops_it_and_is_raised(driver: KortexArmDriver, arm: StandInArm) -> None:
    driver.home()
    arm.fail_next = "raise"
    with pytest.raises(KServerException):
        driver.move_target(0.01, 0.0)
    assert arm.methods()[-1] == "Stop"


def test_an_aborted_move_stops_the_arm(driver: KortexArmDriver, arm: StandInArm) -> None:
    driver.home()
    arm.fail_next = "abort"
    with pytest.raises(KortexMotionError, match="aborted"):
        driver.move_target(0.01, 0.0)
    assert arm.methods()[-1] == "Stop"


def test_a_move_that_never_ends_times_out_and_stops_the_arm(arm: StandInArm, video: str) -> None:
    with KortexArmDriver(camera=video, api=arm.api(), move_timeout_s=0.05) as robot:
        robot.home()
        arm.fail_next = "silent"
        with pytest.raises(KortexMotionError, match="did not finish"):
            robot.move_target(0.0, 0.01)
        assert arm.methods()[-1] == "Stop"


def test_after_the_link_is_lost_nothing_more_is_sent(driver: KortexArmDriver, arm: StandInArm) -> None:
    driver.home()
    sent_before = len(arm.sent)
    arm.lose_link()
    with pytest.raises(KortexMotionError, match="lost"):
        driver.move_target(0.01, 0.0)
    driver.stop()  # safe to call, does not raise
    assert len(arm.sent) == sent_before
    assert not driver.connected


def test_leaving_the_with_block_through_an_exception_stops_and_disconnects(
    arm: StandInArm, video: str
) -> None:
    with pytest.raises(ZeroDivisionError), KortexArmDriver(camera=video, api=arm.api()) as robot:
        robot.home()
        robot.move_target(0.01, 0.01)
        _ = 1 / 0
    assert arm.methods()[-2:] == ["Stop", "CloseSession"]
    assert not arm.transport_connected


def test_missing_kortex_api_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch, video: str) -> None:
    monkeypatch.setitem(sys.modules, "kortex_api", None)  # as if the wheel were not installed
    with pytest.raises(KortexUnavailableError, match=KORTEX_WHEEL) as raised:
        load_kortex_api()
    assert "artifactory.kinovaapps.com" in str(raised.value) and "pip install" in str(raised.value)
    with pytest.raises(KortexUnavailableError):
        KortexArmDriver(camera=video).connect()


def test_grab_frame_is_the_centre_square_resized_in_rgb(driver: KortexArmDriver) -> None:
    frame = driver.grab_frame()
    assert frame.shape == (32, 32, 3) and frame.dtype == np.uint8
    left, middle, right = frame[16, 2], frame[16, 16], frame[16, 29]
    assert left[0] > 200 and left[2] < 60  # red stays red: BGR was turned into RGB
    assert right[2] > 200 and right[0] < 60
    assert middle[1] > 200  # the green band is in the centre of the crop


def test_centre_crop_keeps_the_middle_of_a_wide_frame() -> None:
    wide = np.zeros((100, 300, 3), np.uint8)
    wide[:, 100:200] = 255  # the centre square is all white
    assert centre_crop_resize(wide, 20).min() == 255


def test_a_camera_that_cannot_be_opened_says_so(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="could not open"):
        FixedCamera(str(tmp_path / "missing.avi")).grab()
