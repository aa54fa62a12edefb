"""A robot's model adapted to its room through the API, Redis and the robot worker: its newest camera views,
with no labels, move the batch-norm statistics of its VAR (and of a policy's VAR view); the result is the
active version and a rollback undoes it. A fine-tune starts from the version the adaptation came from and is
measured against the adapted one; told `finetune_from_unadapted: false`, it fine-tunes the adapted version
and keeps the room's statistics. A simulated robot's views come from seeded random moves: one seed, one
adaptation. A robot with too few views is told how many more to capture."""

import io

import numpy as np
import torch
from conftest import TINY, Household, Stack
from PIL import Image

from core.rooms import MIN_ROOM_VIEWS


def _adapt(household: Household, robot_id: int, **body: object) -> dict:
    return household.robot_task(robot_id, "models:adapt-to-room", "adaptations", body, "the adaptation")


def _var_payload(version: dict) -> dict:
    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store

    with get_session_factory()() as session:
        key = session.get_one(models.ModelVersion, version["id"]).var_key
    return torch.load(io.BytesIO(get_blob_store().get(key)), weights_only=True)


def _var_state(version: dict) -> dict[str, torch.Tensor]:
    return _var_payload(version)["state_dict"]


def _split(state: dict[str, torch.Tensor]) -> tuple[dict, dict]:
    """(the image encoder's batch-norm statistics, every weight)"""
    statistics = {k: v for k, v in state.items() if k.startswith("image_encoder.") and "running_" in k}
    weights = {k: v for k, v in state.items() if "running_" not in k and "num_batches" not in k}
    return statistics, weights


def test_a_robot_adapts_to_its_room_from_its_views_and_fine_tunes_from_the_version_before(
    stack: Stack, household: Household, base_model, training_worker
) -> None:  # type: ignore[no-untyped-def]
    robot = household.new_robot("room-adapting-arm", views=20)
    household.client.patch(f"/api/v1/robots/{robot}", json={"settings": {"domain": "unseen_room"}})
    adapted = _adapt(household, robot, views=MIN_ROOM_VIEWS, share=0.5)

    assert adapted["views"] == MIN_ROOM_VIEWS
    assert adapted["status"]["state"] == "done", adapted["status"]
    assert len(household.snapshots(robot)) == 20, "the views it rendered were not stored for labelling"
    assert not any((stack.root / "data" / "room_adaptation").iterdir()), "no working files left behind"
    versions = {v["id"]: v for v in household.versions(robot)}
    active = versions[adapted["status"]["version_id"]]
    base = versions[active["parent_id"]]
    assert active["status"] == "active" and base["status"] == "retired"
    assert f"adapted to {MIN_ROOM_VIEWS} camera views of this room" in active["notes"]
    assert active["metrics"]["room_adaptation"]["views_from"]["rendered"] == MIN_ROOM_VIEWS
    record = active["metrics"]["room_adaptation"]
    assert (record["views"], record["share"], record["from_version"]) == (MIN_ROOM_VIEWS, 0.5, base["id"])
    assert active["metrics"]["base_model"] == base["metrics"]["base_model"], "its base's record is kept"
    base_statistics, base_weights = _split(_var_state(base))
    statistics, weights = _split(_var_state(active))
    assert all(torch.equal(base_weights[k], weights[k]) for k in base_weights), "no weight changed"
    assert all(not torch.equal(base_statistics[k], statistics[k]) for k in base_statistics)

    run = household.start_run(robot, **TINY, finetune_from_unadapted=False)
    run = household.wait_run(run["id"], 300)
    assert run["status"] == "succeeded", run["error"]
    candidate = next(v for v in household.versions(robot) if v["run_id"] == run["id"])
    tuned_statistics, tuned_weights = _split(_var_state(candidate))
    assert all(torch.equal(statistics[k], tuned_statistics[k]) for k in statistics), "the room's, kept"
    assert any(not torch.equal(weights[k], tuned_weights[k]) for k in weights), "while the weights learnt"
    assert "room_adaptation" in _var_payload(candidate)
    if candidate["status"] == "active":
        household.client.post(f"/api/v1/robots/{robot}/models:rollback").raise_for_status()

    run = household.start_run(robot, **TINY, finetune_from_unadapted=True)
    run = household.wait_run(run["id"], 300)
    assert run["status"] == "succeeded", run["error"]
    from_base = next(v for v in household.versions(robot) if v["run_id"] == run["id"])
    assert from_base["parent_id"] == active["id"], "measured against the adapted version"
    assert "room_adaptation" not in _var_payload(from_base), "trained from the version before adapting"
    learnt_statistics, _ = _split(_var_state(from_base))
    assert all(not torch.equal(statistics[k], learnt_statistics[k]) for k in statistics)
    if from_base["status"] == "active":
        household.client.post(f"/api/v1/robots/{robot}/models:rollback").raise_for_status()

    back = _adapt(household, robot, share=0.0)
    assert back["views"] == 0 and back["status"]["state"] == "done", back["status"]
    restored = next(v for v in household.versions(robot) if v["id"] == back["status"]["version_id"])
    assert "base model's batch-norm statistics back" in restored["notes"]
    restored_statistics, _ = _split(_var_state(restored))
    assert all(torch.equal(base_statistics[k], restored_statistics[k]) for k in base_statistics)
    household.client.post(f"/api/v1/robots/{robot}/models:rollback").raise_for_status()

    rolled = household.client.post(f"/api/v1/robots/{robot}/models:rollback")
    assert rolled.status_code == 200 and rolled.json()["id"] == base["id"], "a rollback undoes it"


def test_a_simulated_robot_adapted_twice_with_one_seed_sees_the_same_views_and_another_seed_other_views(
    stack: Stack, household: Household, base_model
) -> None:  # type: ignore[no-untyped-def]
    body = {"name": "seeded-adapting-arm", "kind": "kuka-sim", "settings": {"domain": "unseen_room"}}
    robot = household.client.post("/api/v1/robots", json=body).json()["id"]

    def adapted_statistics(seed: int) -> dict[str, torch.Tensor]:
        adapted = _adapt(household, robot, views=MIN_ROOM_VIEWS, share=0.5, seed=seed)
        assert adapted["status"]["state"] == "done", adapted["status"]
        version = next(v for v in household.versions(robot) if v["id"] == adapted["status"]["version_id"])
        assert version["metrics"]["room_adaptation"]["views_from"]["seed"] == seed
        return _split(_var_state(version))[0]

    first, again, other = adapted_statistics(11), adapted_statistics(11), adapted_statistics(12)
    assert all(torch.equal(first[k], again[k]) for k in first), "one seed, one adaptation"
    assert any(not torch.equal(first[k], other[k]) for k in first), "another seed, other views"
    refused = household.client.post(f"/api/v1/robots/{robot}/models:adapt-to-room", json={"seed": -1})
    assert refused.status_code == 422 and "seed" in refused.text


def test_a_real_robot_with_too_few_frames_is_told_how_many_more_to_send(
    stack: Stack, household: Household, base_model
) -> None:  # type: ignore[no-untyped-def]
    body = {"name": "frames-only arm", "kind": "kinova-real"}
    robot = household.client.post("/api/v1/robots", json=body).json()["id"]
    for shade in range(10):
        frame = io.BytesIO()
        Image.new("RGB", (16, 16), (shade * 20, 90, 120)).save(frame, format="PNG")
        sent = household.client.post(
            f"/api/v1/robots/{robot}/snapshots", files={"image": ("frame.png", frame.getvalue(), "image/png")}
        )
        assert sent.status_code == 201, sent.text
    refused = household.client.post(f"/api/v1/robots/{robot}/models:adapt-to-room", json={})
    assert refused.status_code == 409
    said = f"needs at least {MIN_ROOM_VIEWS}: send {MIN_ROOM_VIEWS - 10} more of its camera frames"
    assert said in refused.text
    too_few = household.client.post(f"/api/v1/robots/{robot}/models:adapt-to-room", json={"views": 5})
    assert too_few.status_code == 422 and "views" in too_few.text
    assert not household.versions(robot), "no model was made"


def test_an_adapted_var_keeps_where_it_came_from_but_not_a_fine_tunes_optimiser_state(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from learning.var.checkpoint import read_checkpoint, save_var
    from learning.var.model import VAR, VARConfig
    from worker.room_adaptation import adapted_files

    parent = save_var(
        VAR(VARConfig(image_size=16)), tmp_path / "parent.pt", sound_set="wordset",
        training={"optimizer": {"state": {}}, "epoch": 3},
    )  # fmt: skip
    no_views = np.zeros((0, 16, 16, 3), np.uint8)
    var_out, policy_out, record = adapted_files(parent, None, no_views, 0.0, tmp_path)
    payload = read_checkpoint(var_out)
    assert payload["sound_set"] == "wordset" and "training" not in payload
    assert policy_out is None and record["share"] == 0.0 and "statistics_before" in payload["room_adaptation"]
