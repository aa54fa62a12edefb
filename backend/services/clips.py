"""Voice clips: checked, normalised, stored as two blobs (original + 16 kHz mono WAV) and one row."""

import unicodedata
from datetime import UTC, datetime

from sqlalchemy import exists, select
from sqlalchemy.orm import Session

from backend import models
from backend.audio import AudioRejected, validate_and_normalise
from backend.blobs import BlobStore, delete_if_unreferenced, sha256_hex
from backend.errors import ApiError, Forbidden, Invalid, NotFound
from backend.settings import Settings


class ClipRejected(ApiError):
    def __init__(self, detail: str, status_code: int) -> None:
        super().__init__(detail)
        self.status_code = status_code


_MARKUP = '<>"'  # never in a real file's name (Windows forbids them); echoing them back would be markup


def clean_filename(filename: str | None) -> str:
    """The upload's name is kept for display only; one that tries to be a path is refused outright."""
    if not filename:
        return "recording.wav"
    if markup := sorted(set(filename) & set(_MARKUP)):
        raise Invalid(
            f"the file name contains {' and '.join(repr(c) for c in markup)}, which file names cannot hold; "
            "rename the file to a plain name like 'go.wav'"
        )
    if "/" in filename or "\\" in filename or filename in (".", ".."):
        raise Invalid(
            f"the file name {filename!r} contains a folder path; send a plain file name like 'go.wav'"
        )
    if any(unicodedata.category(char).startswith("C") for char in filename):
        raise Invalid("the file name contains control characters; send a plain file name like 'go.wav'")
    if len(filename) > 255:
        raise Invalid(
            "the file name is longer than 255 characters; rename the file to a short name like 'go.wav'"
        )
    return filename


def get_clip(session: Session, household_id: int, clip_id: int, include_deleted: bool = True) -> models.Clip:
    clip = session.get(models.Clip, clip_id)
    if clip is None or clip.household_id != household_id or (clip.deleted_at and not include_deleted):
        raise NotFound("clip", clip_id)
    return clip


def list_clips(
    session: Session,
    household_id: int,
    speaker_id: int | None,
    include_deleted: bool,
    limit: int,
    offset: int,
) -> list[models.Clip]:
    query = select(models.Clip).where(models.Clip.household_id == household_id)
    if speaker_id is not None:
        query = query.where(models.Clip.speaker_id == speaker_id)
    if not include_deleted:
        query = query.where(models.Clip.deleted_at.is_(None))
    return list(session.scalars(query.order_by(models.Clip.id.desc()).limit(limit).offset(offset)))


def create_clip(
    session: Session,
    blobs: BlobStore,
    settings: Settings,
    speaker: models.User,
    filename: str | None,
    data: bytes,
    name: str | None,
) -> models.Clip:
    display_name = clean_filename(filename)
    try:
        normalised = validate_and_normalise(
            data,
            min_seconds=settings.min_clip_seconds,
            max_seconds=settings.max_clip_seconds,
            max_bytes=settings.max_clip_bytes,
        )
    except AudioRejected as exc:
        raise ClipRejected(str(exc), exc.status_code) from exc
    checksum = sha256_hex(data)
    new_keys = [key for key in (checksum, sha256_hex(normalised.wav)) if not blobs.exists(key)]
    original_key, wav_key = blobs.put(data), blobs.put(normalised.wav)
    clip = models.Clip(
        household_id=speaker.household_id,
        speaker_id=speaker.id,
        name=name or None,
        original_filename=display_name,
        original_key=original_key,
        original_size=len(data),
        wav_key=wav_key,
        checksum=checksum,
        duration_s=normalised.duration_s,
        sample_rate=normalised.sample_rate,
        channels=normalised.channels,
    )
    try:
        session.add(clip)
        session.commit()
    except BaseException:
        session.rollback()
        delete_if_unreferenced(session, blobs, new_keys)
        raise
    return clip


def rename_clip(session: Session, clip: models.Clip, caller: models.User, name: str | None) -> models.Clip:
    _check_may_change(clip, caller)
    clip.name = name
    session.commit()
    return clip


def delete_clip(session: Session, blobs: BlobStore, clip: models.Clip, caller: models.User) -> None:
    """A labelled clip is only marked deleted (its labels stay as history but leave training); others go."""
    _check_may_change(clip, caller)
    if clip.deleted_at is not None:
        return
    if session.scalar(select(exists().where(models.Label.clip_id == clip.id))):
        clip.deleted_at = datetime.now(UTC)
        session.commit()
        return
    keys = [clip.original_key, clip.wav_key]
    session.delete(clip)
    session.commit()
    delete_if_unreferenced(session, blobs, keys)


def _check_may_change(clip: models.Clip, caller: models.User) -> None:
    if clip.speaker_id != caller.id and not caller.is_admin:
        raise Forbidden("only the member who recorded this clip (or an admin) may change or delete it")
