"""Robot camera images: PNG blobs plus the robot state and where they came from."""

import contextlib
import io
import json
import math
import re
import time
from datetime import UTC, datetime
from typing import Any

import redis
from PIL import Image, UnidentifiedImageError
from sqlalchemy import exists, select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobStore, delete_if_unreferenced, sha256_hex
from backend.broker import redis_client
from backend.errors import Invalid, NotFound, QuotaExceeded, Unavailable

MAX_SIDE = 4096
_SIDE_RULE = f"each side must be 1..{MAX_SIDE} pixels; send the camera frame at its own resolution"
# attempt: backend/services/attempts.py; coaching: backend/services/coaching.py
SOURCES = ("sim-capture", "upload", "camera", "attempt", "coaching")
CAPTURE_QUOTA_PREFIX = "varbot:capture-quota:"  # + household id + hour: views asked for in that hour
_HOUR_S = 3600


def get_snapshot(
    session: Session, household_id: int, snapshot_id: int, include_deleted: bool = True
) -> models.Snapshot:
    snapshot = session.get(models.Snapshot, snapshot_id)
    if (
        snapshot is None
        or snapshot.household_id != household_id
        or (snapshot.deleted_at and not include_deleted)
    ):
        raise NotFound("snapshot", snapshot_id)
    return snapshot


def list_snapshots(
    session: Session, household_id: int, robot_id: int | None, include_deleted: bool, limit: int, offset: int
) -> list[models.Snapshot]:
    query = select(models.Snapshot).where(models.Snapshot.household_id == household_id)
    if robot_id is not None:
        query = query.where(models.Snapshot.robot_id == robot_id)
    if not include_deleted:
        query = query.where(models.Snapshot.deleted_at.is_(None))
    return list(session.scalars(query.order_by(models.Snapshot.id.desc()).limit(limit).offset(offset)))


def as_png(data: bytes, max_bytes: int) -> tuple[bytes, int, int]:
    """The image as PNG bytes (kept as sent when already a plain PNG) with its width and height."""
    if not data:
        raise Invalid("the image is empty (0 bytes)")
    if len(data) > max_bytes:
        raise Invalid(f"the image is {len(data) / 1e6:.1f} MB; at most {max_bytes / 1e6:.0f} MB")
    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.format not in ("PNG", "JPEG", "WEBP"):
                raise Invalid(f"send a PNG or JPEG camera image, not {image.format}")
            width, height = image.size  # as the header declares it: nothing is decoded yet
            if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
                raise Invalid(f"the image is {width}×{height}; {_SIDE_RULE}")
            image.load()
            if image.format == "PNG" and image.mode in ("RGB", "RGBA", "L"):
                return data, width, height
            out = io.BytesIO()
            image.convert("RGB").save(out, format="PNG")
            return out.getvalue(), width, height
    except Image.DecompressionBombError as exc:  # Pillow refuses to open it at all: far over our limit
        raise Invalid(f"the image {_declared_pixels(exc)}; {_SIDE_RULE}") from exc
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        if isinstance(exc, Invalid):
            raise
        raise Invalid("the image cannot be decoded; send a PNG or JPEG camera image") from exc


def _declared_pixels(bomb: Image.DecompressionBombError) -> str:
    found = re.search(r"\((\d+) pixels\)", str(bomb))
    return f"declares {int(found[1]):,} pixels" if found else "declares far too many pixels"


def reserve_capture(household_id: int, count: int, per_hour: int) -> None:
    """Counts `count` views against the household's hourly capture quota (in Redis, shared by every API
    process), or refuses them with 429 and when to try again; `refund_capture` gives them back."""
    now = time.time()
    key = f"{CAPTURE_QUOTA_PREFIX}{household_id}:{int(now // _HOUR_S)}"
    try:
        pipe = redis_client().pipeline(transaction=True)
        pipe.incrby(key, count)
        pipe.expire(key, _HOUR_S + 60)
        used = pipe.execute()[0]
        if used <= per_hour:
            return
        redis_client().decrby(key, count)
    except redis.RedisError as exc:
        raise Unavailable(f"the task queue (Redis) is not reachable ({exc}); no views were captured") from exc
    retry_after = math.ceil(_HOUR_S - now % _HOUR_S)
    raise QuotaExceeded(
        f"your household may capture {per_hour} camera views an hour and has {per_hour - (used - count)} "
        f"left this hour; ask for fewer views, or try again in {math.ceil(retry_after / 60)} min",
        retry_after,
    )


def refund_capture(household_id: int, count: int) -> None:
    """Gives back views that were counted but never queued (best effort)."""
    key = f"{CAPTURE_QUOTA_PREFIX}{household_id}:{int(time.time() // _HOUR_S)}"
    with contextlib.suppress(redis.RedisError):
        redis_client().decrby(key, count)


def parse_json_field(text: str | None, what: str, expected: type) -> Any:
    if text is None or text == "":
        return expected()
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise Invalid(f"{what} must be JSON ({exc.msg})") from exc
    if not isinstance(value, expected):
        raise Invalid(f"{what} must be a JSON {'list of numbers' if expected is list else 'object'}")
    return value


def check_state(state: list[Any]) -> list[float]:
    if len(state) > 64 or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in state):
        raise Invalid("state must be a list of at most 64 numbers (e.g. gripper x, y)")
    if any(v != v or v in (float("inf"), float("-inf")) for v in state):
        raise Invalid("state must hold finite numbers")
    return [float(v) for v in state]


def create_snapshot(
    session: Session,
    blobs: BlobStore,
    robot: models.Robot,
    image: bytes,
    state: list[float],
    source: str,
    meta: dict[str, Any] | None = None,
    max_bytes: int = 10 * 1024 * 1024,
) -> models.Snapshot:
    """Also the workers' way in: `capture_snapshots` renders PNGs and stores them through here."""
    if source not in SOURCES:
        raise Invalid(f"source must be one of {', '.join(SOURCES)}")
    png, width, height = as_png(image, max_bytes)
    is_new = not blobs.exists(sha256_hex(png))
    key = blobs.put(png)
    snapshot = models.Snapshot(
        household_id=robot.household_id,
        robot_id=robot.id,
        image_key=key,
        width=width,
        height=height,
        state=check_state(state),
        source=source,
        meta=meta or {},
    )
    try:
        session.add(snapshot)
        session.commit()
    except BaseException:
        session.rollback()
        delete_if_unreferenced(session, blobs, [key] if is_new else [])
        raise
    return snapshot


def delete_snapshot(session: Session, blobs: BlobStore, snapshot: models.Snapshot) -> None:
    """Like clips: a labelled snapshot is only marked deleted (and leaves training); others go entirely."""
    if snapshot.deleted_at is not None:
        return
    if session.scalar(select(exists().where(models.Label.snapshot_id == snapshot.id))):
        snapshot.deleted_at = datetime.now(UTC)
        session.commit()
        return
    key = snapshot.image_key
    session.delete(snapshot)
    session.commit()
    delete_if_unreferenced(session, blobs, [key])
