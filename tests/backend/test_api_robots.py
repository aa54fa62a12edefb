"""Robots: admins manage them, members see them, other households cannot."""

from apitest_helpers import make_robot, make_wav, upload_snapshot


def test_admin_creates_updates_and_lists_robots(admin, member) -> None:
    robot = admin.client.post(
        "/api/v1/robots", json={"name": "arm", "kind": "kinova-sim", "settings": {"fov": 48.8}}
    )
    assert robot.status_code == 201
    body = robot.json()
    assert (
        body["kind"] == "kinova-sim" and body["settings"] == {"fov": 48.8} and body["active_model_id"] is None
    )
    renamed = admin.client.patch(f"/api/v1/robots/{body['id']}", json={"name": "gen3"})
    assert renamed.json()["name"] == "gen3"
    assert [r["name"] for r in member.client.get("/api/v1/robots").json()] == ["gen3"]
    assert member.client.get(f"/api/v1/robots/{body['id']}").json()["kind"] == "kinova-sim"


def test_every_robot_kind_is_accepted_and_others_are_not(admin) -> None:
    for kind in ("kuka-sim", "turtlebot-sim", "kinova-sim", "kinova-real"):
        make_robot(admin, kind)
    assert admin.client.post("/api/v1/robots", json={"name": "x", "kind": "roomba"}).status_code == 422


def test_members_cannot_create_change_or_delete_robots(admin, member) -> None:
    robot = make_robot(admin)
    assert member.client.post("/api/v1/robots", json={"name": "x", "kind": "kuka-sim"}).status_code == 403
    assert member.client.patch(f"/api/v1/robots/{robot}", json={"name": "y"}).status_code == 403
    assert member.client.delete(f"/api/v1/robots/{robot}").status_code == 403


def test_a_robot_with_history_is_not_deleted(admin) -> None:
    empty, used = make_robot(admin), make_robot(admin)
    upload_snapshot(admin, used)
    assert admin.client.delete(f"/api/v1/robots/{empty}").status_code == 204
    response = admin.client.delete(f"/api/v1/robots/{used}")
    assert response.status_code == 409 and "snapshots" in response.json()["detail"]


def test_robots_of_another_household_are_404(admin, stranger) -> None:
    robot = make_robot(admin)
    assert stranger.client.get(f"/api/v1/robots/{robot}").status_code == 404
    assert stranger.client.patch(f"/api/v1/robots/{robot}", json={"name": "mine"}).status_code == 404
    assert stranger.client.delete(f"/api/v1/robots/{robot}").status_code == 404
    assert stranger.client.get("/api/v1/robots").json() == []


def test_a_room_the_worker_could_not_build_is_refused_saying_why(admin) -> None:
    kitchen = {"name": "arm", "kind": "kuka-sim", "settings": {"domain": "kitchen"}}
    refused = admin.client.post("/api/v1/robots", json=kitchen)
    assert refused.status_code == 422 and "unknown room 'kitchen'" in refused.json()["detail"]
    robot = make_robot(admin)
    marble = {"settings": {"domain": {"floor_texture": "marble"}}}
    refused = admin.client.patch(f"/api/v1/robots/{robot}", json=marble)
    assert refused.status_code == 422 and "settings.domain.floor_texture" in refused.json()["detail"]
    moved = admin.client.patch(f"/api/v1/robots/{robot}", json={"settings": {"domain": "unseen_room"}})
    assert moved.status_code == 200 and moved.json()["settings"] == {"domain": "unseen_room"}


def test_a_robot_id_beyond_any_database_id_is_refused_saying_which_field(member) -> None:
    """Found by the schema fuzz test: a 20-digit robot id reached SQLite and the API answered 500, both when
    trying a command and when choosing the robot the scene shows."""
    tried = member.client.post(
        "/api/v1/scene/tries",
        files={"file": ("said.wav", make_wav(), "audio/wav")},
        data={"robot_id": str(2**64)},
    )
    assert tried.status_code == 422 and "robot_id" in tried.text
    shown = member.client.put("/api/v1/scene/robot", json={"robot_id": 2**64})
    assert shown.status_code == 422 and "robot_id" in shown.text
    skipped = member.client.get("/api/v1/attempts/next", params={"skip": str(2**64)})
    assert skipped.status_code == 422 and "skip" in skipped.text
