from fastapi import APIRouter, status

from backend import schemas
from backend.api.responses import errors
from backend.deps import AdminDep, CallerDep, SessionDep
from backend.schemas import PathId
from backend.services import accounts

router = APIRouter(tags=["household"])


@router.get("/household", response_model=schemas.HouseholdPublic)
def household(caller: CallerDep):  # type: ignore[no-untyped-def]
    return caller.user.household


@router.patch("/household", response_model=schemas.HouseholdPublic)
def rename_household(body: schemas.HouseholdUpdate, caller: AdminDep, session: SessionDep):  # type: ignore[no-untyped-def]
    household = caller.user.household
    household.name = body.name
    session.commit()
    return household


@router.get("/members", response_model=list[schemas.UserPublic])
def members(caller: CallerDep, session: SessionDep):  # type: ignore[no-untyped-def]
    return accounts.list_members(session, caller.household_id)


@router.post(
    "/members", response_model=schemas.UserPublic, status_code=status.HTTP_201_CREATED, responses=errors(409)
)
def add_member(body: schemas.MemberCreate, caller: AdminDep, session: SessionDep):  # type: ignore[no-untyped-def]
    user = accounts.create_user(session, caller.household_id, body)
    session.commit()
    return user


@router.patch("/members/{member_id}", response_model=schemas.UserPublic, responses=errors(409))
def update_member(member_id: PathId, body: schemas.MemberUpdate, caller: AdminDep, session: SessionDep):  # type: ignore[no-untyped-def]
    member = accounts.get_member(session, caller.household_id, member_id)
    return accounts.update_member(session, member, body, caller.signed_in.auth_session_id)
