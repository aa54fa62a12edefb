from fastapi import APIRouter
from fastapi.responses import JSONResponse
from sqlalchemy import text

from backend import broker, schemas
from backend.deps import SessionDep

router = APIRouter(tags=["health"])


@router.get("/health", response_model=schemas.Health, responses={503: {"model": schemas.Health}})
def health(session: SessionDep) -> JSONResponse:
    """The database and the broker (Redis) are reachable: 200, else 503 with what is wrong."""
    try:
        session.execute(text("SELECT 1"))
        database = "ok"
    except Exception as exc:  # any driver error means "not reachable"
        database = f"unreachable: {exc.__class__.__name__}: {exc}"
    broker_state = broker.broker_status()
    ok = database == "ok" and broker_state == "ok"
    body = schemas.Health(status="ok" if ok else "degraded", database=database, broker=broker_state)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)
