from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Response, status
from fastapi.security import OAuth2PasswordRequestForm

from backend import schemas
from backend.deps import CallerDep, SessionDep, SettingsDep
from backend.security import CSRF_COOKIE, SESSION_COOKIE
from backend.services import accounts

router = APIRouter(prefix="/auth", tags=["auth"])

_WRONG = "wrong username or password"


@router.post("/login", response_model=schemas.LoginResult)
def login(body: schemas.LoginRequest, response: Response, session: SessionDep, settings: SettingsDep):  # type: ignore[no-untyped-def]
    """Browsers: sets an HttpOnly SameSite session cookie; send `csrf_token` as X-CSRF-Token on writes."""
    user = accounts.authenticate(session, body.username, body.password)
    if user is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, _WRONG)
    token, auth_session = accounts.open_session(
        session, user, "cookie", settings.secret_key, settings.session_ttl_hours
    )
    max_age = settings.session_ttl_hours * 3600
    secure = settings.cookie_secure
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


@router.post("/token", response_model=schemas.TokenResult)
def token(form: Annotated[OAuth2PasswordRequestForm, Depends()], session: SessionDep, settings: SettingsDep):  # type: ignore[no-untyped-def]
    """Scripts: a bearer token (`Authorization: Bearer …`); no CSRF token needed."""
    user = accounts.authenticate(session, form.username, form.password)
    if user is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, _WRONG)
    access_token, auth_session = accounts.open_session(
        session, user, "bearer", settings.secret_key, settings.session_ttl_hours
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


@router.patch("/me", response_model=schemas.UserPublic)
def update_me(body: schemas.MeUpdate, caller: CallerDep, session: SessionDep):  # type: ignore[no-untyped-def]
    return accounts.update_me(session, caller.user, body)
