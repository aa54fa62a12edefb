"""Request and response bodies: separate create / update / public shapes per resource."""

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import Path, Query
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, field_validator

from backend.models import ModelStatus, RobotKind, Role, RunKind, RunStatus, Verdict

MAX_ID = 2**31 - 1  # ids are 32-bit integers on every database
DbId = Annotated[int, Field(ge=1, le=MAX_ID)]
PathId = Annotated[int, Path(ge=1, le=MAX_ID)]
QueryId = Annotated[int | None, Query(ge=1, le=MAX_ID)]
Offset = Annotated[int, Query(ge=0, le=MAX_ID)]
MAX_SEED = 2**31 - 2  # a task may draw from seed + 1 too (attempts' random views): both stay 32-bit
Seed = Annotated[int, Field(ge=0, le=MAX_SEED)]
Username = Annotated[str, StringConstraints(min_length=3, max_length=64, pattern=r"^[a-z0-9][a-z0-9._-]*$")]
Password = Annotated[str, StringConstraints(min_length=8, max_length=256)]
Name = Annotated[str, StringConstraints(min_length=1, max_length=100, strip_whitespace=True)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Vector = Annotated[list[FiniteFloat], Field(min_length=1, max_length=64)]


class Public(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class Message(BaseModel):
    detail: str


class ValidationIssue(BaseModel):
    """One problem found in a malformed request (FastAPI's validation error)."""

    model_config = ConfigDict(extra="allow")
    loc: list[str | int]
    msg: str
    type: str


class Refusal(BaseModel):
    """The body of every 422."""

    detail: str | list[ValidationIssue] = Field(
        description="What to change: a sentence when the request was well formed but refused, or one entry "
        "per field when it was malformed."
    )


# --- accounts -----------------------------------------------------------------------------------------------


class HouseholdPublic(Public):
    id: int
    name: str
    created_at: datetime


class HouseholdUpdate(BaseModel):
    name: Name


class UserPublic(Public):
    id: int
    household_id: int
    username: str
    display_name: str
    role: Role
    is_active: bool
    created_at: datetime


class MemberCreate(BaseModel):
    username: Username
    display_name: Name
    password: Password
    role: Role = Role.MEMBER


class MemberUpdate(BaseModel):
    display_name: Name | None = None
    role: Role | None = None
    password: Password | None = None
    is_active: bool | None = None


class MeUpdate(BaseModel):
    display_name: Name | None = None
    current_password: str | None = Field(default=None, max_length=256)
    new_password: Password | None = None


class LoginRequest(BaseModel):
    username: str = Field(max_length=64)
    password: str = Field(max_length=256)


class LoginResult(BaseModel):
    user: UserPublic
    household: HouseholdPublic
    csrf_token: str = Field(
        description="Send it back as the X-CSRF-Token header on every cookie-authenticated write."
    )
    expires_at: datetime


class TokenResult(BaseModel):
    access_token: str
    token_type: Literal["bearer"] = "bearer"
    expires_at: datetime


class SessionPublic(Public):
    """One of the caller's sessions: a signed-in browser (cookie) or script (bearer token)."""

    id: int
    kind: Literal["cookie", "bearer"]
    created_at: datetime
    expires_at: datetime
    user_agent: str | None
    client_address: str | None
    current: bool = Field(default=False, description="The session this request came with.")


# --- robots -------------------------------------------------------------------------------------------------


class RobotCreate(BaseModel):
    name: Name
    kind: RobotKind
    settings: dict[str, Any] = Field(default_factory=dict)


class RobotUpdate(BaseModel):
    name: Name | None = None
    settings: dict[str, Any] | None = None


class RobotPublic(Public):
    id: int
    name: str
    kind: RobotKind
    settings: dict[str, Any]
    active_model_id: int | None = None
    created_at: datetime


# --- clips and snapshots ------------------------------------------------------------------------------------


class ClipPublic(Public):
    id: int
    speaker_id: int
    name: str | None
    original_filename: str
    original_size: int
    checksum: str = Field(description="sha256 of the uploaded bytes")
    duration_s: float
    sample_rate: int = Field(description="of the upload; the normalised WAV is always 16 kHz mono 16-bit")
    channels: int
    created_at: datetime
    deleted_at: datetime | None


class ClipUpdate(BaseModel):
    name: Name | None


class SnapshotPublic(Public):
    id: int
    robot_id: int
    width: int
    height: int
    state: list[float]
    source: str
    meta: dict[str, Any]
    created_at: datetime
    deleted_at: datetime | None


class CaptureRequest(BaseModel):
    count: int = Field(ge=1, le=500, description="how many views to render from random poses")


class CaptureQueued(BaseModel):
    task_id: str
    robot_id: int
    count: int
    queue: str


# --- labels -------------------------------------------------------------------------------------------------


class LabelCreate(BaseModel):
    snapshot_id: DbId
    clip_id: DbId
    verdict: Verdict


class LabelUpdate(BaseModel):
    verdict: Verdict


class LabelPublic(Public):
    id: int
    snapshot_id: int
    clip_id: int
    verdict: Verdict
    labeller_id: int
    created_at: datetime
    updated_at: datetime
    updated_by_id: int


class LabelEventPublic(Public):
    action: Literal["created", "changed", "deleted"]
    verdict: Verdict | None
    user_id: int
    at: datetime


class LabelDetail(LabelPublic):
    history: list[LabelEventPublic]


class NextPair(BaseModel):
    snapshot: SnapshotPublic | None
    clip: ClipPublic | None
    strategy: Literal["balanced", "informative", "none"]
    informativeness: float | None = Field(
        default=None, description="how close the image sits between two commands (1 = exactly between)"
    )
    message: str


class TripletCount(BaseModel):
    key: str
    name: str
    triplets: int


class TripletStats(BaseModel):
    triplets: int
    with_silence_positive: int
    snapshots_used: int
    labels: int
    per_command: list[TripletCount]
    per_member: list[TripletCount]


# --- runs and models ----------------------------------------------------------------------------------------


class RunParams(BaseModel):
    """Training parameters; a preset fills them, the request may override any of them."""

    model_config = ConfigDict(extra="forbid")

    var_epochs: int = Field(ge=0, le=500)
    var_learning_rate: float = Field(gt=0, le=0.1)
    var_batch_size: int = Field(ge=1, le=1024)
    policy_steps: int = Field(ge=0, le=5_000_000)
    eval_episodes: int = Field(ge=1, le=2000)
    held_out_fraction: float = Field(ge=0.0, le=0.5)
    seed: Seed
    # 0.5, not 0.25: on three label sets it kept the training room where 0.25 lost 6.5 to 16 points (README)
    replay_fraction: float = Field(
        default=0.5,
        ge=0.0,
        le=0.9,
        description="share of the VAR fine-tune's training triplets replayed from the simulated training "
        "room with the base corpus's clips, so that it keeps what it knew (0: none)",
    )
    replay_block_ends_share: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="in a world with blocks, share of the replayed training-room views with the gripper "
        "placed around a block's end, labelled by the simulator (what `varbot models block-ends` teaches a "
        "base), so that the fine-tune keeps where a block ends (0: random views only)",
    )
    var_keep_view: float = Field(
        default=0.0,
        ge=0.0,
        le=100.0,
        description="weight of a loss that keeps the hidden layer of the VAR fine-tune's replayed "
        "training-room views where the VAR it started from had it (what a policy that sees through the VAR "
        "reads; 0: off)",
    )
    policy_replay_share: float = Field(
        default=0.25,
        ge=0.0,
        le=0.5,
        description="share of the policy self-improvement's simulated environments that keep practising in "
        "the base model's rooms instead of the robot's own, so that it keeps what it knew there (0: none)",
    )
    policy_learning_rate_scale: float = Field(
        default=1 / 3,
        gt=0.0,
        le=3.0,
        description="the policy self-improvement's learning rate as a multiple of the base model's (a "
        "fine-tune of a household's own version keeps that version's rate)",
    )
    finetune_from_unadapted: bool = Field(
        default=True,
        description="a robot whose model was adapted to its room (Adapt to this room) fine-tunes the version "
        "the adaptation started from, whose batch norms then learn the room from the household's own views "
        "(default); false: it fine-tunes the adapted version with the room's statistics kept",
    )
    policy_selection_episodes: int = Field(
        default=0,
        ge=0,
        le=400,
        description="validation episodes per room on which the policy self-improvement's checkpoints (every "
        "25 updates, and the policy it started from) are scored in the robot's room and the simulator's "
        "training room; the best in the robot's room that kept the training room becomes the candidate "
        "(0: the last update's policy, unscored)",
    )
    policy_view_follows_var: bool = Field(
        default=True,
        description="for a policy that sees through the VAR: during its self-improvement it sees through "
        "the household's fine-tuned VAR (default) instead of the copy of the base VAR it was trained with "
        "(false); a policy with its own image encoder is unaffected",
    )


class PresetPublic(RunParams):
    """A preset's parameters and its budget in minutes on the machine it was measured on."""

    minutes_here: float = Field(
        description="about how many minutes a fine-tune with these parameters takes on a 2-core CPU with "
        "`budget_triplets` household triplets (VAR fine-tune, policy self-improvement and evaluation)"
    )
    budget_triplets: int = Field(description="the household triplets the budget is for")
    measured_by: str = Field(description="the bench result the per-part costs come from")


Preset = Literal["quick", "standard", "thorough"]


class RunCreate(BaseModel):
    robot_id: DbId
    kind: RunKind
    preset: Preset = "quick"
    params: dict[str, Any] = Field(default_factory=dict, description="overrides of the preset's RunParams")


class RunPublic(Public):
    id: int
    robot_id: int
    kind: RunKind
    preset: str
    params: dict[str, Any]
    status: RunStatus
    stage: str
    progress: float
    metrics: dict[str, Any]
    timings: dict[str, Any]
    checkpoints: list[str]
    error: str | None
    requested_by_id: int
    task_id: str
    cancel_requested: bool
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class ModelVersionPublic(Public):
    id: int
    robot_id: int
    parent_id: int | None
    run_id: int | None
    status: ModelStatus
    has_var: bool
    has_policy: bool
    metrics: dict[str, Any]
    notes: str | None
    previous_active_id: int | None
    created_at: datetime
    activated_at: datetime | None


class EmbeddingsPublic(BaseModel):
    model_version_id: int
    snapshots: dict[int, list[float]]
    clips: dict[int, list[float]]


class EmbeddingsUpdate(BaseModel):
    snapshots: dict[DbId, Vector] = Field(default_factory=dict)
    clips: dict[DbId, Vector] = Field(default_factory=dict)

    @field_validator("snapshots", "clips")
    @classmethod
    def _bounded(cls, value: dict[int, list[float]]) -> dict[int, list[float]]:
        if len(value) > 100_000:
            raise ValueError("at most 100000 embeddings per request")
        return value


# --- health -------------------------------------------------------------------------------------------------


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    database: str
    broker: str
