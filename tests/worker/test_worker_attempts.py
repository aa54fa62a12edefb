"""The household loop for real, through the API, Redis and Celery workers on a tiny Kuka world: the robot
tries the household's commands and its attempts become snapshots; "did it do what I said?" answers become
labels; a fine-tune with replay of the simulated training room runs; the gate says better, no measurable
change or worse. And what cannot work says why."""

import io
from pathlib import Path

import pytest
from conftest import TINY, Household, Stack
from PIL import Image

from varbot.simulated_household import WORDS

VERDICTS = {"better", "no_change", "worse"}


def _attempts(household: Household, robot_id: int, **body: object) -> dict:
    return household.robot_task(robot_id, "attempts", "attempts", body, "the attempts task to end")


def _judge_every_attempt(household: Household, robot_id: int) -> list[str]:
    """A person at the Label page: the simulator's account of the final view plays what they see."""
    answers = []
    while True:
        offered = household.client.get("/api/v1/attempts/next", params={"robot_id": robot_id}).json()
        if offered["snapshot"] is None:
            return answers
        heard = offered["snapshot"]["meta"]["sim_heard"]
        others = {c["name"]: c["key"] for c in offered["others"]}
        if heard is None:
            body = {"answer": "no", "instead": "nothing"}
        elif WORDS[heard] == offered["asked"]["name"]:
            body = {"answer": "yes"}
        else:
            body = {"answer": "no", "instead": others[WORDS[heard]]}
        stored = household.client.post(f"/api/v1/attempts/{offered['snapshot']['id']}/answer", json=body)
        assert stored.status_code == 201, stored.text
        answers.append(stored.json()["shows"])


def _active_version(robot_id: int, var: bytes, policy: bytes | None, notes: str) -> int:
    """A version of the robot stored and made active the way a worker does it."""
    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services import model_versions

    blobs = get_blob_store()
    with get_session_factory()() as session:
        version = model_versions.create_version(
            session, session.get_one(models.Robot, robot_id), var_key=blobs.put(var),
            policy_key=None if policy is None else blobs.put(policy), notes=notes,
        )  # fmt: skip
        model_versions.activate(session, version)
        return version.id


def _version_with_corpus(robot_id: int, base_var: bytes, sound_set: str) -> int:
    """The tiny base model as the robot's active version, its VAR naming `sound_set` as its corpus."""
    import torch

    from worker.base_models import find_base

    payload = torch.load(io.BytesIO(base_var), weights_only=True)
    buffer = io.BytesIO()
    torch.save({**payload, "sound_set": sound_set}, buffer)
    policy = find_base("kuka").policy_path.read_bytes()
    return _active_version(robot_id, buffer.getvalue(), policy, f"replays {sound_set}")


def test_attempts_become_snapshots_answers_become_labels_and_a_fine_tune_with_replay_gives_a_verdict(
    stack: Stack, household: Household, base_model, training_worker
) -> None:  # type: ignore[no-untyped-def]
    from learning.sounds.build import build_corpora

    robot = household.client.post("/api/v1/robots", json={"name": "attempts-arm", "kind": "kuka-sim"}).json()
    done = _attempts(household, robot["id"], count=8, random_share=0.2)
    assert done["status"]["state"] == "done", done["status"]
    assert (done["random_views"], done["status"]["created"]) == (2, 8)

    snapshots = household.snapshots(robot["id"])
    attempts = [s for s in snapshots if s["source"] == "attempt"]
    assert len(attempts) == 8 and len([s for s in snapshots if s["source"] == "sim-capture"]) == 2
    asked = sorted(s["meta"]["attempt"]["command"] for s in attempts)
    assert asked == sorted(f"name:{word}" for word in WORDS for _ in range(2)), "commands in turn"
    first = attempts[0]
    assert 1 <= len(first["meta"]["attempt"]["frames"]) <= 6
    frame = household.client.get(f"/api/v1/attempts/{first['id']}/frames/0")
    assert Image.open(io.BytesIO(frame.content)).size == (16, 16)

    answers = _judge_every_attempt(household, robot["id"])
    assert len(answers) == 8 and set(answers) <= {*WORDS, "nothing"}
    clips = len(household.clip_ids)
    stats = household.client.get("/api/v1/triplets/stats", params={"robot_id": robot["id"]}).json()
    assert stats["labels"] == 8 * clips, "every answer labels the final view for every recording"
    spoken = sum(answer != "nothing" for answer in answers)
    assert stats["triplets"] == spoken * 2 * (clips - 2) + (8 - spoken) * clips

    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    _version_with_corpus(robot["id"], (base_model / "var.pt").read_bytes(), "wordset")
    params = {**TINY, "replay_fraction": 0.25, "var_keep_view": 1.0, "replay_block_ends_share": 0.5}
    run = household.wait_run(household.start_run(robot["id"], **params)["id"], 300)
    assert run["status"] == "succeeded", run["error"]
    var_stage = run["metrics"]["stages"]["var_finetune"]
    assert var_stage["replay_triplets"] == round(var_stage["train_triplets"] * 0.25 / 0.75) > 0
    drifts = [point["view_drift"] for point in run["metrics"]["curves"]["var_finetune"]]
    assert drifts and all(d is not None and d >= 0 for d in drifts), "the anchor measured the views' drift"
    gate = run["metrics"]["gate"]
    assert gate["verdict"] in VERDICTS and gate["summary"] and gate["min_items_for_a_claim"] == 50
    version = next(v for v in household.versions(robot["id"]) if v["run_id"] == run["id"])
    assert version["notes"].startswith(gate["verdict"])


def test_attempts_asked_with_the_same_seed_come_back_the_same_and_without_one_they_are_new(
    stack: Stack, household: Household, base_model
) -> None:  # type: ignore[no-untyped-def]
    robot = household.client.post("/api/v1/robots", json={"name": "seeded-arm", "kind": "kuka-sim"}).json()

    def views(**body: object) -> list[tuple]:
        before = {s["id"] for s in household.snapshots(robot["id"])}
        asked = _attempts(household, robot["id"], count=4, random_share=0.5, **body)
        assert asked["status"]["state"] == "done", asked["status"]
        made = [s for s in household.snapshots(robot["id"]) if s["id"] not in before]
        return [(s["source"], s["state"], s["meta"].get("attempt", {}).get("clip_id")) for s in made]

    first = views(seed=7)
    assert [source for source, *_ in first].count("attempt") == 4 and len(first) > 4, "and random views"
    assert views(seed=7) == first
    assert views() != first


def test_what_cannot_be_attempted_or_replayed_says_why_and_what_to_do(
    stack: Stack, household: Household, base_model, training_worker
) -> None:  # type: ignore[no-untyped-def]
    body = {"name": "var-only", "kind": "kuka-sim"}
    no_policy = household.client.post("/api/v1/robots", json=body).json()["id"]
    _active_version(no_policy, (base_model / "var.pt").read_bytes(), None, "VAR only")
    refused = _attempts(household, no_policy, count=2)["status"]
    assert refused["state"] == "refused" and "has no policy to act with" in refused["message"]
    assert "activate a version that has one" in refused["message"], "says what to do"
    assert not household.snapshots(no_policy), "nothing was stored"

    robot = household.new_robot("replay-missing-arm", views=40)
    _version_with_corpus(robot, (base_model / "var.pt").read_bytes(), "retired-set")
    run = household.wait_run(household.start_run(robot, **{**TINY, "replay_fraction": 0.25})["id"], 300)
    assert run["status"] == "failed" and "var_finetune" in run["error"]
    assert "replay corpus 'retired-set'" in run["error"] and "could not be built here" in run["error"]
    assert "replay_fraction 0" in run["error"], "says what to do instead"


def test_a_robot_whose_world_has_no_base_model_anywhere_is_refused_with_what_to_do(
    household: Household, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Every simulated world ships a base model, so this is a deployment without the shipped folder."""
    import worker.base_models
    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from worker.attempts import AttemptRefused, robot_model

    monkeypatch.setattr(worker.base_models, "SHIPPED_DIR", tmp_path / "not-shipped")
    robot = household.client.post("/api/v1/robots", json={"name": "bare", "kind": "kinova-sim"}).json()
    with get_session_factory()() as session, pytest.raises(AttemptRefused) as refused:
        robot_model(session, get_blob_store(), session.get_one(models.Robot, robot["id"]), "kinova")
    assert "has no model to act with: train or pick a base model first" in str(refused.value)
    assert "varbot models build-base --world kinova" in str(refused.value)


def test_a_command_with_no_recording_is_refused_before_the_robot_moves(household: Household) -> None:
    robot = household.client.post("/api/v1/robots", json={"name": "ask-arm", "kind": "kuka-sim"}).json()
    response = household.client.post(
        f"/api/v1/robots/{robot['id']}/attempts", json={"count": 1, "commands": ["four"]}
    )
    assert response.status_code == 422 and "no recording of 'four'" in response.json()["detail"]
