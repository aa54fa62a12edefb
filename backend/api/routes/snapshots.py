import uuid
from typing import Annotated

from fastapi import APIRouter, File, Form, Query, Request, Response, UploadFile, status

from backend import broker, models, schemas
from backend.api.ranges import ranged_response
from backend.api.responses import errors
from backend.deps import BlobsDep, CallerDep, SessionDep, SettingsDep
from backend.errors import Conflict, Invalid, Unavailable
from backend.schemas import Offset, PathId, QueryId
from backend.services import robots, snapshots
from backend.services.attempts import ATTEMPT_SOURCE
from core.robots import worker_drives

router = APIRouter(tags=["snapshots"])


@router.post(
    "/robots/{robot_id}/snapshots:capture",
    response_model=schemas.CaptureQueued,
    status_code=status.HTTP_202_ACCEPTED,
    responses=errors(409, 429, 503),
)
def capture(
    robot_id: PathId,
    body: schemas.CaptureRequest,
    caller: CallerDep,
    session: SessionDep,
    settings: SettingsDep,
) -> schemas.CaptureQueued:
    """Ask the robot worker to render `count` camera views from random poses (simulated robots); a household
    may ask for `capture_views_per_hour` views an hour (429 with Retry-After beyond that)."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    if not worker_drives(robot.kind, robot.settings or {}):
        raise Conflict(
            f"robot {robot.id} is a real {robot.kind}: it uploads its own frames (POST …/snapshots), or set "
            "its arm_ip so the robot worker drives it"
        )
    if body.count > settings.max_capture_count:
        raise Invalid(f"at most {settings.max_capture_count} views per request; ask for fewer")
    snapshots.reserve_capture(robot.household_id, body.count, settings.capture_views_per_hour)
    task_id = uuid.uuid4().hex
    kwargs = {"robot_id": robot.id, "household_id": robot.household_id, "count": body.count}
    try:
        broker.send_task(broker.TASK_CAPTURE_SNAPSHOTS, kwargs, broker.QUEUE_ROBOT, task_id)
    except broker.BrokerUnavailable as exc:
        snapshots.refund_capture(robot.household_id, body.count)
        raise Unavailable(f"{exc}; no views were captured") from exc
    return schemas.CaptureQueued(
        task_id=task_id, robot_id=robot.id, count=body.count, queue=broker.QUEUE_ROBOT
    )


@router.post("/robots/{robot_id}/snapshots", response_model=schemas.SnapshotPublic, status_code=201)
def upload_snapshot(
    robot_id: PathId,
    image: Annotated[UploadFile, File(description="PNG or JPEG camera frame")],
    caller: CallerDep,
    session: SessionDep,
    blobs: BlobsDep,
    settings: SettingsDep,
    state: Annotated[str, Form(description="JSON list of numbers, e.g. [0.6, 0.1]")] = "[]",
    meta: Annotated[str, Form(description="JSON object with anything else worth keeping")] = "{}",
    source: Annotated[str, Form()] = "upload",
) -> models.Snapshot:
    """A frame from a robot's camera (real robots send theirs this way)."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    if source == ATTEMPT_SOURCE:  # its meta names blobs the API serves: only the robot worker makes them
        raise Invalid("attempts are made by the robot worker: POST …/attempts")
    data = image.file.read(settings.max_image_bytes + 1)
    return snapshots.create_snapshot(
        session,
        blobs,
        robot,
        data,
        snapshots.check_state(snapshots.parse_json_field(state, "state", list)),
        source,
        snapshots.parse_json_field(meta, "meta", dict),
        settings.max_image_bytes,
    )


@router.get("/snapshots", response_model=list[schemas.SnapshotPublic])
def list_snapshots(
    caller: CallerDep,
    session: SessionDep,
    robot_id: QueryId = None,
    include_deleted: bool = False,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Offset = 0,
) -> list[models.Snapshot]:
    return snapshots.list_snapshots(session, caller.household_id, robot_id, include_deleted, limit, offset)


@router.get("/snapshots/{snapshot_id}", response_model=schemas.SnapshotPublic)
def get_snapshot(snapshot_id: PathId, caller: CallerDep, session: SessionDep) -> models.Snapshot:
    return snapshots.get_snapshot(session, caller.household_id, snapshot_id)


@router.get(
    "/snapshots/{snapshot_id}/image",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **errors(206, 304, 410, 416)},
)
def snapshot_image(
    snapshot_id: PathId, request: Request, caller: CallerDep, session: SessionDep, blobs: BlobsDep
) -> Response:
    snapshot = snapshots.get_snapshot(session, caller.household_id, snapshot_id)
    return ranged_response(request, blobs.get(snapshot.image_key), "image/png", snapshot.image_key)


@router.delete("/snapshots/{snapshot_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_snapshot(snapshot_id: PathId, caller: CallerDep, session: SessionDep, blobs: BlobsDep) -> None:
    snapshots.delete_snapshot(
        session, blobs, snapshots.get_snapshot(session, caller.household_id, snapshot_id)
    )
