"""FastAPI dependencies, as annotated aliases: SessionDep, SettingsDep, BlobsDep, CurrentUser, AdminUser."""

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import lru_cache
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobStore, LocalBlobStore
from backend.db import get_session_factory, session_scope
from backend.security import CSRF_HEADER, SESSION_COOKIE, same_token, token_digest
from backend.settings import Settings, get_settings

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def get_db() -> Iterator[Session]:
    yield from session_scope()


@lru_cache
def _local_blob_store(root: str) -> LocalBlobStore:
    return LocalBlobStore(root)  # type: ignore[arg-type]


def get_blob_store() -> BlobStore:
    return _local_blob_store(str(get_settings().blob_path))


def get_sessions() -> Callable[[], Session]:
    """For endpoints that outlive one session (streams): a factory for short-lived sessions."""
    return get_session_factory()


SessionDep = Annotated[Session, Depends(get_db)]
SessionFactoryDep = Annotated[Callable[[], Session], Depends(get_sessions)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
BlobsDep = Annotated[BlobStore, Depends(get_blob_store)]


@dataclass(frozen=True)
class Caller:
    user: models.User
    auth_session: models.AuthSession

    @property
    def household_id(self) -> int:
        return self.user.household_id


def _unauthorised(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_401_UNAUTHORIZED, detail, headers={"WWW-Authenticate": "Bearer"})


def get_caller(request: Request, session: SessionDep, settings: SettingsDep) -> Caller:
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
    auth_session = session.scalar(
        select(models.AuthSession).where(
            models.AuthSession.token_hash == token_digest(token, settings.secret_key),
            models.AuthSession.kind == kind,
        )
    )
    if (
        auth_session is None
        or auth_session.expires_at <= datetime.now(UTC)
        or not auth_session.user.is_active
    ):
        raise _unauthorised("your session has expired or was signed out; sign in again")
    if kind == "cookie" and request.method not in SAFE_METHODS:
        sent = request.headers.get(CSRF_HEADER, "")
        if not sent or not same_token(sent, auth_session.csrf_token):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                f"missing or wrong CSRF token: send the {CSRF_HEADER} header with the csrf_token from "
                "sign-in (also in the varbot_csrf cookie)",
            )
    return Caller(user=auth_session.user, auth_session=auth_session)


CallerDep = Annotated[Caller, Depends(get_caller)]


def get_admin(caller: CallerDep) -> Caller:
    if not caller.user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only a household admin may do this")
    return caller


AdminDep = Annotated[Caller, Depends(get_admin)]
