"""Which queue a run goes to: a real arm's runs to the robot worker next to the arm (its policy stage drives
the arm), a simulated robot's to the training workers."""

import pytest
from apitest_helpers import queued_tasks

KINDS = ["finetune", "var_finetune", "policy_improve", "evaluate"]


@pytest.fixture
def no_triplet_floor(monkeypatch):  # type: ignore[no-untyped-def]
    from backend.settings import get_settings

    monkeypatch.setattr(get_settings(), "min_triplets_for_training", 0)


def _robot(admin, kind: str, **settings: object) -> int:  # type: ignore[no-untyped-def]
    body = {"name": f"{kind}-robot", "kind": kind, "settings": settings}
    response = admin.client.post("/api/v1/robots", json=body)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _start(admin, robot: int, kind: str) -> dict:  # type: ignore[no-untyped-def]
    response = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": kind, "preset": "quick"})
    assert response.status_code == 201, response.text
    run = response.json()
    assert admin.client.post(f"/api/v1/runs/{run['id']}:cancel").status_code == 200  # one per robot at once
    return run


def test_every_run_of_a_real_arm_goes_to_the_robot_queue(admin, redis_client, no_triplet_floor) -> None:  # type: ignore[no-untyped-def]
    robot = _robot(admin, "kinova-real", arm_ip="10.0.0.2")
    runs = [_start(admin, robot, kind) for kind in KINDS]
    queued = queued_tasks(redis_client, "robot")
    sent = {message["headers"]["id"]: message["headers"]["task"] for message in queued}
    assert sent == {run["task_id"]: f"varbot.{kind}" for run, kind in zip(runs, KINDS, strict=True)}
    assert queued_tasks(redis_client, "training") == []


@pytest.mark.parametrize("kind", ["kuka-sim", "turtlebot-sim", "kinova-sim"])
def test_runs_of_a_simulated_robot_go_to_the_training_queue(
    admin, redis_client, no_triplet_floor, kind
) -> None:  # type: ignore[no-untyped-def]
    run = _start(admin, _robot(admin, kind), "policy_improve")
    (message,) = queued_tasks(redis_client, "training")
    assert message["headers"]["id"] == run["task_id"]
    assert queued_tasks(redis_client, "robot") == []


def test_a_real_arms_run_whose_worker_died_is_sent_back_to_the_robot_queue(
    admin, redis_client, no_triplet_floor, db, sessions, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    from backend import models
    from worker import lease
    from worker.lease import requeue_orphaned_runs

    monkeypatch.setattr(
        lease, "get_session_factory", lambda: sessions
    )  # the janitor reads the API's database

    robot = _robot(admin, "kinova-real", arm_ip="10.0.0.2")
    response = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "policy_improve"})
    run_id = response.json()["id"]
    redis_client.delete("robot")  # a worker took it from the queue ...
    db.get(models.Run, run_id).status = "running"  # ... started it, and died: no lease is held
    db.commit()
    assert run_id in requeue_orphaned_runs()
    (message,) = queued_tasks(redis_client, "robot")
    assert message["headers"]["task"] == "varbot.policy_improve" and f"'run_id': {run_id}" in str(
        message["headers"]["kwargsrepr"]
    )
    assert queued_tasks(redis_client, "training") == []
