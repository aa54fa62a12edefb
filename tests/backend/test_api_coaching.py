"""Coaching by voice through the API: starting a session sends the robot task; a clip said while the robot
worked becomes a recording of the command, a snapshot of the frame it was said over and an *is* label, and is
handed to the worker; what cannot be placed says why. The frames are written as the worker writes them
(`worker.coaching.FrameKeeper` → `backend.services.coaching.add_frame`)."""

import time

import pytest
from apitest_helpers import make_png, make_robot, make_wav, queued_tasks, upload_clip

from backend.errors import Invalid
from backend.services import coaching


def _start(person, robot: int, command: str = "zero") -> dict:  # type: ignore[no-untyped-def]
    body = {"command": command, "seconds": 30}
    response = person.client.post(f"/api/v1/robots/{robot}/coaching", json=body)
    assert response.status_code == 202, response.text
    return response.json()


def _worker_runs(session_id: str, robot: int, household: int, frames_from: float) -> None:
    """What the worker does once it has the session: running, and five frames of 0.2 s each."""
    status = coaching.read_status(session_id)
    coaching.write_status(session_id, {**status, "state": "running", "message": "working"})
    for step in range(5):
        shown = frames_from + 0.2 * step
        frame = coaching.Frame(step + 1, shown, shown + 0.2, make_png(seed=step), [0.5, 0.1 * step], 2)
        coaching.add_frame(session_id, frame)


def _send(person, robot: int, session_id: str, said_from: float, said_to: float):  # type: ignore[no-untyped-def]
    """A clip as the browser sends it: its own clock runs 1000 s ahead of the API's."""
    skew_ms = 1_000_000
    return person.client.post(
        f"/api/v1/robots/{robot}/coaching/{session_id}/clips",
        files={"file": ("coaching.wav", make_wav(0.6), "audio/wav")},
        data={
            "said_from_ms": str(said_from * 1000 + skew_ms),
            "said_to_ms": str(said_to * 1000 + skew_ms),
            "sent_at_ms": str(time.time() * 1000 + skew_ms),
        },
    )


def test_a_clip_said_over_a_frame_becomes_a_recording_a_snapshot_and_an_is_label(admin, redis_client) -> None:  # type: ignore[no-untyped-def]
    assert upload_clip(admin, name="Zero").status_code == 201
    robot = make_robot(admin)
    started = _start(admin, robot)
    assert (started["state"], started["command_name"], started["steps"]) == ("queued", "Zero", 150)
    (task,) = queued_tasks(redis_client, "robot")
    assert task["headers"]["task"] == "varbot.coach" and task["headers"]["id"] == started["session_id"]
    session_id = started["session_id"]
    early = _send(admin, robot, session_id, time.time() - 0.6, time.time())
    assert early.status_code == 409 and "has not started yet" in early.json()["detail"]

    now = time.time()
    _worker_runs(session_id, robot, admin.household_id, frames_from=now - 1.0)
    sent = _send(admin, robot, session_id, now - 0.62, now - 0.5)  # middle: frame 3 (now-0.6 .. now-0.4)
    assert sent.status_code == 201, sent.text
    answer = sent.json()
    assert answer["step"] == 3 and answer["clip"]["name"] == "Zero"
    assert "saved as “Zero”" in answer["message"]
    snapshot = admin.client.get(f"/api/v1/snapshots/{answer['snapshot_id']}").json()
    assert snapshot["source"] == "coaching" and snapshot["state"] == [0.5, pytest.approx(0.2)]
    label = admin.client.get(f"/api/v1/labels/{answer['label']}").json()
    assert (label["snapshot_id"], label["clip_id"], label["verdict"]) == (
        answer["snapshot_id"], answer["clip"]["id"], "is",
    )  # fmt: skip
    (heard,) = coaching.clips_since(session_id, 0)
    assert heard["clip_id"] == answer["clip"]["id"] and heard["said_to"] == pytest.approx(now - 0.5, abs=0.5)
    status = admin.client.get(f"/api/v1/robots/{robot}/coaching/{session_id}").json()
    assert (status["state"], status["labels"]) == ("running", 1)

    long_ago = _send(admin, robot, session_id, now - 30.6, now - 30.0)
    assert long_ago.status_code == 409 and "not moving while you spoke" in long_ago.json()["detail"]
    cancelled = admin.client.post(f"/api/v1/robots/{robot}/coaching/{session_id}/cancel").json()
    assert cancelled["state"] == "cancelling" and coaching.stop_asked(session_id)


def test_what_cannot_be_coached_says_why(admin, stranger) -> None:  # type: ignore[no-untyped-def]
    robot = make_robot(admin)
    response = admin.client.post(f"/api/v1/robots/{robot}/coaching", json={"command": "zero"})
    assert response.status_code == 409 and "record one on the Record page" in response.json()["detail"]
    assert upload_clip(admin, name="one").status_code == 201
    response = admin.client.post(f"/api/v1/robots/{robot}/coaching", json={"command": "zero"})
    assert response.status_code == 422 and "coach one of these: “one”" in response.json()["detail"]
    session_id = _start(admin, robot, "one")["session_id"]
    assert stranger.client.get(f"/api/v1/robots/{robot}/coaching/{session_id}").status_code == 404


def test_the_browsers_times_must_fit_together() -> None:
    with pytest.raises(Invalid, match="said_from_ms < said_to_ms"):
        coaching.spoken_times(2000, 1000, 3000, 100.0)
    with pytest.raises(Invalid, match="at most 15 s"):
        coaching.spoken_times(0, 20_000, 20_000, 100.0)
    said = coaching.spoken_times(9000, 10_000, 10_500, 100.0)
    assert (said.said_from, said.said_to) == pytest.approx((98.5, 99.5))
