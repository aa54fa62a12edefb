"""Training runs end to end through a real API, a real Redis and real Celery worker processes."""

import os
import signal
import threading

import pytest
from conftest import TINY, Household, Stack, sse_runs, stop_process_group, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.speech]


def test_a_finetune_run_goes_from_queued_to_succeeded_with_live_progress_and_a_new_model_version(
    stack: Stack, household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    robot = household.new_robot("progress-arm")
    seen: list[dict] = []
    stream_client = household.client.__class__(
        base_url=stack.api_url, headers=dict(household.client.headers), timeout=30
    )
    run = household.start_run(robot, **TINY)
    reader = threading.Thread(target=sse_runs, args=(stack, stream_client, run["id"], seen, 240), daemon=True)
    reader.start()
    reader.join(260)
    ours = [event for event in seen if event["id"] == run["id"]]
    statuses = [event["status"] for event in ours]
    assert statuses[-1] == "succeeded", (ours[-1], stack.log("worker-robot")[-2000:])
    assert "running" in statuses
    progress = [event["progress"] for event in ours if event["status"] == "running"]
    assert len(set(progress)) >= 3 and progress == sorted(progress) and 0 < progress[-1] <= 1, progress
    # The VAR stage fills the first 30 % of a finetune's bar; the bar starts near 0, not full.
    var_stage = [event["progress"] for event in ours if event["stage"] in ("starting", "var_finetune")]
    assert var_stage and max(var_stage) <= 0.3 and min(progress) < 0.3, ours
    assert {"var_finetune", "policy_improve", "evaluate"} <= {event["stage"] for event in ours}
    final = household.run(run["id"])
    assert final["progress"] == 1.0 and final["error"] is None
    assert set(final["timings"]["stages_s"]) >= {"var_finetune", "policy_improve", "evaluate"}
    assert final["metrics"]["curves"]["var_finetune"] and final["metrics"]["curves"]["policy_improve"]
    assert final["metrics"]["triplets"]["train"] > 0 and final["metrics"]["labels_used"] > 0
    assert final["checkpoints"], "checkpoints and curves are kept with the run"
    versions = household.versions(robot)
    made = [v for v in versions if v["run_id"] == run["id"]]
    assert len(made) == 1 and made[0]["has_var"] and made[0]["has_policy"]
    base = [v for v in versions if v["run_id"] is None]
    assert len(base) == 1, "the shipped base model became the robot's first version"
    assert made[0]["parent_id"] == base[0]["id"]
    gate = final["metrics"]["gate"]
    assert gate["reasons"] and (made[0]["status"] == "active") == gate["promoted"]


def test_cancelling_a_running_run_ends_it_cancelled_and_leaves_the_active_model_alone(
    household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    robot = household.new_robot("cancel-arm")
    run = household.start_run(robot, **{**TINY, "policy_steps": 24 * 400})
    wait_until(lambda: household.run(run["id"])["stage"] == "policy_improve", 180, "the policy stage")
    active_before = [v["id"] for v in household.versions(robot) if v["status"] == "active"]
    response = household.client.post(f"/api/v1/runs/{run['id']}:cancel")
    assert response.status_code == 200, response.text
    final = household.wait_run(run["id"], timeout=90)
    assert final["status"] == "cancelled"
    assert final["stage"] == "policy_improve"
    assert final["checkpoints"], "the last checkpoint is kept"
    versions = household.versions(robot)
    assert [v["id"] for v in versions if v["status"] == "active"] == active_before
    assert not [v for v in versions if v["run_id"] == run["id"]]


def test_a_worker_killed_mid_run_is_replaced_and_the_run_completes_exactly_once(
    stack: Stack, household: Household
) -> None:
    robot = household.new_robot("crash-arm")
    first = stack.start_worker("training", "worker-training-killed")
    try:
        run = household.start_run(robot, **{**TINY, "policy_steps": 24 * 6})
        wait_until(
            lambda: (
                household.run(run["id"])["stage"] == "policy_improve"
                and (stack.root / "data" / "runs" / str(run["id"]) / "policy" / "checkpoint.pt").is_file()
            ),
            180,
            "a policy checkpoint",
        )
        os.killpg(first.pid, signal.SIGKILL)  # the worker, its pool child and the env workers, at once
        first.wait()
    finally:
        stop_process_group(first)
    assert household.run(run["id"])["status"] == "running"
    second = stack.start_worker("training", "worker-training-replacement")
    try:
        final = household.wait_run(run["id"], timeout=240)
    finally:
        stop_process_group(second)
    assert final["status"] == "succeeded", final["error"]
    assert "resumed_at" in final["metrics"]["latest"]
    assert len([v for v in household.versions(robot) if v["run_id"] == run["id"]]) == 1
    runs = household.client.get("/api/v1/runs", params={"robot_id": robot}).json()
    assert [r["status"] for r in runs] == ["succeeded"]


def test_a_worse_candidate_is_not_promoted_and_the_reasons_are_recorded(
    stack: Stack, household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    """A version and its mirror image (image embeddings negated) score a and 1 − a on the same held-out
    triplets: whichever is worse is made the candidate against the better one, which is active."""
    robot = household.new_robot("gate-arm")
    first = household.wait_run(household.start_run(robot, "evaluate", **TINY)["id"])
    assert first["status"] == "succeeded", first["error"]
    base = next(v for v in household.versions(robot) if v["status"] == "active")
    accuracy = first["metrics"]["evaluation"]["active"]["triplet_accuracy"]
    mirror = _add_mirrored_candidate(robot, base["id"])
    if accuracy < 0.5:  # the mirror is the better one: make it active, the base becomes the worse candidate
        assert household.client.post(f"/api/v1/models/{mirror}:activate").status_code == 200
        worse, better = _add_copy_candidate(robot, base["id"]), mirror
    else:
        worse, better = mirror, base["id"]
    run = household.wait_run(household.start_run(robot, "evaluate", **TINY)["id"])
    assert run["status"] == "succeeded", run["error"]
    gate = run["metrics"]["gate"]
    assert gate["promoted"] is False, gate
    assert gate["verdict"] in ("worse", "no_change"), "a lower score is never called better"
    assert any("triplet accuracy" in reason for reason in gate["reasons"])
    assert "kept the old version" in gate["summary"]
    versions = {v["id"]: v for v in household.versions(robot)}
    assert versions[worse]["status"] == "candidate" and "kept as candidate" in versions[worse]["notes"]
    assert versions[better]["status"] == "active"


def _add_version(robot_id: int, parent_id: int, mirror: bool) -> int:
    import io

    import torch

    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services import model_versions

    blobs = get_blob_store()
    with get_session_factory()() as session:
        parent = session.get_one(models.ModelVersion, parent_id)
        payload = torch.load(io.BytesIO(blobs.get(parent.var_key)), weights_only=True)
        if mirror:  # negating the last layer negates every image embedding
            for name in ("image_encoder.head.3.weight", "image_encoder.head.3.bias"):
                payload["state_dict"][name].neg_()
        buffer = io.BytesIO()
        torch.save({**payload, "note": "mirrored" if mirror else "copy"}, buffer)
        version = model_versions.create_version(
            session, session.get_one(models.Robot, robot_id), var_key=blobs.put(buffer.getvalue()),
            policy_key=parent.policy_key, parent_id=parent.id,
        )  # fmt: skip
        session.commit()
        return version.id


def _add_mirrored_candidate(robot_id: int, parent_id: int) -> int:
    return _add_version(robot_id, parent_id, mirror=True)


def _add_copy_candidate(robot_id: int, parent_id: int) -> int:
    return _add_version(robot_id, parent_id, mirror=False)


def test_a_run_whose_labels_vanished_before_it_started_is_refused_with_how_many_more_are_needed(
    stack: Stack, household: Household
) -> None:
    robot = household.new_robot("refused-arm", views=12)
    run = household.start_run(robot, **TINY)  # no training worker yet: the run waits in the queue
    labels = household.client.get("/api/v1/labels", params={"limit": 500}).json()
    snapshot_ids = {s["id"] for s in household.snapshots(robot)}
    for label in labels:
        if label["snapshot_id"] in snapshot_ids:
            assert household.client.delete(f"/api/v1/labels/{label['id']}").status_code == 204
    worker = stack.start_worker("training", "worker-training-refusal")
    try:
        final = household.wait_run(run["id"], timeout=120)
    finally:
        stop_process_group(worker)
    assert final["status"] == "failed"
    assert final["error"].startswith("refused:") and "20 more are needed" in final["error"]
    assert not [v for v in household.versions(robot) if v["run_id"] == run["id"]]
