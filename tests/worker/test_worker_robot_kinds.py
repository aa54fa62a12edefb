"""Every robot kind is added through the API and a run is started on it, through a real API, Redis and real
Celery workers: every simulated world has a shipped base model, so each simulated kind trains, and a real
arm's run goes to the robot worker, which reaches for the arm's driver."""

from functools import partial

import pytest
from conftest import TINY, Household, Stack

from core.robots import RobotKind, world_of_kind
from tests.sim.kortex_standin import StandInArm
from worker.base_models import find_base
from worker.real_arm import capture_arm_views, kortex_driver

pytestmark = [pytest.mark.slow, pytest.mark.speech]

ARM = {"arm_ip": "10.0.0.2", "camera": 0, "image_size": 16}
VIEWS = 4


def _add_robot(household: Household, kind: RobotKind) -> int:
    """The robot, added through the API, with a few views answered (a run needs 2 triplets): a simulated
    robot's rendered by the robot worker, a real arm's taken from the Kortex stand-in in this process."""
    name = f"every-kind-{kind.value}"
    if kind.simulated:
        return household.new_robot(name, views=VIEWS, kind=kind.value)
    body = {"name": name, "kind": kind.value, "settings": ARM}
    response = household.client.post("/api/v1/robots", json=body)
    assert response.status_code == 201, response.text
    robot = response.json()["id"]
    arm = StandInArm(image_size=ARM["image_size"])
    try:
        connect = partial(kortex_driver, api=arm.api(), open_capture=arm.video_capture)
        capture_arm_views(robot, household.household_id, VIEWS, connect=connect)
    finally:
        arm.close()
    for snapshot in household.snapshots(robot):
        household.answer(snapshot)  # no ground truth on a real arm: "nothing I said"
    return robot


def test_each_robot_kind_is_added_through_the_api_and_a_run_starts_on_it(
    stack: Stack, household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    runs = {
        kind: household.start_run(_add_robot(household, kind), kind="policy_improve", **TINY)
        for kind in RobotKind
    }
    for kind, run in runs.items():
        final = household.wait_run(run["id"], timeout=600)
        find_base(world_of_kind(kind))  # the workers look where this process looks: it would raise here
        if kind is RobotKind.KINOVA_REAL:  # the robot worker took it and reached for the arm's driver
            assert (final["status"], final["stage"]) == ("failed", "policy_improve"), final
            assert "KortexUnavailableError" in final["error"], final["error"]
        else:
            assert final["status"] == "succeeded", (kind, final["error"], stack.log("worker-robot")[-2000:])
