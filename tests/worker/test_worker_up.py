"""`varbot up` starts the whole product (Redis, migrations, API, a training and a robot worker, the scene),
keeps it alive when one part dies (the part comes back, the API answers meanwhile) and Ctrl-C stops all of
it: no process left behind, Redis's data saved.

The tests share one `varbot up` (starting it takes a while); the Ctrl-C test comes last and stops it."""

import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import psutil
import pytest
from conftest import PASSWORD, free_port, wait_until

pytestmark = pytest.mark.slow
RESTART_DELAY_S = 5  # long enough to see the API answer while a part is away


@dataclass
class Up:
    process: subprocess.Popen[bytes]
    root: Path
    url: str

    def output(self) -> str:
        return (self.root / "up.log").read_text(errors="replace")

    def child(self, fragment: str) -> psutil.Process:
        """The one direct child of `varbot up` whose command line contains `fragment`."""
        found = [c for c in psutil.Process(self.process.pid).children() if fragment in " ".join(_cmdline(c))]
        assert len(found) == 1, f"{fragment!r}: {[_cmdline(c) for c in found]}"
        return found[0]

    def said(self, text: str) -> bool:
        assert self.process.poll() is None, f"varbot up exited:\n{self.output()}"
        return text in self.output()


@pytest.fixture(scope="module")
def up() -> Iterator[Up]:
    root = Path(tempfile.mkdtemp(prefix="vbu-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")}
    env.update(
        VARBOT_DATA_DIR=str(root / "data"),
        VARBOT_ENVIRONMENT="development",
        VARBOT_UP_RESTART_DELAY_S=str(RESTART_DELAY_S),
        VARBOT_ADMIN_PASSWORD=PASSWORD,
        PYTHONUNBUFFERED="1",
    )
    with (root / "up.log").open("wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "varbot.cli", "up", "--port", str(port), "--no-demo"],
            env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
    running = Up(process, root, f"http://127.0.0.1:{port}")
    try:
        wait_until(lambda: running.said("varbot is running at"), 180, "varbot up")
        admin = ["admin", "create", "--username", "alice", "--household", "home"]
        subprocess.run([sys.executable, "-m", "varbot.cli", *admin], env=env, check=True, capture_output=True)
        yield running
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGINT)
            process.wait(90)
        for child in psutil.Process().children(recursive=True):
            if "vbu-" in " ".join(_cmdline(child)):
                child.kill()


def signed_in(url: str) -> httpx.Client:
    client = httpx.Client(base_url=f"{url}/api/v1", timeout=30)
    token = client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
    assert token.status_code == 200, token.text
    client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
    return client


def test_a_killed_worker_or_redis_is_restarted_while_the_api_and_the_other_parts_go_on(up: Up) -> None:
    alice = signed_in(up.url)
    robot = alice.post("/robots", json={"name": "arm", "kind": "kuka-sim"}).json()["id"]
    steady = {name: up.child(name).pid for name in ("varbot.cli api", "--queue robot", "varbot.cli scene")}

    training = up.child("--queue training")
    training.kill()
    wait_until(lambda: up.said("worker-training stopped unexpectedly"), 30, "the launcher to see the death")
    assert alice.get("/robots").status_code == 200, "the API answers while the worker is away"
    wait_until(lambda: up.said("worker-training is back"), 180, "the training worker to come back")
    assert up.child("--queue training").pid != training.pid
    assert (up.root / "data" / "run" / "worker-training.ready").is_file()

    up.child("redis-server").kill()
    wait_until(lambda: up.said("redis stopped unexpectedly"), 30, "the launcher to see Redis die")
    health = alice.get("/health")
    assert health.status_code == 503 and health.json()["broker"].startswith("unreachable"), health.text
    capture = alice.post(f"/robots/{robot}/snapshots:capture", json={"count": 2})
    assert capture.status_code == 503, capture.text
    assert "the task queue (Redis) is not reachable" in capture.json()["detail"]
    assert alice.get("/robots").status_code == 200, "what needs no Redis still works"
    assert not up.said("redis is back"), "Redis was back before the API was asked; raise RESTART_DELAY_S"
    wait_until(lambda: up.said("redis is back"), 60, "Redis to come back")
    wait_until(lambda: alice.get("/health").status_code == 200, 30, "/health to say ok again")
    assert alice.post(f"/robots/{robot}/snapshots:capture", json={"count": 2}).status_code == 202
    assert {name: up.child(name).pid for name in steady} == steady, "nothing else was restarted"
    alice.close()


def test_ctrl_c_stops_every_child_and_saves_redis(up: Up) -> None:
    health = httpx.get(f"{up.url}/api/v1/health", timeout=5)
    assert health.status_code == 200 and health.json()["broker"] == "ok"
    assert "admin create" in up.output()
    children = psutil.Process(up.process.pid).children(recursive=True)
    names = " ".join(" ".join(_cmdline(c)) for c in children)
    assert "redis-server" in names and "api" in names
    assert "--queue training" in names and "--queue robot" in names

    os.killpg(up.process.pid, signal.SIGINT)  # what Ctrl-C in the terminal does
    assert up.process.wait(90) == 0, up.output()
    wait_until(lambda: not any(_alive(c) for c in children), 10, "every child of `varbot up` to exit")
    assert (up.root / "data" / "redis" / "redis.rdb").is_file(), "Redis saved its data on the way out"
    assert "stopped." in up.output()


def _alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _cmdline(process: psutil.Process) -> list[str]:
    try:
        return process.cmdline()
    except psutil.Error:
        return []
