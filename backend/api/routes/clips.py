from typing import Annotated

from fastapi import APIRouter, File, Form, Query, Request, Response, UploadFile, status

from backend import audio, models, schemas
from backend.api.ranges import ranged_response
from backend.api.responses import errors
from backend.deps import BlobsDep, CallerDep, SessionDep, SettingsDep
from backend.schemas import Offset, PathId, QueryId
from backend.services import clips
from backend.services.clips import ClipRejected

router = APIRouter(prefix="/clips", tags=["clips"])


@router.post(
    "", response_model=schemas.ClipPublic, status_code=status.HTTP_201_CREATED, responses=errors(413, 415)
)
def upload_clip(
    file: Annotated[UploadFile, File(description=f"a recording ({audio.ACCEPTED}), 0.3–10 s, at most 5 MB")],
    caller: CallerDep,
    session: SessionDep,
    blobs: BlobsDep,
    settings: SettingsDep,
    name: Annotated[str | None, Form(max_length=100, description="what was said, for people only")] = None,
) -> models.Clip:
    data = file.file.read(settings.max_clip_bytes + 1)
    if len(data) > settings.max_clip_bytes:
        limit_mb = settings.max_clip_bytes / 2**20
        raise ClipRejected(f"the file is over {limit_mb:.0f} MB; clips may be at most {limit_mb:.0f} MB", 413)
    return clips.create_clip(
        session, blobs, settings, caller.user, file.filename, data, (name or "").strip() or None
    )


@router.get("", response_model=list[schemas.ClipPublic])
def list_clips(
    caller: CallerDep,
    session: SessionDep,
    speaker_id: QueryId = None,
    include_deleted: bool = False,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Offset = 0,
) -> list[models.Clip]:
    return clips.list_clips(session, caller.household_id, speaker_id, include_deleted, limit, offset)


@router.get("/{clip_id}", response_model=schemas.ClipPublic)
def get_clip(clip_id: PathId, caller: CallerDep, session: SessionDep) -> models.Clip:
    return clips.get_clip(session, caller.household_id, clip_id)


@router.get(
    "/{clip_id}/audio",
    response_class=Response,
    responses={
        200: {"content": {media_type: {} for media_type in audio.MEDIA_TYPES.values()}},
        **errors(206, 304, 410, 416),
    },
)
def clip_audio(
    clip_id: PathId,
    request: Request,
    caller: CallerDep,
    session: SessionDep,
    blobs: BlobsDep,
    original: bool = False,
) -> Response:
    """The normalised 16 kHz mono 16-bit WAV (or, with `original=true`, the bytes as uploaded)."""
    clip = clips.get_clip(session, caller.household_id, clip_id)
    if not original:
        return ranged_response(request, blobs.get(clip.wav_key), "audio/wav", clip.wav_key)
    data = blobs.get(clip.original_key)
    return ranged_response(request, data, audio.media_type_of(data), clip.original_key)


@router.patch("/{clip_id}", response_model=schemas.ClipPublic)
def rename_clip(
    clip_id: PathId, body: schemas.ClipUpdate, caller: CallerDep, session: SessionDep
) -> models.Clip:
    clip = clips.get_clip(session, caller.household_id, clip_id, include_deleted=False)
    return clips.rename_clip(session, clip, caller.user, body.name)


@router.delete("/{clip_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_clip(clip_id: PathId, caller: CallerDep, session: SessionDep, blobs: BlobsDep) -> None:
    """A clip that has labels is soft-deleted (kept as history, left out of training)."""
    clips.delete_clip(session, blobs, clips.get_clip(session, caller.household_id, clip_id), caller.user)
