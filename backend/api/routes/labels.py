from typing import Annotated

from fastapi import APIRouter, Query, Response, status
from pydantic import BaseModel
from sqlalchemy.orm import Session

from backend import models, schemas
from backend.api.responses import errors
from backend.deps import Caller, CallerDep, SessionDep
from backend.schemas import Offset, PathId, QueryId
from backend.services import labels, pairs, robots, triplets

router = APIRouter(tags=["labels"])


def _json(body: BaseModel, status_code: int = status.HTTP_200_OK) -> Response:
    """The labelling loop's responses, built and checked once here: FastAPI passes a Response through
    without validating it a second time (on a thread hop of its own)."""
    return Response(body.model_dump_json(), status_code=status_code, media_type="application/json")


@router.get("/labels/next", response_model=schemas.NextPair, responses=errors(404))
def next_pair(caller: CallerDep, session: SessionDep, robot_id: QueryId = None) -> Response:
    """The next (image, command) pair to ask about: never one already answered, balanced across the
    household's commands, and (once an active model has embedded the data) the image that sits most
    between two commands."""
    if robot_id is not None:
        robots.get_robot(session, caller.household_id, robot_id)
    choice = pairs.next_pair(session, caller.user_id, caller.household_id, robot_id)
    if choice is None:
        return _json(
            schemas.NextPair(
                snapshot=None,
                clip=None,
                strategy="none",
                message="nothing left to ask: record a command, or capture more camera views "
                "(POST /api/v1/robots/{robot_id}/snapshots:capture)",
            )
        )
    return _json(
        schemas.NextPair(
            snapshot=schemas.SnapshotPublic.model_validate(choice.snapshot),
            clip=schemas.ClipPublic.model_validate(choice.clip),
            strategy=choice.strategy,  # type: ignore[arg-type]
            informativeness=choice.informativeness,
            message="does this command describe what the robot sees?",
        )
    )


@router.post(
    "/labels",
    response_model=schemas.LabelPublic,
    status_code=status.HTTP_201_CREATED,
    responses=errors(404, 409),
)
def create_label(body: schemas.LabelCreate, caller: CallerDep, session: SessionDep) -> Response:
    label = labels.create_label(session, caller.user_id, caller.household_id, body)
    return _json(schemas.LabelPublic.model_validate(label), status.HTTP_201_CREATED)


@router.get("/labels", response_model=list[schemas.LabelPublic])
def list_labels(
    caller: CallerDep,
    session: SessionDep,
    snapshot_id: QueryId = None,
    clip_id: QueryId = None,
    labeller_id: QueryId = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Offset = 0,
) -> list[models.Label]:
    return labels.list_labels(session, caller.household_id, snapshot_id, clip_id, labeller_id, limit, offset)


@router.get("/labels/{label_id}", response_model=schemas.LabelDetail)
def get_label(label_id: PathId, caller: CallerDep, session: SessionDep) -> schemas.LabelDetail:
    label = labels.get_label(session, caller.household_id, label_id)
    return schemas.LabelDetail.model_validate(
        {
            **schemas.LabelPublic.model_validate(label).model_dump(),
            "history": [
                schemas.LabelEventPublic.model_validate(e) for e in labels.history(session, label.id)
            ],
        }
    )


@router.put("/labels/{label_id}", response_model=schemas.LabelPublic)
def change_label(
    label_id: PathId, body: schemas.LabelUpdate, caller: CallerDep, session: SessionDep
) -> models.Label:
    """Only the member who answered (or an admin) may change an answer."""
    return labels.change_label(session, _own_label(label_id, caller, session), caller.user_id, body.verdict)


@router.delete("/labels/{label_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_label(label_id: PathId, caller: CallerDep, session: SessionDep) -> None:
    """Undo (the member who answered, or an admin): the label goes, its history (who answered, who removed it,
    when) stays."""
    labels.delete_label(session, _own_label(label_id, caller, session), caller.user_id)


def _own_label(label_id: int, caller: Caller, session: Session) -> models.Label:
    label = labels.get_label(session, caller.household_id, label_id)
    labels.check_may_change(label, caller.user_id, caller.is_admin)
    return label


@router.get("/triplets/stats", response_model=schemas.TripletStats, responses=errors(404))
def triplet_stats(caller: CallerDep, session: SessionDep, robot_id: QueryId = None) -> schemas.TripletStats:
    """How many triplets the labels yield, per command and per member (the rule is core/labels.py)."""
    if robot_id is not None:
        robots.get_robot(session, caller.household_id, robot_id)
    return triplets.triplet_stats(session, caller.household_id, robot_id)
