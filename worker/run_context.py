"""What a run works on: its folder and `state.json`, and the `RunContext` the stages read (the household's
data, the parent version's weights, the robot's world and room), prepared once when the run starts or
resumes."""

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobStore
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.schemas import RunParams
from backend.services import model_versions
from backend.settings import get_settings
from core.paths import data_subdir
from core.robots import world_of_kind
from core.rooms import DomainShift, RoomRanges, ranges_from_fields, room_of
from worker.base_models import BaseModelMissing, find_base
from worker.household import HouseholdData, load_household

STATE_FILE = "state.json"
TRAINS_VAR = (models.RunKind.FINETUNE, models.RunKind.VAR_FINETUNE)


def run_folder(run_id: int) -> Path:
    return data_subdir("runs", str(run_id))


class RunState:
    """`state.json`: the parent version, and the result of every finished stage."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / STATE_FILE
        self.data: dict[str, Any] = (
            json.loads(self.path.read_text()) if self.path.is_file() else {"completed": {}}
        )

    @property
    def completed(self) -> dict[str, Any]:
        return self.data["completed"]

    def save(self) -> None:
        temporary = self.path.with_suffix(".tmp")
        temporary.write_text(json.dumps(self.data, indent=2, default=str))
        os.replace(temporary, self.path)


@dataclass(frozen=True)
class RunContext:
    """Everything the stages read: the household's data, the parent's weights, the run's parameters."""

    run_id: int
    kind: models.RunKind
    params: dict[str, Any]
    folder: Path
    world: str
    room: DomainShift | None
    robot_id: int
    household_id: int
    parent_id: int  # the active version when the run started: what the candidate is measured against
    parent_var: Path
    parent_policy: Path | None
    start_var: Path  # what training starts from: the parent's, or the version its room adaptation came from
    start_policy: Path | None
    parent_base_ranges: RoomRanges | None  # the rooms the parent's base model was trained over, if recorded
    data: HouseholdData
    candidate_id: int | None  # an evaluate run's newest candidate version

    def candidate_var(self) -> Path:
        """The VAR this run made, or the one it started from when it trains none."""
        done = RunState(self.folder).completed.get("var_finetune")
        return Path(done["checkpoint"]) if done else self.start_var

    def candidate_policy(self) -> Path | None:
        """The policy this run made, or the one it started from when it trains none."""
        done = RunState(self.folder).completed.get("policy_improve")
        return Path(done["checkpoint"]) if done else self.start_policy


def prepare_context(
    run_id: int, kind: models.RunKind, params: dict[str, Any], state: RunState, folder: Path
) -> RunContext:
    """The run's context; the parent version is chosen once (kept in `state`), so a resumed run keeps it."""
    from learning.var.checkpoint import front_end_of, read_checkpoint

    blobs = get_blob_store()
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        robot = session.get_one(models.Robot, run.robot_id)
        world = world_of_kind(robot.kind)
        if "parent_id" not in state.data:
            state.data["parent_id"] = active_or_base(session, blobs, robot, world).id
            state.save()
        parent = session.get_one(models.ModelVersion, state.data["parent_id"])
        parent_var = materialise(blobs, parent.var_key, folder / "parent" / "var.pt")
        parent_policy = materialise_optional(blobs, parent.policy_key, folder / "parent" / "policy.pt")
        start_var, start_policy = parent_var, parent_policy
        start = training_start(session, parent, kind, params)
        if start.id != parent.id:
            start_var = materialise(blobs, str(start.var_key), folder / "start" / "var.pt")
            start_policy = materialise_optional(blobs, start.policy_key, folder / "start" / "policy.pt")
        image_size = int(read_checkpoint(parent_var)["config"]["image_size"])
        needs = get_settings().min_triplets_for_training if kind in TRAINS_VAR else 2
        data = load_household(
            session, blobs, robot, image_size, _feature_kind(world), params["held_out_fraction"],
            params["seed"], needs, front_end=front_end_of(parent_var),
        )  # fmt: skip
        return RunContext(
            run_id=run_id,
            kind=kind,
            params=params,
            folder=folder,
            world=world,
            room=room_of(robot.settings or {}),
            robot_id=robot.id,
            household_id=robot.household_id,
            parent_id=parent.id,
            parent_var=parent_var,
            parent_policy=parent_policy,
            start_var=start_var,
            start_policy=start_policy,
            parent_base_ranges=recorded_ranges(parent.metrics),
            data=data,
            candidate_id=_newest_candidate(session, robot.id) if kind == models.RunKind.EVALUATE else None,
        )


def run_param(params: dict[str, Any], name: str) -> Any:
    """A run's parameter, or `RunParams`' default (the one place defaults live) for a run stored before the
    parameter existed."""
    return params.get(name, RunParams.model_fields[name].default)


def training_start(
    session: Session, parent: models.ModelVersion, kind: models.RunKind, params: dict[str, Any]
) -> models.ModelVersion:
    """The version a fine-tune starts from. For a robot adapted to its room (`worker.room_adaptation`), the
    version the adaptation started from, unless the run says `finetune_from_unadapted: false`: trained from
    there, the fine-tune's batch norms learn the room from the household's views and the replayed training
    room together, and the training room kept its success, where a fine-tune of the adapted statistics lost
    up to 9 points of it (README, *Adapting to a room from its own views*)."""
    from learning.var.room_adaptation import CHECKPOINT_KEY

    if kind != models.RunKind.FINETUNE or not run_param(params, "finetune_from_unadapted"):
        return parent
    start = parent
    while adaptation := (start.metrics or {}).get(CHECKPOINT_KEY):  # an adaptation of an adaptation too
        start = session.get_one(models.ModelVersion, adaptation["from_version"])
    return start


def recorded_ranges(metrics: dict[str, Any] | None) -> RoomRanges | None:
    """The training ranges a base model version's record keeps (None for other versions and older records)."""
    fields = ((metrics or {}).get("base_model") or {}).get("room_ranges")
    return ranges_from_fields(fields) if fields else None


def _feature_kind(world: str) -> str:
    try:
        return find_base(world).feature_kind
    except BaseModelMissing:
        return "speech"


def _newest_candidate(session: Session, robot_id: int) -> int | None:
    return session.scalar(
        select(models.ModelVersion.id)
        .where(
            models.ModelVersion.robot_id == robot_id,
            models.ModelVersion.status == models.ModelStatus.CANDIDATE,
        )
        .order_by(models.ModelVersion.id.desc())
    )


def materialise(blobs: BlobStore, key: str, path: Path) -> Path:
    """The blob `key` as a file at `path`, written once, atomically."""
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(".tmp")
        temporary.write_bytes(blobs.get(key))
        os.replace(temporary, path)
    return path


def materialise_optional(blobs: BlobStore, key: str | None, path: Path) -> Path | None:
    """A version's optional file (its policy): None when it has none."""
    return None if key is None else materialise(blobs, key, path)


def active_or_base(
    session: Session, blobs: BlobStore, robot: models.Robot, world: str
) -> models.ModelVersion:
    """The robot's active version; a robot that never had one gets the shipped base model, made active."""
    active = model_versions.active_version(session, robot.id)
    if active is not None:
        return active
    base = find_base(world)
    version = model_versions.create_version(
        session,
        robot,
        var_key=blobs.put(base.var_path.read_bytes()),
        policy_key=blobs.put(base.policy_path.read_bytes()),
        metrics={"base_model": base.record},
        notes=f"base model for the simulated {world} world ({base.folder})",
    )
    model_versions.activate(session, version)  # commits
    return version
