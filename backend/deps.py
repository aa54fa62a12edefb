"""FastAPI dependencies, as annotated aliases: SessionDep, SettingsDep, BlobsDep, CurrentUser, AdminUser."""

from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cached_property, lru_cache
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import bindparam, select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobStore, LocalBlobStore
from backend.db import get_engine, get_session_factory
from backend.security import CSRF_HEADER, SESSION_COOKIE, same_token, signed_in_cache, token_digest
from backend.settings import Settings, get_settings

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


async def get_db() -> AsyncIterator[Session]:
    """One session per request. Opening one does no I/O, so it happens on the event loop rather than on a
    worker thread; so does closing one, unless a PostgreSQL transaction is still open (a round trip)."""
    session = get_session_factory()()
    try:
        yield session
    finally:
        if session.in_transaction() and get_engine().dialect.name != "sqlite":
            await run_in_threadpool(session.close)
        else:
            session.close()


async def current_settings() -> Settings:
    return get_settings()


@lru_cache
def _local_blob_store(root: str) -> LocalBlobStore:
    return LocalBlobStore(root)  # type: ignore[arg-type]


def get_blob_store() -> BlobStore:
    return _local_blob_store(str(get_settings().blob_path))


def forget_cached_settings() -> None:
    """Drop everything built from the settings (engine, sessions, broker clients, blob store), so the next
    use reads the environment afresh: for a process that points itself at another database or Redis."""
    from backend import broker

    for cached in (
        get_settings,
        get_engine,
        get_session_factory,
        broker.celery_client,
        broker.redis_client,
        _local_blob_store,
    ):
        cached.cache_clear()


def get_sessions() -> Callable[[], Session]:
    """For endpoints that outlive one session (streams): a factory for short-lived sessions."""
    return get_session_factory()


SessionDep = Annotated[Session, Depends(get_db)]
SessionFactoryDep = Annotated[Callable[[], Session], Depends(get_sessions)]
SettingsDep = Annotated[Settings, Depends(current_settings)]
BlobsDep = Annotated[BlobStore, Depends(get_blob_store)]


class Caller:
    """The signed-in member behind a request. Identity and role come with the sign-in lookup; the `user` and
    `auth_session` rows are loaded from the request's session only by the endpoints that need them."""

    def __init__(self, signed_in: "SignedIn", session: Session) -> None:
        self.signed_in = signed_in
        self.user_id = signed_in.user_id
        self.household_id = signed_in.household_id
        self.is_admin = signed_in.role == models.Role.ADMIN
        self._session = session

    @cached_property
    def user(self) -> models.User:
        return self._session.get_one(models.User, self.user_id)

    @cached_property
    def auth_session(self) -> models.AuthSession:
        return self._session.get_one(models.AuthSession, self.signed_in.auth_session_id)


@dataclass(frozen=True)
class SignedIn:
    """What one sign-in lookup yields: enough to authorise a request without loading ORM objects."""

    auth_session_id: int
    user_id: int
    household_id: int
    role: str
    csrf_token: str
    expires_at: datetime


_SIGNED_IN = (
    select(
        models.AuthSession.id,
        models.AuthSession.user_id,
        models.User.household_id,
        models.User.role,
        models.AuthSession.csrf_token,
        models.AuthSession.expires_at,
    )
    .join(models.User, models.User.id == models.AuthSession.user_id)
    .where(
        models.AuthSession.token_hash == bindparam("token_hash"),
        models.AuthSession.kind == bindparam("kind"),
        models.User.is_active.is_(True),
    )
)


def _look_up(session: Session, token_hash: str, kind: str) -> SignedIn | None:
    generation = signed_in_cache.generation
    row = session.connection().execute(_SIGNED_IN, {"token_hash": token_hash, "kind": kind}).first()
    if row is None:
        return None
    signed_in = SignedIn(*row)
    signed_in_cache.remember(token_hash, kind, signed_in, generation)
    return signed_in


def _unauthorised(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_401_UNAUTHORIZED, detail, headers={"WWW-Authenticate": "Bearer"})


def _credentials(request: Request, settings: Settings) -> tuple[str, str]:
    """The HMAC of the session token the request carries, and how it came (bearer header or cookie)."""
    authorization = request.headers.get("authorization", "")
    scheme, _, bearer = authorization.partition(" ")
    if scheme.lower() == "bearer" and bearer:
        token, kind = bearer.strip(), "bearer"
    elif cookie := request.cookies.get(SESSION_COOKIE):
        token, kind = cookie, "cookie"
    else:
        raise _unauthorised(
            "sign in first: POST /api/v1/auth/login (browsers) or /api/v1/auth/token (scripts)"
        )
    return token_digest(token, settings.secret_key), kind


def _authorise(request: Request, kind: str, signed_in: SignedIn | None, session: Session) -> Caller:
    if signed_in is None or signed_in.expires_at <= datetime.now(UTC):
        raise _unauthorised("your session has expired or was signed out; sign in again")
    if kind == "cookie" and request.method not in SAFE_METHODS:
        sent = request.headers.get(CSRF_HEADER, "")
        if not sent or not same_token(sent, signed_in.csrf_token):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                f"missing or wrong CSRF token: send the {CSRF_HEADER} header with the csrf_token from "
                "sign-in (also in the varbot_csrf cookie)",
            )
    return Caller(signed_in, session)


def get_caller(request: Request, session: Session, settings: Settings) -> Caller:
    """The signed-in member behind a request (or a WebSocket handshake); 401/403 otherwise."""
    token_hash, kind = _credentials(request, settings)
    signed_in = signed_in_cache.get(token_hash, kind) or _look_up(session, token_hash, kind)
    return _authorise(request, kind, signed_in, session)


async def current_caller(request: Request, session: SessionDep, settings: SettingsDep) -> Caller:
    """The dependency: a recently seen session costs no database query and no worker thread."""
    token_hash, kind = _credentials(request, settings)
    signed_in = signed_in_cache.get(token_hash, kind)
    if signed_in is None:
        signed_in = await run_in_threadpool(_look_up, session, token_hash, kind)
    return _authorise(request, kind, signed_in, session)


CallerDep = Annotated[Caller, Depends(current_caller)]


def get_admin(caller: CallerDep) -> Caller:
    if not caller.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only a household admin may do this")
    return caller


AdminDep = Annotated[Caller, Depends(get_admin)]
