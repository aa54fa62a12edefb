"""Snapshot capture for simulated robots: the robot moves at random (`sim.explore.random_views`) and every
view is stored as a PNG in the blob store with a snapshot row (robot state, and the simulator's own account of
what is in view as `meta["sim_heard"]`, used only to score simulated success — never shown as a label)."""

import io
import secrets

import numpy as np
from PIL import Image

from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services.snapshots import create_snapshot
from core.robots import world_of_kind
from core.rooms import room_of
from worker.base_models import BaseModelMissing, find_base


def fresh_seed() -> int:
    """A seed no earlier request used (likely): a household that asks again gets new views."""
    return secrets.randbits(31)


def capture_views(
    robot_id: int, household_id: int, count: int, task_id: str | None = None, seed: int | None = None
) -> dict:
    """`count` random views of the simulated robot's world in its room, each stored as a snapshot; `seed`
    (default: a fresh one) decides them, given the robot's settings."""
    from sim.explore import random_views

    blobs = get_blob_store()
    with get_session_factory()() as session:
        robot = session.get(models.Robot, robot_id)
        if robot is None or robot.household_id != household_id:
            raise ValueError(f"robot {robot_id} of household {household_id} does not exist")
        if not models.RobotKind(robot.kind).simulated:
            raise ValueError(f"robot {robot_id} is a real {robot.kind}; it uploads its own frames")
        world = world_of_kind(robot.kind)
        settings = robot.settings or {}
        image_size = int(settings.get("image_size") or _base_image_size(world))
        seed = fresh_seed() if seed is None else seed
        created = []
        for index, (image, heard, state) in enumerate(
            random_views(world, count, seed=seed, image_size=image_size, domain=room_of(settings))
        ):
            snapshot = create_snapshot(
                session,
                blobs,
                robot,
                png(image),
                [float(v) for v in np.asarray(state).ravel()],
                "sim-capture",
                meta={"world": world, "seed": seed, "index": index, "sim_heard": heard, "task_id": task_id},
            )
            created.append(snapshot.id)
    return {"robot_id": robot_id, "created": len(created), "snapshot_ids": created}


def _base_image_size(world: str) -> int:
    try:
        return find_base(world).image_size
    except BaseModelMissing:
        return 96


def png(image: np.ndarray) -> bytes:
    out = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(out, format="PNG")
    return out.getvalue()
