"""The real Kinova arm's work (worker/real_arm.py) against the Kortex stand-in, which moves the PyBullet Gen3
and returns its rendered camera: views captured from the arm's camera, the household's commands tried with the
active policy on the arm, policy self-improvement on the arm within a step budget (with cancel and the run's
progress), and a link lost mid-episode (the arm stops, the work fails saying why, and what was stored stays).
The runs execute in this process (`worker.pipeline.execute_run`, the training worker's own entry point), so
the stand-in can be handed to them. There is no real arm here; nothing has been tried on one."""

import threading
from collections.abc import Iterator
from functools import partial

import pytest
from conftest import TINY, Household, Stack, wait_until

from sim.arm import WORKSPACE_X_M, WORKSPACE_Y_M
from sim.kortex_driver import KortexMotionError
from tests.sim.kortex_standin import StandInArm
from varbot.simulated_household import WORDS
from worker import real_arm
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


# --- self-improvement on the arm ----------------------------------------------------------------------------

STEPS_PER_UPDATE = 12  # the tiny policy's num_steps, on the arm's one env


def _labelled_arm(household: Household, standin: StandInArm, name: str) -> tuple[int, int]:
    """An arm with the tiny model active and 3 views captured, each answered "nothing I said"."""
    robot = _arm_robot(household, name, image_size=IMAGE)
    version = _activate_tiny_model(robot)
    capture_arm_views(robot, household.household_id, 3, connect=_connect(standin))
    for snapshot in household.snapshots(robot):
        for word in WORDS:
            body = {
                "snapshot_id": snapshot["id"],
                "clip_id": household.clip_ids[(word, "en")],
                "verdict": "is_not",
            }
            assert household.client.post("/api/v1/labels", json=body).status_code == 201
    standin.sent.clear()
    return robot, version


def _start_on_arm(
    household: Household, robot: int, standin: StandInArm, monkeypatch: pytest.MonkeyPatch, steps: int
) -> tuple[dict, threading.Thread]:
    from worker.pipeline import execute_run

    monkeypatch.setattr(real_arm, "connect_arm", _connect(standin))
    run = _run_for_this_process(household, robot, steps, monkeypatch)
    worker = threading.Thread(target=execute_run, args=(run["id"],), daemon=True)
    worker.start()
    return run, worker


def _run_for_this_process(
    household: Household, robot: int, steps: int, monkeypatch: pytest.MonkeyPatch
) -> dict:
    """A policy_improve run made as the API makes it, but not sent to the robot queue: this process, which has
    the stand-in, is its worker (the stack's robot worker would take it from the queue and reach for a real
    arm)."""
    from sqlalchemy import select

    from backend import broker, models
    from backend.db import get_session_factory
    from backend.schemas import RunCreate
    from backend.services import runs

    body = RunCreate(robot_id=robot, kind="policy_improve", params={**TINY, "policy_steps": steps})
    with monkeypatch.context() as unsent, get_session_factory()() as session:
        unsent.setattr(broker, "send_task", lambda name, kwargs, queue, task_id: task_id)
        parent = session.scalar(
            select(models.User).where(
                models.User.household_id == household.household_id, models.User.username == "parent"
            )
        )
        run_id = runs.create_run(session, parent, body, min_triplets=0).id
    return household.run(run_id)


def _what_stays(household: Household, robot: int) -> tuple[list, list, list]:
    labels = household.client.get("/api/v1/labels", params={"robot_id": robot, "limit": 500}).json()
    clips = household.client.get("/api/v1/clips").json()
    active = [v["id"] for v in household.versions(robot) if v["status"] == "active"]
    return labels, clips, active


def test_the_policy_improves_itself_on_the_arm_within_its_step_budget(
    stack: Stack, household: Household, standin: StandInArm, monkeypatch: pytest.MonkeyPatch
) -> None:
    robot, _ = _labelled_arm(household, standin, "improving-arm")
    run, worker = _start_on_arm(household, robot, standin, monkeypatch, 2 * STEPS_PER_UPDATE)
    worker.join(600)
    final = household.run(run["id"])
    assert final["status"] == "succeeded", final["error"]
    curve = final["metrics"]["curves"]["policy_improve"]
    assert [point["env_steps"] for point in curve] == [STEPS_PER_UPDATE, 2 * STEPS_PER_UPDATE]
    assert standin.methods().count("ExecuteAction") >= 2 * STEPS_PER_UPDATE  # every step moved the arm
    assert standin.methods().count("ExecuteActionFromReference") >= 2  # episodes start from home
    assert standin.methods()[-2:] == ["Stop", "CloseSession"] and standin.violations == []
    assert [v for v in household.versions(robot) if v["run_id"] == run["id"]]


def test_cancelling_a_run_on_the_arm_stops_the_arm_and_keeps_the_active_model(
    stack: Stack, household: Household, standin: StandInArm, monkeypatch: pytest.MonkeyPatch
) -> None:
    robot, _ = _labelled_arm(household, standin, "cancelled-arm")
    before = _what_stays(household, robot)
    run, worker = _start_on_arm(household, robot, standin, monkeypatch, 400 * STEPS_PER_UPDATE)
    wait_until(
        lambda: household.run(run["id"])["metrics"].get("curves", {}).get("policy_improve"), 180, "an update"
    )
    assert household.client.post(f"/api/v1/runs/{run['id']}:cancel").status_code == 200
    worker.join(120)
    final = household.run(run["id"])
    assert (final["status"], final["stage"]) == ("cancelled", "policy_improve")
    assert standin.methods()[-2:] == ["Stop", "CloseSession"]
    assert _what_stays(household, robot) == before


def test_a_link_lost_mid_episode_fails_the_run_plainly_and_loses_nothing(
    stack: Stack, household: Household, standin: StandInArm, monkeypatch: pytest.MonkeyPatch
) -> None:
    robot, _ = _labelled_arm(household, standin, "unplugged-run-arm")
    before = _what_stays(household, robot)
    standin.moves_until_disconnect = 3 * STEPS_PER_UPDATE  # after two updates, each with its checkpoint
    run, worker = _start_on_arm(household, robot, standin, monkeypatch, 50 * STEPS_PER_UPDATE)
    worker.join(600)
    final = household.run(run["id"])
    assert (final["status"], final["stage"]) == ("failed", "policy_improve")
    assert "KortexMotionError" in final["error"] and "link to the arm at 10.0.0.2 was lost" in final["error"]
    assert standin.stopped_by_controller and not standin.transport_connected
    assert "policy_checkpoint" in final["metrics"]["artifacts"] and final["checkpoints"]
    assert _what_stays(household, robot) == before
    assert not [v for v in household.versions(robot) if v["run_id"] == run["id"]]


def test_the_robot_worker_without_kortex_api_fails_an_arms_attempts_saying_how_to_install_it(
    stack: Stack, household: Household
) -> None:
    """Through the API, Redis and the stack's robot worker, which has no Kortex stand-in and no kortex_api."""
    robot = _arm_robot(household, "worker-arm")
    _activate_tiny_model(robot)
    response = household.client.post(f"/api/v1/robots/{robot}/attempts", json={"count": 1})
    assert response.status_code == 202, response.text
    task_id = response.json()["task_id"]

    def ended() -> dict | None:
        status = household.client.get(f"/api/v1/robots/{robot}/attempts/{task_id}").json()
        return status if status["state"] in ("done", "refused", "failed") else None

    status = wait_until(ended, 180, "the attempts task to end", interval=0.5)
    assert status["state"] == "failed" and "KortexUnavailableError" in status["message"]
    assert "kortex_api" in status["message"] and "pip install" in status["message"]
    assert household.snapshots(robot) == []


def test_a_run_on_the_arm_is_taken_by_the_robot_worker_next_to_it(
    stack: Stack, household: Household, standin: StandInArm
) -> None:
    """Through the API and Redis with no training worker running: the arm's run goes to the robot queue, and
    the stack's robot worker (no stand-in, no kortex_api) takes it and fails it at the arm's driver, saying
    how to install Kinova's wheel; the active model stays. (The views are labelled from the stand-in.)"""
    robot, version = _labelled_arm(household, standin, "queued-arm")
    run = household.start_run(robot, kind="policy_improve", **{**TINY, "policy_steps": STEPS_PER_UPDATE})
    final = household.wait_run(run["id"], timeout=300)
    assert (final["status"], final["stage"]) == ("failed", "policy_improve"), final
    assert "KortexUnavailableError" in final["error"] and "kortex_api" in final["error"], final["error"]
    assert [v["id"] for v in household.versions(robot) if v["status"] == "active"] == [version]
