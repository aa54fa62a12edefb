"""Snapshots: capture requests to the robot worker, uploaded frames, listing, PNGs, delete."""

import io
import struct
import zlib

import pytest
from apitest_helpers import make_png, make_robot, queued_tasks, upload_clip, upload_snapshot
from PIL import Image


def test_capture_enqueues_the_robot_task_by_name(admin, redis_client) -> None:
    robot = make_robot(admin, "turtlebot-sim")
    response = admin.client.post(f"/api/v1/robots/{robot}/snapshots:capture", json={"count": 12})
    assert response.status_code == 202
    tasks = queued_tasks(redis_client, "robot")
    assert len(tasks) == 1
    headers = tasks[0]["headers"]
    assert headers["task"] == "varbot.capture_snapshots"
    assert headers["id"] == response.json()["task_id"]
    assert "'count': 12" in headers["kwargsrepr"] and f"'robot_id': {robot}" in headers["kwargsrepr"]


def test_capture_is_for_simulated_robots_and_bounded(admin, member) -> None:
    real = make_robot(admin, "kinova-real")
    assert admin.client.post(f"/api/v1/robots/{real}/snapshots:capture", json={"count": 3}).status_code == 409
    sim = make_robot(admin)
    assert member.client.post(f"/api/v1/robots/{sim}/snapshots:capture", json={"count": 0}).status_code == 422
    assert (
        member.client.post(f"/api/v1/robots/{sim}/snapshots:capture", json={"count": 10_000}).status_code
        == 422
    )


def test_capture_says_503_when_the_broker_is_down(admin, broker_down) -> None:
    robot = make_robot(admin)
    response = admin.client.post(f"/api/v1/robots/{robot}/snapshots:capture", json={"count": 3})
    assert response.status_code == 503 and "not reachable" in response.json()["detail"]


def test_uploaded_frames_are_listed_and_served_as_png(admin, member) -> None:
    robot = make_robot(admin, "kinova-real")
    created = upload_snapshot(member, robot, meta='{"camera": "wrist"}')
    assert created.status_code == 201, created.text
    snapshot = created.json()
    assert (snapshot["width"], snapshot["height"], snapshot["state"]) == (32, 24, [0.6, 0.1])
    assert snapshot["meta"] == {"camera": "wrist"} and snapshot["source"] == "upload"
    image = member.client.get(f"/api/v1/snapshots/{snapshot['id']}/image")
    assert image.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(image.content)).size == (32, 24)
    assert [s["id"] for s in member.client.get(f"/api/v1/snapshots?robot_id={robot}").json()] == [
        snapshot["id"]
    ]
    assert member.client.get(f"/api/v1/snapshots/{snapshot['id']}").json()["id"] == snapshot["id"]


def test_jpeg_frames_are_stored_as_png(admin) -> None:
    robot = make_robot(admin, "kinova-real")
    response = admin.client.post(
        f"/api/v1/robots/{robot}/snapshots", files={"image": ("f.jpg", make_png(fmt="JPEG"), "image/jpeg")}
    )
    assert response.status_code == 201
    png = admin.client.get(f"/api/v1/snapshots/{response.json()['id']}/image").content
    assert png.startswith(b"\x89PNG")


def test_bad_frames_are_refused(admin) -> None:
    robot = make_robot(admin, "kinova-real")
    url = f"/api/v1/robots/{robot}/snapshots"
    assert admin.client.post(url, files={"image": ("f.png", b"", "image/png")}).status_code == 422
    assert admin.client.post(url, files={"image": ("f.png", b"not an image", "image/png")}).status_code == 422
    bad_state = admin.client.post(
        url, files={"image": ("f.png", make_png(), "image/png")}, data={"state": "[1, "}
    )
    assert bad_state.status_code == 422 and "state must be JSON" in bad_state.json()["detail"]
    words = admin.client.post(
        url, files={"image": ("f.png", make_png(), "image/png")}, data={"state": '["a"]'}
    )
    assert words.status_code == 422
    source = admin.client.post(
        url, files={"image": ("f.png", make_png(), "image/png")}, data={"source": "mars"}
    )
    assert source.status_code == 422


def test_delete_is_hard_unless_labelled(admin, member, blob_store) -> None:
    robot = make_robot(admin)
    plain = upload_snapshot(member, robot, seed=1).json()["id"]
    labelled = upload_snapshot(member, robot, seed=2).json()["id"]
    clip = upload_clip(member).json()["id"]
    member.client.post("/api/v1/labels", json={"snapshot_id": labelled, "clip_id": clip, "verdict": "is_not"})
    assert member.client.delete(f"/api/v1/snapshots/{plain}").status_code == 204
    assert member.client.get(f"/api/v1/snapshots/{plain}").status_code == 404
    assert member.client.delete(f"/api/v1/snapshots/{labelled}").status_code == 204
    assert member.client.get(f"/api/v1/snapshots/{labelled}").json()["deleted_at"] is not None
    assert member.client.get("/api/v1/snapshots").json() == []
    # The labelled image and the clip (already 16 kHz mono 16-bit: original and normalised are one blob).
    assert len(list(blob_store.root.glob("??/??/*"))) == 2


def test_snapshots_of_another_household_are_404(admin, stranger) -> None:
    robot = make_robot(admin)
    snapshot = upload_snapshot(admin, robot).json()["id"]
    assert stranger.client.get(f"/api/v1/snapshots/{snapshot}").status_code == 404
    assert stranger.client.get(f"/api/v1/snapshots/{snapshot}/image").status_code == 404
    assert stranger.client.delete(f"/api/v1/snapshots/{snapshot}").status_code == 404
    assert upload_snapshot(stranger, robot).status_code == 404
    assert (
        stranger.client.post(f"/api/v1/robots/{robot}/snapshots:capture", json={"count": 1}).status_code
        == 404
    )
    assert stranger.client.get(f"/api/v1/snapshots?robot_id={robot}").json() == []


def png_header_only(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares width×height RGB pixels (a decompression bomb when large)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b""))
        + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize(("width", "height"), [(20_000, 20_000), (5000, 10), (1, 70_000)])
def test_an_image_too_large_by_its_header_is_refused_before_decoding(
    admin, blob_store, width, height
) -> None:
    robot = make_robot(admin, "kinova-real")
    bomb = png_header_only(width, height)
    assert len(bomb) < 100
    response = admin.client.post(
        f"/api/v1/robots/{robot}/snapshots", files={"image": ("f.png", bomb, "image/png")}
    )
    assert response.status_code == 422, response.text
    assert "each side must be 1..4096 pixels" in response.json()["detail"]
    assert admin.client.get("/api/v1/snapshots").json() == []
    assert list(blob_store.root.glob("??/??/*")) == []
