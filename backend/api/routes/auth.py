from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from fastapi.security import OAuth2PasswordRequestForm

from backend import models, schemas
from backend.api.responses import errors
from backend.deps import CallerDep, SessionDep, SettingsDep
from backend.schemas import PathId
from backend.security import CSRF_COOKIE, SESSION_COOKIE
from backend.services import accounts
from backend.settings import Settings

router = APIRouter(prefix="/auth", tags=["auth"])

_WRONG = "wrong username or password"
# Documented for clients: what a sign-in may answer besides 200 and 401.
_SIGN_IN_REFUSALS = {
    401: {"model": schemas.Message, "description": "Wrong username or password."},
    429: {"description": "Too many wrong passwords for this account or address: wait `Retry-After` seconds."},
    503: {"description": "Too many sign-ins waiting to be checked: wait `Retry-After` seconds."},
}


def _client(request: Request) -> accounts.Client:
    return accounts.Client(
        request.client.host if request.client else "unknown", request.headers.get("user-agent")
    )


async def _sign_in(
    request: Request, session: SessionDep, settings: Settings, username: str, password: str, kind: str
) -> tuple[models.User, str, models.AuthSession]:
    client = _client(request)
    user = await accounts.authenticate(session, settings, username, password, client)
    if user is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, _WRONG)
    opened = await run_in_threadpool(accounts.open_session, session, user, kind, settings, client)
    return user, *opened


@router.post("/login", response_model=schemas.LoginResult, responses=_SIGN_IN_REFUSALS)
async def login(  # type: ignore[no-untyped-def]
    body: schemas.LoginRequest,
    request: Request,
    response: Response,
    session: SessionDep,
    settings: SettingsDep,
):
    """Browsers: sets an HttpOnly SameSite session cookie; send `csrf_token` as X-CSRF-Token on writes."""
    user, token, auth_session = await _sign_in(
        request, session, settings, body.username, body.password, "cookie"
    )
    max_age = settings.session_ttl_hours * 3600
    secure = settings.secure_cookies
    response.set_cookie(
        SESSION_COOKIE, token, max_age=max_age, httponly=True, samesite="lax", secure=secure, path="/"
    )
    response.set_cookie(
        CSRF_COOKIE,
        auth_session.csrf_token,
        max_age=max_age,
        httponly=False,
        samesite="strict",
        secure=secure,
        path="/",
    )
    return schemas.LoginResult(
        user=schemas.UserPublic.model_validate(user),
        household=schemas.HouseholdPublic.model_validate(user.household),
        csrf_token=auth_session.csrf_token,
        expires_at=auth_session.expires_at,
    )


@router.post("/token", response_model=schemas.TokenResult, responses=_SIGN_IN_REFUSALS)
async def token(  # type: ignore[no-untyped-def]
    form: Annotated[OAuth2PasswordRequestForm, Depends()],
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
):
    """Scripts: a bearer token (`Authorization: Bearer …`); no CSRF token needed."""
    _user, access_token, auth_session = await _sign_in(
        request, session, settings, form.username, form.password, "bearer"
    )
    return schemas.TokenResult(access_token=access_token, expires_at=auth_session.expires_at)


@router.post("/logout", status_code=status.HTTP_204_NO_CONTENT)
def logout(caller: CallerDep, session: SessionDep, response: Response) -> None:
    accounts.close_session(session, caller.auth_session)
    response.delete_cookie(SESSION_COOKIE, path="/")
    response.delete_cookie(CSRF_COOKIE, path="/")


@router.get("/me", response_model=schemas.UserPublic)
def me(caller: CallerDep):  # type: ignore[no-untyped-def]
    return caller.user


@router.patch("/me", response_model=schemas.UserPublic, responses=errors(429, 503))
def update_me(body: schemas.MeUpdate, caller: CallerDep, session: SessionDep, settings: SettingsDep):  # type: ignore[no-untyped-def]
    """A new password (with the current one) signs out every other session of yours; this one stays."""
    return accounts.update_me(session, caller.user, body, settings, caller.auth_session)


@router.get("/sessions", response_model=list[schemas.SessionPublic])
def sessions(caller: CallerDep, session: SessionDep) -> list[schemas.SessionPublic]:
    """Your signed-in browsers and scripts, oldest first."""
    current = caller.signed_in.auth_session_id
    return [
        schemas.SessionPublic.model_validate(found).model_copy(update={"current": found.id == current})
        for found in accounts.list_sessions(session, caller.user_id)
    ]


@router.delete("/sessions", status_code=status.HTTP_204_NO_CONTENT)
def end_other_sessions(caller: CallerDep, session: SessionDep) -> None:
    """Signs out everywhere else: every session of yours but this one."""
    accounts.end_other_sessions(session, caller.user_id, caller.signed_in.auth_session_id)


@router.delete("/sessions/{session_id}", status_code=status.HTTP_204_NO_CONTENT)
def end_session(session_id: PathId, caller: CallerDep, session: SessionDep) -> None:
    """Ends one of your sessions (this one too: that is signing out)."""
    accounts.close_session(session, accounts.own_session(session, caller.user_id, session_id))
