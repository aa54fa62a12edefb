import asyncio
import json
import time
from collections.abc import AsyncIterator
from datetime import datetime
from typing import Annotated, Any

import redis.asyncio
from fastapi import APIRouter, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from sqlalchemy import select

from backend import broker, models, schemas
from backend.api.responses import errors
from backend.deps import AdminDep, CallerDep, SessionDep, SessionFactoryDep, SettingsDep
from backend.models import RunStatus
from backend.schemas import Offset, PathId, QueryId
from backend.services import runs

router = APIRouter(prefix="/runs", tags=["runs"])

_HEARTBEAT_S = 15.0
_POLL_WHILE_SUBSCRIBED_S = 5.0


@router.get("/presets", response_model=dict[str, schemas.PresetPublic])
def presets(
    triplets: Annotated[
        int | None,
        Query(
            ge=0,
            le=100_000_000,
            description=f"the household's triplets (default: {runs.MEASURED_TRIPLETS:,})",
        ),
    ] = None,
) -> dict[str, schemas.PresetPublic]:
    """The parameter sets behind "quick", "standard" and "thorough", each with its budget in minutes for a
    household with `triplets` triplets (a VAR epoch's cost grows with them)."""
    return runs.published_presets(triplets)


@router.post(
    "", response_model=schemas.RunPublic, status_code=status.HTTP_201_CREATED, responses=errors(404, 409, 503)
)
def create_run(
    body: schemas.RunCreate, caller: AdminDep, session: SessionDep, settings: SettingsDep
) -> models.Run:
    """Start training (admins). Enqueued by Celery task name on the `training` queue."""
    return runs.create_run(session, caller.user, body, settings.min_triplets_for_training)


@router.get("", response_model=list[schemas.RunPublic])
def list_runs(
    caller: CallerDep,
    session: SessionDep,
    robot_id: QueryId = None,
    status: RunStatus | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Offset = 0,
) -> list[models.Run]:
    return runs.list_runs(session, caller.household_id, robot_id, status, limit, offset)


@router.get(
    "/events",
    response_class=StreamingResponse,
    responses={200: {"content": {"text/event-stream": {}}}, **errors(404)},
)
async def run_events(
    request: Request,
    caller: CallerDep,
    session: SessionDep,
    session_factory: SessionFactoryDep,
    settings: SettingsDep,
    run_id: QueryId = None,
    timeout: Annotated[float, Query(gt=0, le=3600, description="seconds before the stream ends")] = 300.0,
) -> StreamingResponse:
    """Server-Sent Events: `event: run` with a RunPublic as data, first for the current runs, then on every
    change (from Redis pub/sub, with database polling as the fallback). EventSource reconnects by itself."""
    household_id = caller.household_id
    if run_id is not None:
        runs.get_run(session, household_id, run_id)
    session.close()  # the stream must not hold a database connection while it waits

    def poll(since: datetime | None) -> list[dict[str, Any]]:
        with session_factory() as poll_session:
            query = select(models.Run).where(models.Run.household_id == household_id)
            if run_id is not None:
                query = query.where(models.Run.id == run_id)
            if since is None:
                query = query.order_by(models.Run.id.desc()).limit(20)
            else:
                query = query.where(models.Run.updated_at > since)
            return [
                schemas.RunPublic.model_validate(run).model_dump(mode="json")
                for run in poll_session.scalars(query)
            ]

    return StreamingResponse(
        event_stream(
            request, household_id, run_id, timeout, poll, settings.redis_url, settings.sse_poll_seconds
        ),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )


async def event_stream(
    request: Request,
    household_id: PathId,
    run_id: int | None,
    timeout: float,
    poll: Any,
    redis_url: str,
    poll_seconds: float,
) -> AsyncIterator[str]:
    sent: dict[int, str] = {}

    def fresh(run: dict[str, Any]) -> bool:
        if run_id is not None and run["id"] != run_id:
            return False
        if sent.get(run["id"], "") >= run["updated_at"]:
            return False
        sent[run["id"]] = run["updated_at"]
        return True

    def frame(run: dict[str, Any]) -> str:
        return f"id: {run['id']}@{run['updated_at']}\nevent: run\ndata: {json.dumps(run)}\n\n"

    start = time.monotonic()
    for run in reversed(await run_in_threadpool(poll, None)):
        if fresh(run):
            yield frame(run)
    since = _latest(sent)
    pubsub = await _subscribe(redis_url, broker.run_channel(household_id))
    last_poll = last_beat = time.monotonic()
    try:
        while time.monotonic() - start < timeout and not await request.is_disconnected():
            wait = min(poll_seconds, max(0.0, timeout - (time.monotonic() - start)))
            if pubsub is not None:
                try:
                    message = await pubsub.get_message(ignore_subscribe_messages=True, timeout=wait)
                except redis.RedisError:
                    pubsub = None
                    message = None
                if message is not None:
                    run = json.loads(message["data"]).get("run")
                    if isinstance(run, dict) and fresh(run):
                        yield frame(run)
                    continue
            else:
                await asyncio.sleep(wait)
            interval = _POLL_WHILE_SUBSCRIBED_S if pubsub is not None else poll_seconds
            if time.monotonic() - last_poll >= interval:
                last_poll = time.monotonic()
                for run in await run_in_threadpool(poll, since):
                    if fresh(run):
                        yield frame(run)
                since = _latest(sent) or since
            if time.monotonic() - last_beat >= _HEARTBEAT_S:
                last_beat = time.monotonic()
                yield ": keep-alive\n\n"
    finally:
        if pubsub is not None:
            await pubsub.aclose()


def _latest(sent: dict[int, str]) -> datetime | None:
    return max((datetime.fromisoformat(stamp) for stamp in sent.values()), default=None)


async def _subscribe(redis_url: str, channel: str) -> Any:
    try:
        client = redis.asyncio.Redis.from_url(redis_url, socket_connect_timeout=2)
        pubsub = client.pubsub()
        await pubsub.subscribe(channel)
        return pubsub
    except (redis.RedisError, OSError):
        return None


@router.get("/{run_id}", response_model=schemas.RunPublic)
def get_run(run_id: PathId, caller: CallerDep, session: SessionDep) -> models.Run:
    return runs.get_run(session, caller.household_id, run_id)


@router.post("/{run_id}:cancel", response_model=schemas.RunPublic, responses=errors(409))
def cancel_run(run_id: PathId, caller: AdminDep, session: SessionDep) -> models.Run:
    """Queued runs are cancelled at once; a running one stops at its next check of the cancel flag."""
    return runs.cancel_run(session, runs.get_run(session, caller.household_id, run_id))
