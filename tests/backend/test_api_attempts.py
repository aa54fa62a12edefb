"""The robot's attempts and "did it do what I said?": asking the robot worker for attempts (and what cannot
work), the next attempt to judge with its replay, and each answer stored as ordinary is / is-not labels."""

import json

import pytest
from apitest_helpers import make_png, make_robot, queued_tasks, upload_clip, upload_snapshot

from backend.services.attempts import NOTHING, Command, labels_for_answer, random_view_count, shown_command
from core.labels import Verdict

COMMANDS = {
    "name:one": Command("name:one", "one", (1, 2)),
    "name:two": Command("name:two", "two", (3,)),
    "name:three": Command("name:three", "three", (4,)),
}


def _verdicts(shown: str | None) -> dict[int, str]:
    return {clip: verdict.value for clip, verdict in labels_for_answer(COMMANDS, shown)}


def test_yes_is_for_the_asked_command_and_is_not_for_every_other() -> None:
    shown = shown_command(COMMANDS, "name:one", True, None)
    assert _verdicts(shown) == {1: "is", 2: "is", 3: "is_not", 4: "is_not"}


def test_no_with_another_command_is_for_that_one_and_is_not_for_the_rest_the_asked_one_included() -> None:
    shown = shown_command(COMMANDS, "name:one", False, "name:three")
    assert _verdicts(shown) == {1: "is_not", 2: "is_not", 3: "is_not", 4: "is"}


def test_no_with_nothing_is_not_for_every_command() -> None:
    assert shown_command(COMMANDS, "name:two", False, NOTHING) is None
    assert set(_verdicts(None).values()) == {Verdict.IS_NOT.value}


@pytest.mark.parametrize(
    ("asked", "instead", "says"),
    [
        ("name:one", None, "say what the view shows instead"),
        ("name:one", "name:one", "answer 'yes' instead"),
        ("name:one", "name:four", "none of the household's commands"),
        ("name:gone", NOTHING, "no recording left"),
    ],
)
def test_an_answer_that_cannot_be_a_label_says_why(asked: str, instead: str | None, says: str) -> None:
    from backend.errors import Invalid

    with pytest.raises(Invalid, match=says):
        shown_command(COMMANDS, asked, False, instead)


def test_random_views_are_the_asked_share_of_all_views() -> None:
    assert random_view_count(30, 0.25) == 10 and random_view_count(30, 0.0) == 0
    assert random_view_count(1, 0.5) == 1


# --- the API ------------------------------------------------------------------------------------------------


def _record(person, *names: str) -> dict[str, list[int]]:  # type: ignore[no-untyped-def]
    clips: dict[str, list[int]] = {}
    for name in names:
        response = upload_clip(person, name=name)
        assert response.status_code == 201, response.text
        clips.setdefault(name, []).append(response.json()["id"])
    return clips


def _attempt(db, blob_store, robot_id: int, command: str, clip_id: int, frames: int = 3) -> int:  # type: ignore[no-untyped-def]
    """An attempt as the robot worker stores it (`worker.attempts`)."""
    from backend import models
    from backend.services.snapshots import create_snapshot

    keys = [blob_store.put(make_png(seed=100 + i)) for i in range(frames)]
    meta = {"attempt": {"command": command, "clip_id": clip_id, "frames": keys}, "sim_heard": None}
    robot = db.get(models.Robot, robot_id)
    return create_snapshot(db, blob_store, robot, make_png(seed=7), [0.6, 0.1], "attempt", meta).id


def test_a_member_judges_an_attempt_and_the_answer_becomes_full_labels_with_triplets(
    admin, member, db, blob_store
) -> None:  # type: ignore[no-untyped-def]
    clips = _record(admin, "one", "one", "two", "three")
    robot = make_robot(admin)
    attempt = _attempt(db, blob_store, robot, "name:two", clips["two"][0])
    upload_snapshot(admin, robot)  # an ordinary view is never offered as an attempt

    offered = member.client.get("/api/v1/attempts/next", params={"robot_id": robot}).json()
    assert offered["snapshot"]["id"] == attempt and offered["asked"]["name"] == "two"
    assert offered["clip_id"] == clips["two"][0]
    assert [c["name"] for c in offered["others"]] == ["one", "three"]
    assert offered["frames"] == [f"/api/v1/attempts/{attempt}/frames/{i}" for i in range(3)]
    frame = member.client.get(offered["frames"][1])
    assert frame.status_code == 200 and frame.headers["content-type"] == "image/png"
    assert frame.content == make_png(seed=101)
    assert member.client.get(f"/api/v1/attempts/{attempt}/frames/3").status_code == 404

    answered = member.client.post(
        f"/api/v1/attempts/{attempt}/answer", json={"answer": "no", "instead": offered["others"][0]["key"]}
    )
    assert answered.status_code == 201, answered.text
    body = answered.json()
    assert body["shows"] == "one"
    verdicts = {label["clip_id"]: label["verdict"] for label in body["labels"]}
    assert verdicts == {clips["one"][0]: "is", clips["one"][1]: "is", clips["two"][0]: "is_not",
                        clips["three"][0]: "is_not"}  # fmt: skip
    stats = member.client.get("/api/v1/triplets/stats", params={"robot_id": robot}).json()
    assert stats["triplets"] == 2 * 2 and stats["labels"] == 4
    assert member.client.get("/api/v1/attempts/next", params={"robot_id": robot}).json()["snapshot"] is None
    again = member.client.post(f"/api/v1/attempts/{attempt}/answer", json={"answer": "yes"})
    assert again.status_code == 409 and "already answered" in again.json()["detail"]
    history = member.client.get(f"/api/v1/labels/{body['labels'][0]['id']}").json()["history"]
    assert [event["action"] for event in history] == ["created"]


def test_undo_removes_every_label_an_answer_created_and_the_attempt_is_offered_again(
    admin, db, blob_store
) -> None:  # type: ignore[no-untyped-def]
    clips = _record(admin, "one", "two")
    robot = make_robot(admin)
    attempt = _attempt(db, blob_store, robot, "name:one", clips["one"][0])
    stored = admin.client.post(
        f"/api/v1/attempts/{attempt}/answer", json={"answer": "no", "instead": NOTHING}
    )
    assert stored.status_code == 201 and stored.json()["shows"] == NOTHING
    stats = admin.client.get("/api/v1/triplets/stats").json()
    assert stats["triplets"] == stats["with_silence_positive"] == 2, "nothing we said: silence triplets"
    for label in stored.json()["labels"]:
        assert admin.client.delete(f"/api/v1/labels/{label['id']}").status_code == 204
    assert admin.client.get("/api/v1/triplets/stats").json()["labels"] == 0
    assert admin.client.get("/api/v1/attempts/next").json()["snapshot"]["id"] == attempt


def test_only_the_robot_worker_makes_attempts_and_another_household_cannot_see_them(
    admin, stranger, db, blob_store
) -> None:  # type: ignore[no-untyped-def]
    clips = _record(admin, "one")
    robot = make_robot(admin)
    attempt = _attempt(db, blob_store, robot, "name:one", clips["one"][0])
    uploaded = upload_snapshot(admin, robot, meta=json.dumps({"attempt": {"frames": ["f" * 64]}}))
    assert uploaded.status_code == 201 and uploaded.json()["source"] == "upload"
    forged = admin.client.post(
        f"/api/v1/robots/{robot}/snapshots",
        files={"image": ("f.png", make_png(), "image/png")},
        data={"source": "attempt", "meta": json.dumps({"attempt": {"frames": ["f" * 64]}})},
    )
    assert forged.status_code == 422 and "robot worker" in forged.json()["detail"]
    assert admin.client.get(f"/api/v1/attempts/{uploaded.json()['id']}/frames/0").status_code == 404
    assert stranger.client.get(f"/api/v1/attempts/{attempt}/frames/0").status_code == 404
    assert (
        stranger.client.post(f"/api/v1/attempts/{attempt}/answer", json={"answer": "yes"}).status_code == 404
    )
    assert stranger.client.get("/api/v1/attempts/next").json()["snapshot"] is None


def test_asking_for_attempts_sends_the_robot_task_with_the_commands_and_a_share_of_random_views(
    admin, redis_client
) -> None:  # type: ignore[no-untyped-def]
    _record(admin, "one", "two")
    robot = make_robot(admin)
    response = admin.client.post(
        f"/api/v1/robots/{robot}/attempts", json={"count": 6, "random_share": 0.25, "commands": ["Two"]}
    )
    assert response.status_code == 202, response.text
    queued = response.json()
    assert (queued["attempts"], queued["random_views"], queued["commands"]) == (6, 2, ["two"])
    (task,) = queued_tasks(redis_client, "robot")
    assert task["headers"]["task"] == "varbot.try_commands" and task["headers"]["id"] == queued["task_id"]
    assert "'commands': ['name:two']" in task["headers"]["kwargsrepr"]
    status = admin.client.get(f"/api/v1/robots/{robot}/attempts/{queued['task_id']}")
    assert status.status_code == 200 and status.json()["state"] == "queued"
    assert admin.client.get(f"/api/v1/robots/{robot}/attempts/{'0' * 32}").status_code == 404


def test_what_cannot_be_attempted_says_why_and_what_to_do(admin) -> None:  # type: ignore[no-untyped-def]
    robot = make_robot(admin)
    nothing = admin.client.post(f"/api/v1/robots/{robot}/attempts", json={"count": 2})
    assert nothing.status_code == 409 and "record some on the Record page" in nothing.json()["detail"]
    _record(admin, "one")
    unknown = admin.client.post(f"/api/v1/robots/{robot}/attempts", json={"count": 2, "commands": ["four"]})
    assert unknown.status_code == 422
    assert "no recording of 'four': record it on the Record page first" in unknown.json()["detail"]
    real = make_robot(admin, "kinova-real", "real arm")
    refused = admin.client.post(f"/api/v1/robots/{real}/attempts", json={"count": 2})
    assert refused.status_code == 409 and "simulated robots" in refused.json()["detail"]


def test_attempts_say_503_when_the_broker_is_down(admin, broker_down) -> None:  # type: ignore[no-untyped-def]
    _record(admin, "one")
    robot = make_robot(admin)
    response = admin.client.post(f"/api/v1/robots/{robot}/attempts", json={"count": 2})
    assert response.status_code == 503 and "not reachable" in response.json()["detail"]
