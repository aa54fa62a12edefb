"""The real Kinova arm's robot-queue work (worker/real_arm.py) against the Kortex stand-in, which moves the
PyBullet Gen3 and returns its rendered camera: views captured from the arm's camera, the household's commands
tried with the active policy on the arm, and a link lost mid-episode (the arm stops, the task fails saying
why, and what was stored stays). There is no real arm here; nothing has been tried on one."""

from collections.abc import Iterator
from functools import partial

import pytest
from conftest import Household, Stack

from sim.arm import WORKSPACE_X_M, WORKSPACE_Y_M
from sim.kortex_driver import KortexMotionError
from tests.sim.kortex_standin import StandInArm
from worker.real_arm import (
    WALK_STEPS_PER_VIEW,
    ArmNotConfigured,
    capture_arm_views,
    kortex_driver,
    try_arm_commands,
)

IMAGE = 16  # the tiny base model's size


@pytest.fixture
def standin() -> Iterator[StandInArm]:
    arm = StandInArm(image_size=IMAGE)
    yield arm
    arm.close()


def _connect(arm: StandInArm):  # type: ignore[no-untyped-def]
    return partial(kortex_driver, api=arm.api(), open_capture=arm.video_capture)


def _arm_robot(household: Household, name: str, **settings: object) -> int:
    body = {"name": name, "kind": "kinova-real", "settings": {"arm_ip": "10.0.0.2", "camera": 0, **settings}}
    response = household.client.post("/api/v1/robots", json=body)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _activate_tiny_model(robot_id: int) -> int:
    """The tiny base model (trained on the simulated Kuka: same observation contract) as the arm's active
    version."""
    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services import model_versions
    from worker.base_models import find_base

    base, blobs = find_base("kuka"), get_blob_store()
    with get_session_factory()() as session:
        version = model_versions.create_version(
            session, session.get_one(models.Robot, robot_id), var_key=blobs.put(base.var_path.read_bytes()),
            policy_key=blobs.put(base.policy_path.read_bytes()), notes="tiny model on the real arm",
        )  # fmt: skip
        model_versions.activate(session, version)
        return version.id


def test_views_captured_from_the_arm_camera_become_snapshots(
    stack: Stack, household: Household, standin: StandInArm
) -> None:
    robot = _arm_robot(household, "capture-arm", image_size=IMAGE)
    result = capture_arm_views(robot, household.household_id, 3, "capture-task", connect=_connect(standin))
    snapshots = household.snapshots(robot)
    assert result["created"] == 3 and len(snapshots) == 3
    for snapshot in snapshots:
        assert snapshot["source"] == "camera" and (snapshot["width"], snapshot["height"]) == (IMAGE, IMAGE)
        assert snapshot["meta"]["arm"] == "10.0.0.2" and "sim_heard" not in snapshot["meta"]
        x, y = snapshot["state"]
        assert WORKSPACE_X_M[0] - 1e-3 <= x <= WORKSPACE_X_M[1] + 1e-3
        assert WORKSPACE_Y_M[0] - 1e-3 <= y <= WORKSPACE_Y_M[1] + 1e-3
    assert standin.methods().count("ExecuteAction") == 1 + 3 * WALK_STEPS_PER_VIEW  # home's reach + walks
    assert standin.methods()[-2:] == ["Stop", "CloseSession"] and standin.violations == []


def test_the_arm_tries_the_households_commands_with_its_active_policy(
    stack: Stack, household: Household, standin: StandInArm
) -> None:
    robot = _arm_robot(household, "attempts-arm")
    version = _activate_tiny_model(robot)
    result = try_arm_commands(robot, household.household_id, 2, 1, [], "attempts-task", _connect(standin))
    assert (result["created"], result["random_views"]) == (2, 1)
    snapshots = household.snapshots(robot)
    attempts = [s for s in snapshots if s["source"] == "attempt"]
    assert len(attempts) == 2 and len(snapshots) == 3
    for attempt in attempts:
        assert attempt["meta"]["attempt"]["model_version_id"] == version
        assert attempt["meta"]["sim_heard"] is None  # a real arm has no ground truth
        assert attempt["meta"]["attempt"]["frames"]
    homes = standin.methods().count("ExecuteActionFromReference")
    assert homes == 3  # every attempt starts from home, and so does the capture of the random view
    assert standin.violations == []


def test_a_robot_without_an_arm_address_is_refused_saying_what_to_set(
    stack: Stack, household: Household, standin: StandInArm
) -> None:
    response = household.client.post("/api/v1/robots", json={"name": "no-ip-arm", "kind": "kinova-real"})
    with pytest.raises(ArmNotConfigured, match="arm_ip"):
        capture_arm_views(response.json()["id"], household.household_id, 1, connect=_connect(standin))
    assert standin.sent == []


def test_a_link_lost_mid_capture_stops_the_arm_fails_plainly_and_keeps_the_views_taken(
    stack: Stack, household: Household, standin: StandInArm
) -> None:
    robot = _arm_robot(household, "unplugged-arm", image_size=IMAGE)
    standin.moves_until_disconnect = 1 + 2 * WALK_STEPS_PER_VIEW + 3  # during the walk to the third view
    with pytest.raises(KortexMotionError, match=r"link to the arm at 10\.0\.0\.2 was lost") as failed:
        capture_arm_views(robot, household.household_id, 5, connect=_connect(standin))
    assert "KClientException" not in str(failed.value)
    assert standin.stopped_by_controller and not standin.transport_connected
    assert len(household.snapshots(robot)) == 2
