"""Helpers of the scene tests (a module of its own: test modules import it by name, as tests/backend does)."""

import time
from dataclasses import dataclass


@dataclass
class SceneHousehold:
    household_id: int
    robot_id: int


def clear_backend_caches() -> None:
    from backend.deps import forget_cached_settings

    forget_cached_settings()


def eventually(condition, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out after {timeout:.0f} s waiting for {what}"
        time.sleep(0.05)


def untrained_model_bytes() -> tuple[bytes, bytes]:
    """A real (untrained) VAR and policy as checkpoint bytes, the way a worker stores them: enough for the
    scene to place points on the sphere and drive the robot; what they learned is not under test."""
    import io
    import tempfile
    from pathlib import Path

    import torch

    from learning.rl.policy import Policy, PolicyConfig
    from learning.rl.ppo import CHECKPOINT_KIND
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig

    torch.manual_seed(0)
    with tempfile.TemporaryDirectory() as folder:
        var = save_var(VAR(VARConfig()), Path(folder) / "var.pt").read_bytes()
    policy = Policy(PolicyConfig(image_size=96, state_dim=2))
    buffer = io.BytesIO()
    torch.save(
        {"kind": CHECKPOINT_KIND, "policy_config": policy.config.to_dict(), "policy": policy.state_dict()},
        buffer,
    )
    return var, buffer.getvalue()


def activate_untrained_model(robot_id: int, model: tuple[bytes, bytes] | None = None) -> int:
    """Stores and activates an untrained model (`model`'s VAR and policy bytes, made here by default) for the
    robot, as a worker's promotion does; its id."""
    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services import model_versions

    var, policy = model or untrained_model_bytes()
    store = get_blob_store()
    with get_session_factory()() as session:
        robot = session.get_one(models.Robot, robot_id)
        version = model_versions.create_version(
            session, robot, var_key=store.put(var), policy_key=store.put(policy), notes="untrained"
        )
        model_versions.activate(session, version)
        return version.id


def add_named_clip(household_id: int, name: str, wav: bytes) -> int:
    """A recording of the household's command `name`, stored as an upload stores it."""
    from sqlalchemy import select

    from backend import models
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services.clips import create_clip
    from backend.settings import get_settings

    with get_session_factory()() as session:
        speaker = session.scalar(select(models.User).where(models.User.household_id == household_id))
        if speaker is None:
            speaker = models.User(
                household_id=household_id,
                username=f"speaker{household_id}",
                display_name="Sam",
                password_hash="-",
            )
            session.add(speaker)
            session.commit()
        clip = create_clip(session, get_blob_store(), get_settings(), speaker, "command.wav", wav, name)
        return clip.id
