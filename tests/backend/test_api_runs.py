"""Runs: admins start them (enqueued by task name), members watch them, cancel through a flag, live stream."""

import json
import threading

import pytest
from apitest_helpers import make_robot, queued_tasks

from varbot.services import wait_until


@pytest.fixture
def robot(admin) -> int:
    return make_robot(admin)


@pytest.fixture
def no_triplet_floor(monkeypatch):  # type: ignore[no-untyped-def]
    from backend.settings import get_settings

    monkeypatch.setattr(get_settings(), "min_triplets_for_training", 0)


@pytest.mark.parametrize(
    ("kind", "task"),
    [
        ("finetune", "varbot.finetune"),
        ("var_finetune", "varbot.var_finetune"),
        ("policy_improve", "varbot.policy_improve"),
        ("evaluate", "varbot.evaluate"),
    ],
)
def test_admin_starts_a_run_enqueued_by_task_name(
    admin, robot, redis_client, no_triplet_floor, kind, task
) -> None:
    response = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": kind, "preset": "standard"})
    assert response.status_code == 201, response.text
    run = response.json()
    assert run["status"] == "queued" and run["progress"] == 0 and run["requested_by_id"] == admin.user_id
    assert run["params"]["var_epochs"] == 20
    (message,) = queued_tasks(redis_client, "training")
    assert message["headers"]["task"] == task and message["headers"]["id"] == run["task_id"]
    assert f"'run_id': {run['id']}" in message["headers"]["kwargsrepr"]


def test_members_cannot_start_or_cancel_runs(admin, member, robot, no_triplet_floor) -> None:
    assert member.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).status_code == 403
    run = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()
    assert member.client.post(f"/api/v1/runs/{run['id']}:cancel").status_code == 403
    assert member.client.get(f"/api/v1/runs/{run['id']}").json()["id"] == run["id"]
    assert [r["id"] for r in member.client.get("/api/v1/runs").json()] == [run["id"]]


def test_parameters_are_validated_and_override_the_preset(admin, robot, no_triplet_floor) -> None:
    bad = admin.client.post(
        "/api/v1/runs", json={"robot_id": robot, "kind": "evaluate", "params": {"var_epochs": -1}}
    )
    assert bad.status_code == 422 and "var_epochs" in bad.json()["detail"]
    unknown = admin.client.post(
        "/api/v1/runs", json={"robot_id": robot, "kind": "evaluate", "params": {"lr": 1}}
    )
    assert unknown.status_code == 422 and "lr" in unknown.json()["detail"]
    assert admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "x"}).status_code == 422
    assert (
        admin.client.post(
            "/api/v1/runs", json={"robot_id": robot, "kind": "evaluate", "preset": "x"}
        ).status_code
        == 422
    )
    good = admin.client.post(
        "/api/v1/runs",
        json={"robot_id": robot, "kind": "evaluate", "preset": "quick", "params": {"eval_episodes": 7}},
    )
    assert good.json()["params"]["eval_episodes"] == 7 and good.json()["params"]["var_epochs"] == 5


def test_presets_are_published(member) -> None:
    presets = member.client.get("/api/v1/runs/presets").json()
    assert set(presets) == {"quick", "standard", "thorough"}
    assert presets["quick"]["policy_steps"] < presets["thorough"]["policy_steps"]
    minutes = [presets[name]["minutes_here"] for name in ("quick", "standard", "thorough")]
    assert 0 < minutes[0] < minutes[1] < minutes[2], "each preset states its budget in minutes"
    assert presets["standard"]["measured_by"] == "bench/results/household_4000_triplets.json"


def test_a_presets_budget_is_for_the_households_triplets_when_it_gives_them(member) -> None:
    measured = member.client.get("/api/v1/runs/presets").json()["thorough"]
    fewer = member.client.get("/api/v1/runs/presets", params={"triplets": 1000}).json()["thorough"]
    assert measured["budget_triplets"] == 4034 and fewer["budget_triplets"] == 1000
    assert fewer["minutes_here"] < measured["minutes_here"], "a VAR epoch over fewer triplets costs less"
    refused = member.client.get("/api/v1/runs/presets", params={"triplets": -1})
    assert refused.status_code == 422 and "triplets" in refused.text


def test_fine_tuning_is_refused_without_enough_triplets(admin, robot) -> None:
    response = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "finetune"})
    assert response.status_code == 409
    assert "at least 20 triplets" in response.json()["detail"] and "there are 0" in response.json()["detail"]


def test_one_unfinished_run_per_robot(admin, robot, no_triplet_floor) -> None:
    admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"})
    second = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"})
    assert second.status_code == 409 and "still queued or running" in second.json()["detail"]


def test_cancelling_a_queued_run_ends_it(admin, robot, no_triplet_floor) -> None:
    run = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()
    cancelled = admin.client.post(f"/api/v1/runs/{run['id']}:cancel").json()
    assert cancelled["status"] == "cancelled" and cancelled["cancel_requested"] and cancelled["finished_at"]
    assert admin.client.post(f"/api/v1/runs/{run['id']}:cancel").status_code == 409


def test_cancelling_a_running_run_sets_the_flag_for_the_worker(admin, robot, no_triplet_floor, db) -> None:
    from backend import models

    run_id = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()["id"]
    db.get(models.Run, run_id).status = "running"
    db.commit()
    response = admin.client.post(f"/api/v1/runs/{run_id}:cancel").json()
    assert response["status"] == "running" and response["cancel_requested"] is True


def test_a_run_that_cannot_be_queued_fails_visibly(admin, robot, no_triplet_floor, broker_down) -> None:
    response = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"})
    assert response.status_code == 503
    (run,) = admin.client.get("/api/v1/runs").json()
    assert run["status"] == "failed" and "could not be queued" in run["error"]


def test_runs_of_another_household_are_404(admin, stranger, robot, no_triplet_floor) -> None:
    run = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()
    assert stranger.client.get(f"/api/v1/runs/{run['id']}").status_code == 404
    assert stranger.client.post(f"/api/v1/runs/{run['id']}:cancel").status_code == 404
    assert (
        stranger.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).status_code == 404
    )
    assert stranger.client.get("/api/v1/runs").json() == []
    assert stranger.client.get(f"/api/v1/runs/events?run_id={run['id']}&timeout=1").status_code == 404


def _events(body: str) -> list[dict]:  # type: ignore[type-arg]
    return [json.loads(line[6:]) for line in body.splitlines() if line.startswith("data: ")]


def test_the_event_stream_sends_current_runs_then_updates_from_redis(
    admin, member, robot, no_triplet_floor
) -> None:
    from backend import broker

    run = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()
    update = dict(
        run, status="running", stage="evaluating", progress=0.5, updated_at="2999-01-01T00:00:00+00:00"
    )

    def worker_publishes_once_the_stream_listens() -> None:
        channel = broker.run_channel(admin.household_id)
        listening = lambda: broker.redis_client().pubsub_numsub(channel)[0][1] > 0  # noqa: E731
        wait_until(listening, 10, "the event stream to subscribe to its channel", interval=0.02)
        broker.publish(channel, {"type": "run", "run": update})

    threading.Thread(target=worker_publishes_once_the_stream_listens).start()
    response = member.client.get("/api/v1/runs/events?timeout=2")
    assert response.headers["content-type"].startswith("text/event-stream")
    events = _events(response.text)
    assert [(e["id"], e["status"]) for e in events] == [(run["id"], "queued"), (run["id"], "running")]
    assert events[1]["progress"] == 0.5


def test_the_event_stream_works_without_redis(admin, robot, no_triplet_floor, broker_down) -> None:
    assert admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).status_code == 503
    response = admin.client.get("/api/v1/runs/events?timeout=1")
    assert response.status_code == 200
    assert [e["status"] for e in _events(response.text)] == ["failed"]


def test_polling_finds_runs_changed_since_the_last_look(admin, robot, no_triplet_floor, db, sessions) -> None:
    import asyncio
    from datetime import UTC, datetime, timedelta

    from backend import models
    from backend.api.routes import runs as runs_routes

    run_id = admin.client.post("/api/v1/runs", json={"robot_id": robot, "kind": "evaluate"}).json()["id"]
    polls: list[datetime | None] = []

    def poll(since):  # type: ignore[no-untyped-def]
        polls.append(since)
        with sessions() as session:
            query = session.query(models.Run).filter(models.Run.household_id == admin.household_id)
            if since is not None:
                query = query.filter(models.Run.updated_at > since)
            from backend.schemas import RunPublic

            return [RunPublic.model_validate(r).model_dump(mode="json") for r in query]

    class Connected:
        async def is_disconnected(self) -> bool:
            if len(polls) == 1:  # after the first look, a worker moves the run on
                with sessions() as session:
                    row = session.get(models.Run, run_id)
                    row.stage, row.updated_at = "evaluating", datetime.now(UTC) + timedelta(seconds=5)
                    session.commit()
            return False

    async def collect() -> list[str]:
        stream = runs_routes.event_stream(
            Connected(), admin.household_id, None, 0.6, poll, "unix:///nonexistent", 0.1
        )
        return [chunk async for chunk in stream]

    chunks = asyncio.run(collect())
    stages = [e["stage"] for chunk in chunks for e in _events(chunk)]
    assert stages == ["queued", "evaluating"]


def test_the_thorough_preset_keeps_the_hidden_layer_its_policy_reads(member) -> None:
    presets = member.client.get("/api/v1/runs/presets").json()
    assert presets["thorough"]["var_keep_view"] > 0, "its fine-tune anchors the replayed views"
    assert presets["quick"]["var_keep_view"] == presets["standard"]["var_keep_view"] == 0
