"""A coaching session for real, through the API, Redis and the stack's robot worker on the tiny Kuka base:
the session runs to its end at its pace, a clip said while it ran is heard over the frames it overlaps and
becomes an *is* label, and the coached policy is stored as a candidate version (not made active)."""

import time

from conftest import Household, Stack, wait_until


def _status(household: Household, robot: int, session_id: str) -> dict:
    response = household.client.get(f"/api/v1/robots/{robot}/coaching/{session_id}")
    assert response.status_code == 200, response.text
    return response.json()


def test_a_session_runs_to_its_end_hears_a_clip_and_stores_a_candidate(
    stack: Stack, household: Household, base_model
) -> None:  # type: ignore[no-untyped-def]
    robot = household.client.post("/api/v1/robots", json={"name": "coach-arm", "kind": "kuka-sim"}).json()[
        "id"
    ]
    body = {"command": "two", "seconds": 20, "steps_per_s": 10}
    started = household.client.post(f"/api/v1/robots/{robot}/coaching", json=body)
    assert started.status_code == 202, started.text
    session_id = started.json()["session_id"]
    wait_until(
        lambda: _status(household, robot, session_id)["step"] >= 30, 120, "the robot to take 30 steps", 0.2
    )
    said_to = time.time()
    clip = household.client.post(
        f"/api/v1/robots/{robot}/coaching/{session_id}/clips",
        files={"file": ("two.wav", household_wav(household), "audio/wav")},
        data={"said_from_ms": str(said_to * 1000 - 700), "said_to_ms": str(said_to * 1000),
              "sent_at_ms": str(time.time() * 1000)},
    )  # fmt: skip
    assert clip.status_code == 201, clip.text

    def ended() -> dict | None:
        status = _status(household, robot, session_id)
        return status if status["state"] in ("done", "failed", "refused", "cancelled") else None

    final = wait_until(ended, 120, "the coaching session to end", 0.5)
    assert final["state"] == "done", (final, stack.log("worker-robot")[-3000:])
    assert final["step"] == 200 and final["labels"] == 1
    assert final["voiced_steps"] >= 5, "0.7 s of voice at 10 steps a second"
    (coached,) = [v for v in household.versions(robot) if "coached by voice" in (v["notes"] or "")]
    assert coached["status"] == "candidate" and coached["metrics"]["coaching"]["voiced_steps"] >= 5
    label = household.client.get(f"/api/v1/labels/{clip.json()['label']}").json()
    assert label["verdict"] == "is" and label["clip_id"] == clip.json()["clip"]["id"]


def household_wav(household: Household) -> bytes:
    clip_id = household.clip_ids[("two", "en")]
    return household.client.get(f"/api/v1/clips/{clip_id}/audio").content
