"""Model versions: listing, activation, rollback (admins only), embeddings, household scoping."""

import pytest
from apitest_helpers import make_robot


@pytest.fixture
def versions(admin, db):  # type: ignore[no-untyped-def]
    """A robot with three candidate versions, each the child of the previous one."""
    from backend import models
    from backend.services import model_versions

    robot_id = make_robot(admin)
    robot = db.get(models.Robot, robot_id)
    made = []
    for i in range(3):
        version = model_versions.create_version(
            db,
            robot,
            var_key=f"{i:064d}",
            policy_key=None,
            parent_id=made[-1] if made else None,
            metrics={"i": i},
        )
        made.append(version.id)
    db.commit()
    return robot_id, made


def test_versions_are_listed_with_parent_and_metrics(member, versions) -> None:
    robot, (v1, v2, v3) = versions
    listed = member.client.get(f"/api/v1/robots/{robot}/models").json()
    assert [v["id"] for v in listed] == [v3, v2, v1]
    assert (
        listed[0]["parent_id"] == v2
        and listed[0]["status"] == "candidate"
        and listed[0]["metrics"] == {"i": 2}
    )
    assert listed[0]["has_var"] and not listed[0]["has_policy"]
    assert member.client.get(f"/api/v1/models/{v1}").json()["parent_id"] is None


def test_activation_retires_the_previous_version_and_rollback_walks_back(admin, versions) -> None:
    robot, (v1, v2, v3) = versions
    for version in (v1, v2, v3):
        assert admin.client.post(f"/api/v1/models/{version}:activate").json()["status"] == "active"
    statuses = {v["id"]: v["status"] for v in admin.client.get(f"/api/v1/robots/{robot}/models").json()}
    assert statuses == {v1: "retired", v2: "retired", v3: "active"}
    assert admin.client.get(f"/api/v1/robots/{robot}").json()["active_model_id"] == v3
    assert admin.client.post(f"/api/v1/robots/{robot}/models:rollback").json()["id"] == v2
    assert admin.client.post(f"/api/v1/robots/{robot}/models:rollback").json()["id"] == v1
    assert admin.client.get(f"/api/v1/robots/{robot}").json()["active_model_id"] == v1
    nothing = admin.client.post(f"/api/v1/robots/{robot}/models:rollback")
    assert nothing.status_code == 409 and "no earlier" in nothing.json()["detail"]
    name = admin.client.get(f"/api/v1/robots/{robot}").json()["name"]
    assert name in nothing.json()["detail"] and f"robot {robot}" not in nothing.json()["detail"]  # its name


def test_activating_the_active_version_changes_nothing(admin, versions) -> None:
    _, (v1, *_) = versions
    admin.client.post(f"/api/v1/models/{v1}:activate")
    again = admin.client.post(f"/api/v1/models/{v1}:activate").json()
    assert again["status"] == "active" and again["previous_active_id"] is None


def test_members_cannot_activate_or_roll_back(member, versions) -> None:
    robot, (v1, *_) = versions
    assert member.client.post(f"/api/v1/models/{v1}:activate").status_code == 403
    assert member.client.post(f"/api/v1/robots/{robot}/models:rollback").status_code == 403
    assert member.client.put(f"/api/v1/models/{v1}/embeddings", json={}).status_code == 403


def test_embeddings_are_stored_and_replaced(admin, versions) -> None:
    from apitest_helpers import upload_snapshot

    robot, (v1, *_) = versions
    snapshot = upload_snapshot(admin, robot).json()["id"]
    url = f"/api/v1/models/{v1}/embeddings"
    assert admin.client.put(url, json={"snapshots": {snapshot: [1, 0, 0]}}).status_code == 200
    admin.client.put(url, json={"snapshots": {snapshot: [0, 0, 1]}})
    assert admin.client.get(url).json()["snapshots"] == {str(snapshot): [0, 0, 1]}
    mixed = admin.client.put(url, json={"snapshots": {snapshot: [1, 0]}, "clips": {}})
    assert mixed.status_code == 200
    from apitest_helpers import upload_clip

    clip = upload_clip(admin).json()["id"]
    uneven = admin.client.put(url, json={"snapshots": {snapshot: [1, 0]}, "clips": {clip: [1, 0, 0]}})
    assert uneven.status_code == 422 and "same length" in uneven.json()["detail"]
    missing = admin.client.put(url, json={"clips": {"999999": [1, 0, 0]}})
    assert missing.status_code == 404


def test_versions_of_another_household_are_404(stranger, versions) -> None:
    robot, (v1, *_) = versions
    assert stranger.client.get(f"/api/v1/models/{v1}").status_code == 404
    assert stranger.client.post(f"/api/v1/models/{v1}:activate").status_code == 404
    assert stranger.client.get(f"/api/v1/robots/{robot}/models").status_code == 404
    assert stranger.client.post(f"/api/v1/robots/{robot}/models:rollback").status_code == 404
    assert stranger.client.get(f"/api/v1/models/{v1}/embeddings").status_code == 404
