"""A robot's model adapted to the room its camera sees (the robot queue's `adapt_to_room`): views of the
room, unlabelled (a simulated robot's rendered as it moves at random and never stored, a real one's newest
frames), move the batch-norm statistics of its VAR's image encoder and of its policy's frozen VAR view
(`learning.var.room_adaptation`). The result is a new model version, made active at once
(it changes no weight, and the Admin page's rollback undoes it); runs, attempts and the scene use it as any
other version."""

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select

from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services import model_versions
from core.paths import data_subdir
from core.robots import world_of_kind
from core.rooms import MIN_ROOM_VIEWS, room_of
from learning.var.room_adaptation import CHECKPOINT_KEY
from worker.household import decoded_image
from worker.run_context import active_or_base, materialise

ADAPTATION = CHECKPOINT_KEY  # the adaptation's record: in the VAR checkpoint, and in the version's metrics

# what the VAR checkpoint says of where it came from (its optimiser state is left behind)
KEPT_CHECKPOINT_KEYS = ("manifest_hash", "sound_set", "world", "refit", "room_invariance", "finetuned_on")


class AdaptationRefused(ValueError):
    """What cannot be adapted, with what to do."""


def adapt_robot_to_room(
    robot_id: int, household_id: int, views: int, share: float, seed: int | None = None
) -> dict[str, Any]:
    """Adapt the robot's active model (or its base model) to `views` views of its room: a simulated robot
    moves at random (from `seed`, a fresh one when None) and its camera's views are used as they come, never
    stored (they would crowd the Label page); a real one's are its newest stored snapshots. The new active
    version's id and what changed."""
    blobs = get_blob_store()
    with get_session_factory()() as session:
        robot = session.get(models.Robot, robot_id)
        if robot is None or robot.household_id != household_id:
            raise AdaptationRefused(f"robot {robot_id} of household {household_id} does not exist")
        parent = active_or_base(session, blobs, robot, world_of_kind(robot.kind))
        if parent.var_key is None:
            raise AdaptationRefused(
                f"the active version {parent.id} has no VAR to adapt: activate one that has"
            )
        with tempfile.TemporaryDirectory(dir=data_subdir("room_adaptation")) as work:
            version = _adapted_version(session, blobs, robot, parent, views, share, seed, Path(work))
        model_versions.activate(session, version)  # commits
        return {
            "robot_id": robot.id,
            "version_id": version.id,
            "notes": version.notes,
            **version.metrics[ADAPTATION],
        }


def _adapted_version(
    session: Any,
    blobs: Any,
    robot: models.Robot,
    parent: models.ModelVersion,
    views: int,
    share: float,
    seed: int | None,
    folder: Path,
) -> models.ModelVersion:
    """The adapted files made in `folder` (a scratch folder) and stored as a new candidate version."""
    var_path = materialise(blobs, str(parent.var_key), folder / "parent" / "var.pt")
    policy_path = None
    if parent.policy_key is not None:
        policy_path = materialise(blobs, parent.policy_key, folder / "parent" / "policy.pt")
    source, images = room_views(session, blobs, robot, views, share, _image_size(var_path), seed)
    var_out, policy_out, record = adapted_files(var_path, policy_path, images, share, folder)
    record = {**record, "views_from": source, "from_version": parent.id}
    return model_versions.create_version(
        session,
        robot,
        var_key=blobs.put(var_out.read_bytes()),
        policy_key=blobs.put(policy_out.read_bytes()) if policy_out is not None else None,
        parent_id=parent.id,
        metrics={**_kept_metrics(parent), ADAPTATION: record},
        notes=_notes(parent.id, record),
    )


def room_views(
    session: Any,
    blobs: Any,
    robot: models.Robot,
    count: int,
    share: float,
    image_size: int,
    seed: int | None = None,
) -> tuple[dict[str, Any] | None, np.ndarray]:
    """Where the views come from, and the views (none for share 0, which needs none); a simulated robot's
    random moves start from `seed` (a fresh one when None)."""
    if share == 0:
        return None, np.zeros((0, image_size, image_size, 3), dtype=np.uint8)
    if models.RobotKind(robot.kind).simulated:
        from sim.explore import random_views
        from worker.capture import fresh_seed

        seed = fresh_seed() if seed is None else seed
        room = room_of(robot.settings or {})
        drawn = random_views(world_of_kind(robot.kind), count, seed=seed, image_size=image_size, domain=room)
        return {"rendered": count, "seed": seed}, np.stack([image for image, _, _ in drawn])
    snapshot_ids, images = newest_views(session, blobs, robot, count, image_size)
    return {"snapshots": [snapshot_ids[0], snapshot_ids[-1]]}, images


def newest_views(
    session: Any, blobs: Any, robot: models.Robot, count: int, image_size: int
) -> tuple[list[int], np.ndarray]:
    """The robot's `count` newest live snapshots (oldest first) as uint8 images at the VAR's size."""
    rows = list(
        session.scalars(
            select(models.Snapshot)
            .where(models.Snapshot.robot_id == robot.id, models.Snapshot.deleted_at.is_(None))
            .order_by(models.Snapshot.id.desc())
            .limit(count)
        )
    )[::-1]
    if len(rows) < MIN_ROOM_VIEWS:
        raise AdaptationRefused(
            f"robot {robot.id} has {len(rows)} camera views and adapting to its room needs at least "
            f"{MIN_ROOM_VIEWS}: send {MIN_ROOM_VIEWS - len(rows)} more of its camera frames, then ask again"
        )
    return [row.id for row in rows], np.stack(
        [decoded_image(blobs.get(row.image_key), image_size) for row in rows]
    )


def adapted_files(
    var_path: Path, policy_path: Path | None, images: np.ndarray, share: float, folder: Path
) -> tuple[Path, Path | None, dict[str, Any]]:
    """The VAR (and the policy, when it sees through the VAR) with statistics adapted to `images`."""
    from learning.rl.checkpoints import policy_with_view, read_policy_checkpoint
    from learning.var.checkpoint import load_var, read_checkpoint, save_var
    from learning.var.room_adaptation import adapt_to_room

    payload = read_checkpoint(var_path)
    var = load_var(var_path)
    earlier = payload.get(ADAPTATION) or {}
    adaptation = adapt_to_room(var.image_encoder, images, share, earlier.get("statistics_before"))
    record = adaptation.to_dict()
    kept = {key: payload[key] for key in KEPT_CHECKPOINT_KEYS if key in payload}
    adapted = {**record, "statistics_before": adaptation.statistics_before}
    var_out = save_var(var, folder / "var.pt", **kept, **{ADAPTATION: adapted})
    policy_out = None
    if policy_path is not None:
        sees_through_var = read_policy_checkpoint(policy_path)["policy_config"].get("view_var") is not None
        policy_out = folder / "policy.pt"
        if sees_through_var:
            policy_with_view(policy_path, var.image_encoder.state_dict(), policy_out)
        else:
            policy_out.write_bytes(policy_path.read_bytes())
        record["policy_view_adapted"] = sees_through_var
    return var_out, policy_out, record


def _notes(parent_id: int, record: dict[str, Any]) -> str:
    if record["share"] == 0:
        return f"version {parent_id} with its base model's batch-norm statistics back (no weight changed)"
    return (
        f"version {parent_id} adapted to {record['views']} camera views of this room (batch-norm "
        f"statistics moved {record['share']:.0%} of the way; no weight changed)"
    )


def _kept_metrics(parent: models.ModelVersion) -> dict[str, Any]:
    """What a version's metrics say of where it came from that still holds after adapting (the base model's
    record names the rooms its policy replays)."""
    return {key: value for key, value in (parent.metrics or {}).items() if key == "base_model"}


def _image_size(var_path: Path) -> int:
    from learning.var.checkpoint import read_checkpoint

    return int(read_checkpoint(var_path)["config"]["image_size"])
