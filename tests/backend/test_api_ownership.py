"""What one member may do to the household's shared data: answers are their labeller's (or an admin's) to
change or undo, as clips are their speaker's; camera captures share an hourly quota per household."""

import pytest
from apitest_helpers import make_robot, queued_tasks, upload_clip, upload_snapshot


@pytest.fixture
def answer(admin, member) -> int:  # type: ignore[no-untyped-def]
    """bob's answer to one pair."""
    robot = make_robot(admin)
    body = {
        "snapshot_id": upload_snapshot(member, robot).json()["id"],
        "clip_id": upload_clip(member).json()["id"],
        "verdict": "is",
    }
    response = member.client.post("/api/v1/labels", json=body)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_another_member_can_neither_change_nor_undo_an_answer(make_person, member, answer) -> None:
    carol = make_person("carol")
    changed = carol.client.put(f"/api/v1/labels/{answer}", json={"verdict": "is_not"})
    assert changed.status_code == 403 and "who gave this answer (or an admin)" in changed.json()["detail"]
    assert carol.client.delete(f"/api/v1/labels/{answer}").status_code == 403
    kept = member.client.get(f"/api/v1/labels/{answer}").json()
    assert kept["verdict"] == "is" and [event["action"] for event in kept["history"]] == ["created"]


def test_the_labeller_and_an_admin_can(member, admin, answer) -> None:
    assert member.client.put(f"/api/v1/labels/{answer}", json={"verdict": "is_not"}).status_code == 200
    assert admin.client.put(f"/api/v1/labels/{answer}", json={"verdict": "is"}).status_code == 200
    assert admin.client.delete(f"/api/v1/labels/{answer}").status_code == 204


@pytest.fixture
def quota_of_30(monkeypatch):  # type: ignore[no-untyped-def]
    from backend.settings import get_settings

    monkeypatch.setattr(get_settings(), "capture_views_per_hour", 30)


def capture(person, robot: int, count: int):  # type: ignore[no-untyped-def]
    return person.client.post(f"/api/v1/robots/{robot}/snapshots:capture", json={"count": count})


def test_captures_beyond_the_household_hourly_quota_are_refused(
    admin, member, stranger, redis_client, quota_of_30
) -> None:
    robot = make_robot(admin)
    assert capture(member, robot, 12).status_code == 202
    assert capture(admin, robot, 12).status_code == 202  # the quota is the household's, not one member's
    refused = capture(member, robot, 12)
    assert refused.status_code == 429
    assert "30 camera views an hour and has 6 left" in refused.json()["detail"]
    assert 0 < int(refused.headers["Retry-After"]) <= 3600
    assert capture(member, robot, 6).status_code == 202, "a refused request uses none of the quota"
    assert capture(member, robot, 1).status_code == 429
    assert len(queued_tasks(redis_client, "robot")) == 3
    elsewhere = make_robot(stranger)
    assert capture(stranger, elsewhere, 30).status_code == 202, "another household has its own quota"
