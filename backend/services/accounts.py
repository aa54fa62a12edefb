"""Households, members and sign-in sessions.

A member's sessions end together when what they were opened with no longer holds: a new password (all but
the session that changed it), a new role or deactivation by an admin. Members list and end their own."""

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from fastapi.concurrency import run_in_threadpool
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from backend import models, throttle
from backend.errors import Conflict, Forbidden, NotFound
from backend.schemas import MemberCreate, MemberUpdate, MeUpdate
from backend.security import (
    HashingBusy,
    hash_password,
    new_token,
    signed_in_cache,
    token_digest,
    verify_password,
    verify_password_waiting,
)
from backend.settings import Settings


def create_household(session: Session, name: str) -> models.Household:
    household = models.Household(name=name)
    session.add(household)
    session.flush()
    return household


def create_user(session: Session, household_id: int, body: MemberCreate) -> models.User:
    if session.scalar(select(models.User.id).where(models.User.username == body.username)) is not None:
        raise Conflict(f"the username {body.username!r} is taken; choose another")
    user = models.User(
        household_id=household_id,
        username=body.username,
        display_name=body.display_name,
        password_hash=hash_password(body.password),
        role=body.role,
    )
    session.add(user)
    session.flush()
    return user


@dataclass(frozen=True)
class Client:
    """Where a sign-in comes from: the throttle counts per address, the session list shows both."""

    address: str
    user_agent: str | None = None


def _find_user(session: Session, username: str) -> models.User | None:
    return session.scalar(select(models.User).where(models.User.username == username.strip().lower()))


async def authenticate(
    session: Session, settings: Settings, username: str, password: str, client: Client
) -> models.User | None:
    """The active member with this username and password, or None; `throttle.Throttled` while the account
    or the address has had too many wrong passwords, `security.HashingBusy` when too many sign-ins wait."""
    attempt, user = await run_in_threadpool(_count_and_find, session, settings, username, client.address)
    try:
        right = await verify_password_waiting(password, user.password_hash if user else None)
    except HashingBusy:
        await run_in_threadpool(throttle.forgive, attempt)  # never checked: not a wrong password
        raise
    if not right or user is None or not user.is_active:
        return None
    await run_in_threadpool(throttle.forgive, attempt)
    return user


def _count_and_find(
    session: Session, settings: Settings, username: str, address: str
) -> tuple[throttle.Attempt, models.User | None]:
    return throttle.begin(session, settings, username, address), _find_user(session, username)


def open_session(
    session: Session, user: models.User, kind: str, settings: Settings, client: Client
) -> tuple[str, models.AuthSession]:
    token = new_token()
    now = datetime.now(UTC)
    auth_session = models.AuthSession(
        user_id=user.id,
        token_hash=token_digest(token, settings.secret_key),
        csrf_token=new_token(),
        kind=kind,
        created_at=now,
        expires_at=now + timedelta(hours=settings.session_ttl_hours),
        user_agent=(client.user_agent or "")[:200] or None,
        client_address=client.address[:64],
    )
    session.add(auth_session)
    # Expired sessions of this user are dropped here rather than by a separate job.
    session.execute(
        delete(models.AuthSession).where(
            models.AuthSession.user_id == user.id, models.AuthSession.expires_at < now
        )
    )
    session.commit()
    return token, auth_session


def close_session(session: Session, auth_session: models.AuthSession) -> None:
    session.delete(auth_session)
    session.commit()
    signed_in_cache.forget(auth_session_id=auth_session.id)


def list_sessions(session: Session, user_id: int) -> list[models.AuthSession]:
    return list(
        session.scalars(
            select(models.AuthSession)
            .where(models.AuthSession.user_id == user_id, models.AuthSession.expires_at > datetime.now(UTC))
            .order_by(models.AuthSession.id)
        )
    )


def own_session(session: Session, user_id: int, session_id: int) -> models.AuthSession:
    auth_session = session.get(models.AuthSession, session_id)
    if auth_session is None or auth_session.user_id != user_id:
        raise NotFound("session", session_id)
    return auth_session


def _end_sessions(session: Session, user_id: int, keep: int | None = None) -> None:
    """Deletes a member's sessions but `keep`; the caller commits, then forgets the member's cached ones."""
    ended = delete(models.AuthSession).where(models.AuthSession.user_id == user_id)
    if keep is not None:
        ended = ended.where(models.AuthSession.id != keep)
    session.execute(ended)


def end_other_sessions(session: Session, user_id: int, current_session_id: int) -> None:
    _end_sessions(session, user_id, keep=current_session_id)
    session.commit()
    signed_in_cache.forget(user_id=user_id)


def list_members(session: Session, household_id: int) -> list[models.User]:
    return list(
        session.scalars(
            select(models.User).where(models.User.household_id == household_id).order_by(models.User.id)
        )
    )


def get_member(session: Session, household_id: int, user_id: int) -> models.User:
    user = session.get(models.User, user_id)
    if user is None or user.household_id != household_id:
        raise NotFound("member", user_id)
    return user


def _active_admins(session: Session, household_id: int) -> int:
    return (
        session.scalar(
            select(func.count())
            .select_from(models.User)
            .where(
                models.User.household_id == household_id,
                models.User.role == models.Role.ADMIN,
                models.User.is_active.is_(True),
            )
        )
        or 0
    )


def update_member(
    session: Session, member: models.User, body: MemberUpdate, admin_session_id: int
) -> models.User:
    losing_admin = member.is_admin and (
        (body.role is not None and body.role != models.Role.ADMIN) or body.is_active is False
    )
    if losing_admin and _active_admins(session, member.household_id) <= 1:
        raise Conflict("a household needs at least one active admin: make someone else admin first")
    if body.display_name is not None:
        member.display_name = body.display_name
    new_role = body.role is not None and body.role != member.role
    if body.role is not None:
        member.role = body.role
    if body.password is not None:
        member.password_hash = hash_password(body.password)
    if body.is_active is not None:
        member.is_active = body.is_active
    if body.password is not None or body.is_active is False or new_role:
        _end_sessions(session, member.id, keep=admin_session_id)  # an admin changing their own role stays
    session.commit()
    signed_in_cache.forget(user_id=member.id)
    return member


def update_me(
    session: Session, user: models.User, body: MeUpdate, settings: Settings, current: models.AuthSession
) -> models.User:
    """A new password ends every other session of the member; the one that changed it stays signed in."""
    if body.new_password is not None:
        _check_current_password(session, settings, user, body.current_password or "", current)
        user.password_hash = hash_password(body.new_password)
        _end_sessions(session, user.id, keep=current.id)
    if body.display_name is not None:
        user.display_name = body.display_name
    session.commit()
    signed_in_cache.forget(user_id=user.id)
    return user


def _check_current_password(
    session: Session, settings: Settings, user: models.User, password: str, current: models.AuthSession
) -> None:
    """Wrong current passwords count like wrong sign-ins: a stolen session must not be a way to guess."""
    attempt = throttle.begin(session, settings, user.username, current.client_address or "unknown")
    if not verify_password(password, user.password_hash):
        raise Forbidden("the current password is wrong; to change your password, give the current one")
    throttle.forgive(attempt)
