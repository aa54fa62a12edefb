"""Households, members and sign-in sessions."""

from datetime import UTC, datetime, timedelta

from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from backend import models
from backend.errors import Conflict, Forbidden, NotFound
from backend.schemas import MemberCreate, MemberUpdate, MeUpdate
from backend.security import hash_password, new_token, signed_in_cache, token_digest, verify_password


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


def authenticate(session: Session, username: str, password: str) -> models.User | None:
    user = session.scalar(select(models.User).where(models.User.username == username.strip().lower()))
    if not verify_password(password, user.password_hash if user else None) or user is None:
        return None
    return user if user.is_active else None


def open_session(
    session: Session, user: models.User, kind: str, secret_key: str, ttl_hours: int
) -> tuple[str, models.AuthSession]:
    token = new_token()
    now = datetime.now(UTC)
    auth_session = models.AuthSession(
        user_id=user.id,
        token_hash=token_digest(token, secret_key),
        csrf_token=new_token(),
        kind=kind,
        created_at=now,
        expires_at=now + timedelta(hours=ttl_hours),
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


def update_member(session: Session, member: models.User, body: MemberUpdate) -> models.User:
    losing_admin = member.is_admin and (
        (body.role is not None and body.role != models.Role.ADMIN) or body.is_active is False
    )
    if losing_admin and _active_admins(session, member.household_id) <= 1:
        raise Conflict("a household needs at least one active admin: make someone else admin first")
    if body.display_name is not None:
        member.display_name = body.display_name
    if body.role is not None:
        member.role = body.role
    if body.password is not None:
        member.password_hash = hash_password(body.password)
    if body.is_active is not None:
        member.is_active = body.is_active
    if body.password is not None or body.is_active is False:
        session.execute(delete(models.AuthSession).where(models.AuthSession.user_id == member.id))
    session.commit()
    signed_in_cache.forget(user_id=member.id)  # a new role, or no more sessions
    return member


def update_me(session: Session, user: models.User, body: MeUpdate) -> models.User:
    if body.new_password is not None:
        if not body.current_password or not verify_password(body.current_password, user.password_hash):
            raise Forbidden("the current password is wrong; to change your password, give the current one")
        user.password_hash = hash_password(body.new_password)
    if body.display_name is not None:
        user.display_name = body.display_name
    session.commit()
    return user
