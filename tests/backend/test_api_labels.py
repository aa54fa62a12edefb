"""Labels: is / is not, change and undo with history, the next pair to ask about, triplet counts."""

import pytest
from apitest_helpers import make_robot, make_wav, upload_clip, upload_snapshot


@pytest.fixture
def scene(admin, member):  # type: ignore[no-untyped-def]
    """A robot with three views and two commands ("left" by bob, "right" by alice)."""
    robot = make_robot(admin)
    snapshots = [upload_snapshot(member, robot, seed=i).json()["id"] for i in range(3)]
    left = upload_clip(member, make_wav(frequency=300), name="left").json()["id"]
    right = upload_clip(admin, make_wav(frequency=600), name="right").json()["id"]
    return robot, snapshots, left, right


def label(person, snapshot_id: int, clip_id: int, verdict: str):  # type: ignore[no-untyped-def]
    return person.client.post(
        "/api/v1/labels", json={"snapshot_id": snapshot_id, "clip_id": clip_id, "verdict": verdict}
    )


def test_a_verdict_is_created_changed_and_undone_with_its_history(member, admin, scene) -> None:
    _, (s0, *_), left, _ = scene
    created = label(member, s0, left, "is")
    assert created.status_code == 201
    label_id = created.json()["id"]
    assert created.json()["labeller_id"] == member.user_id
    changed = admin.client.put(f"/api/v1/labels/{label_id}", json={"verdict": "is_not"})
    assert changed.json()["verdict"] == "is_not" and changed.json()["updated_by_id"] == admin.user_id
    detail = member.client.get(f"/api/v1/labels/{label_id}").json()
    assert [(e["action"], e["verdict"], e["user_id"]) for e in detail["history"]] == [
        ("created", "is", member.user_id),
        ("changed", "is_not", admin.user_id),
    ]
    assert member.client.delete(f"/api/v1/labels/{label_id}").status_code == 204
    assert member.client.get(f"/api/v1/labels/{label_id}").status_code == 404
    assert label(member, s0, left, "is").status_code == 201  # the pair can be answered again after undo


def test_a_pair_is_answered_once(member, admin, scene) -> None:
    _, (s0, *_), left, _ = scene
    label(member, s0, left, "is")
    again = label(admin, s0, left, "is_not")
    assert again.status_code == 409 and "PUT /labels/" in again.json()["detail"]


def test_verdicts_are_is_or_is_not(member, scene) -> None:
    _, (s0, *_), left, _ = scene
    assert label(member, s0, left, "maybe").status_code == 422


def test_labels_are_listed_and_filtered(member, admin, scene) -> None:
    _, (s0, s1, _), left, right = scene
    label(member, s0, left, "is")
    label(admin, s1, right, "is_not")
    assert len(member.client.get("/api/v1/labels").json()) == 2
    assert [
        x["clip_id"] for x in member.client.get(f"/api/v1/labels?labeller_id={admin.user_id}").json()
    ] == [right]
    assert len(member.client.get(f"/api/v1/labels?snapshot_id={s0}&clip_id={left}").json()) == 1


def test_next_pair_never_repeats_and_runs_dry(member, scene) -> None:
    _, snapshots, left, right = scene
    seen = set()
    for _ in range(len(snapshots) * 2):
        pair = member.client.get("/api/v1/labels/next").json()
        assert pair["strategy"] == "balanced"
        key = (pair["snapshot"]["id"], pair["clip"]["id"])
        assert key not in seen
        seen.add(key)
        assert label(member, *key, "is_not").status_code == 201
    assert seen == {(s, c) for s in snapshots for c in (left, right)}
    done = member.client.get("/api/v1/labels/next").json()
    assert done["snapshot"] is None and done["strategy"] == "none" and "capture more" in done["message"]


def test_next_pair_balances_commands(member, scene) -> None:
    _, _, left, right = scene
    asked = []
    for _ in range(4):
        pair = member.client.get("/api/v1/labels/next").json()
        asked.append(pair["clip"]["id"])
        label(member, pair["snapshot"]["id"], pair["clip"]["id"], "is")
    assert asked.count(left) == asked.count(right) == 2


def test_next_pair_finishes_an_image_before_starting_another(member, scene) -> None:
    first = member.client.get("/api/v1/labels/next").json()
    label(member, first["snapshot"]["id"], first["clip"]["id"], "is")
    second = member.client.get("/api/v1/labels/next").json()
    assert second["snapshot"]["id"] == first["snapshot"]["id"] and second["clip"]["id"] != first["clip"]["id"]


def test_images_are_asked_about_every_command_before_a_second_clip_of_one(member, admin, scene) -> None:
    _, snapshots, left, right = scene
    left_by_alice = upload_clip(admin, make_wav(frequency=330), name="left").json()["id"]
    command = {left: "left", left_by_alice: "left", right: "right"}

    def answer_next() -> tuple[int, int]:
        pair = member.client.get("/api/v1/labels/next").json()
        key = (pair["snapshot"]["id"], pair["clip"]["id"])
        assert label(member, *key, "is_not").status_code == 201
        return key

    first_round = [answer_next() for _ in range(len(snapshots) * 2)]
    assert sorted((s, command[c]) for s, c in first_round) == sorted(
        (s, name) for s in snapshots for name in ("left", "right")
    )
    # then the "left" clip each image was not asked about
    other_left = {s: ({left, left_by_alice} - {c}).pop() for s, c in first_round if command[c] == "left"}
    assert {answer_next() for _ in range(len(snapshots))} == set(other_left.items())


def test_members_labelling_at_once_are_asked_different_pairs(member, admin, scene) -> None:
    asked = [person.client.get("/api/v1/labels/next").json() for person in (member, admin)]
    pairs = [(pair["snapshot"]["id"], pair["clip"]["id"]) for pair in asked]
    assert pairs[0] != pairs[1]
    again = member.client.get("/api/v1/labels/next").json()  # a member is not kept from their own pair
    assert (again["snapshot"]["id"], again["clip"]["id"]) != pairs[1]
    assert label(admin, *pairs[1], "is").status_code == 201  # no 409: nobody else was answering it


def test_when_every_pair_is_being_answered_one_is_asked_anyway(member, admin) -> None:
    robot = make_robot(admin)
    only = (upload_snapshot(member, robot).json()["id"], upload_clip(member, make_wav()).json()["id"])
    for person in (member, admin):
        pair = person.client.get("/api/v1/labels/next").json()
        assert (pair["snapshot"]["id"], pair["clip"]["id"]) == only
    assert label(member, *only, "is").status_code == 201
    assert label(admin, *only, "is_not").status_code == 409  # the race the leases avoid when they can


def test_next_pair_with_no_commands_asks_to_record_one(admin) -> None:
    upload_snapshot(admin, make_robot(admin))
    assert admin.client.get("/api/v1/labels/next").json()["clip"] is None


def test_next_pair_prefers_images_between_two_commands_once_a_model_exists(admin, member, scene, db) -> None:
    from backend import models

    robot, (s0, s1, s2), left, right = scene
    version = models.ModelVersion(
        household_id=admin.household_id, robot_id=robot, status="active", var_key="0" * 64
    )
    db.add(version)
    db.commit()
    put = admin.client.put(
        f"/api/v1/models/{version.id}/embeddings",
        json={
            "clips": {left: [1, 0, 0], right: [0, 1, 0]},
            # s1 sits exactly between "left" and "right"; s0 and s2 are clearly one or the other.
            "snapshots": {s0: [1, 0, 0], s1: [0.7071, 0.7071, 0], s2: [0, 1, 0]},
        },
    )
    assert put.status_code == 200, put.text
    pair = member.client.get("/api/v1/labels/next").json()
    assert pair["strategy"] == "informative" and pair["snapshot"]["id"] == s1
    assert pair["informativeness"] == pytest.approx(1.0, abs=1e-3)


def test_triplets_count_is_with_is_not_pairs_and_silence(member, admin, scene) -> None:
    _, (s0, s1, s2), left, right = scene
    label(member, s0, left, "is")
    label(admin, s0, right, "is_not")  # s0: one triplet (left+, right-)
    label(member, s1, left, "is_not")
    label(member, s1, right, "is_not")  # s1: nothing I said → two silence triplets
    label(member, s2, left, "is")  # s2: no negative yet → nothing
    stats = member.client.get("/api/v1/triplets/stats").json()
    assert stats["triplets"] == 3 and stats["with_silence_positive"] == 2
    assert stats["snapshots_used"] == 2 and stats["labels"] == 5
    per_command = {c["name"]: c["triplets"] for c in stats["per_command"]}
    assert per_command == {"left": 1, "nothing I said (silence)": 2}
    per_member = {m["name"]: m["triplets"] for m in stats["per_member"]}
    assert per_member == {"Bob": 3}


def test_an_image_not_asked_about_every_command_is_not_silence_yet(member, scene) -> None:
    _, (s0, *_), left, _ = scene
    label(member, s0, left, "is_not")
    assert member.client.get("/api/v1/triplets/stats").json()["triplets"] == 0


def test_labels_of_another_household_are_404(member, stranger, scene) -> None:
    robot, (s0, *_), left, _ = scene
    label_id = label(member, s0, left, "is").json()["id"]
    assert stranger.client.get(f"/api/v1/labels/{label_id}").status_code == 404
    assert stranger.client.put(f"/api/v1/labels/{label_id}", json={"verdict": "is_not"}).status_code == 404
    assert stranger.client.delete(f"/api/v1/labels/{label_id}").status_code == 404
    assert label(stranger, s0, left, "is_not").status_code == 404
    assert stranger.client.get("/api/v1/labels").json() == []
    assert stranger.client.get(f"/api/v1/labels/next?robot_id={robot}").status_code == 404
    assert stranger.client.get(f"/api/v1/triplets/stats?robot_id={robot}").status_code == 404
    assert stranger.client.get("/api/v1/triplets/stats").json()["triplets"] == 0
