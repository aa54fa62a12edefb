"""`varbot up` starts the whole product (Redis, migrations, API, a training and a robot worker; no scene,
which the API starts when a member opens one), keeps it alive when one part dies (the part comes back, the API
answers meanwhile) and Ctrl-C stops all of it: no process left behind, Redis's data saved.

The tests share one `varbot up` (starting it takes a while); the Ctrl-C test comes last and stops it."""

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from conftest import PASSWORD, wait_until

from varbot.launched import LaunchedUp, alive
from varbot.services import Service, Stack
from varbot.supervisor import STABLE_AFTER_S, Supervisor

pytestmark = pytest.mark.slow
RESTART_DELAY_S = 5  # long enough to see the API answer while a part is away


@pytest.fixture(scope="module")
def up() -> Iterator[LaunchedUp]:
    root = Path(tempfile.mkdtemp(prefix="vbu-"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")}
    env.update(
        VARBOT_DATA_DIR=str(root / "data"),
        VARBOT_ENVIRONMENT="development",
        VARBOT_UP_RESTART_DELAY_S=str(RESTART_DELAY_S),
        VARBOT_ADMIN_PASSWORD=PASSWORD,
        PYTHONUNBUFFERED="1",
    )
    running = LaunchedUp.start(root / "up.log", env, timeout=180)
    try:
        admin = ["admin", "create", "--username", "alice", "--household", "home"]
        subprocess.run([sys.executable, "-m", "varbot.cli", *admin], env=env, check=True, capture_output=True)
        yield running
    finally:
        leftovers = running.children() if running.process.poll() is None else []
        with contextlib.suppress(subprocess.TimeoutExpired):
            running.interrupt(timeout=90)
        for child in leftovers:
            if alive(child):
                child.kill()


def signed_in(url: str) -> httpx.Client:
    client = httpx.Client(base_url=f"{url}/api/v1", timeout=30)
    token = client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
    assert token.status_code == 200, token.text
    client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
    return client


def test_a_killed_worker_and_redis_are_restarted_while_the_api_and_the_rest_go_on(up: LaunchedUp) -> None:
    alice = signed_in(up.url)
    robot = alice.post("/robots", json={"name": "arm", "kind": "kuka-sim"}).json()["id"]
    steady = {name: up.child(name).pid for name in ("varbot.cli api", "--queue robot")}
    training = up.child("--queue training")

    training.kill()
    up.child("redis-server").kill()
    for name in ("worker-training", "redis"):
        wait_until(
            lambda said=f"{name} stopped unexpectedly": up.said(said), 30, f"the launcher to see {name} die"
        )
    assert alice.get("/robots").status_code == 200, "what needs neither still works"
    health = alice.get("/health")
    assert health.status_code == 503 and health.json()["broker"].startswith("unreachable"), health.text
    capture = alice.post(f"/robots/{robot}/snapshots:capture", json={"count": 2})
    assert capture.status_code == 503, capture.text
    assert "the task queue (Redis) is not reachable" in capture.json()["detail"]
    assert not up.said("redis is back"), "Redis was back before the API was asked; raise RESTART_DELAY_S"

    for name in ("redis", "worker-training"):
        wait_until(lambda said=f"{name} is back": up.said(said), 180, f"{name} to come back")
    assert up.child("--queue training").pid != training.pid
    assert (data_dir(up) / "run" / "worker-training.ready").is_file()
    wait_until(lambda: alice.get("/health").status_code == 200, 30, "/health to say ok again")
    assert alice.post(f"/robots/{robot}/snapshots:capture", json={"count": 2}).status_code == 202
    assert {name: up.child(name).pid for name in steady} == steady, "nothing else was restarted"
    alice.close()


def test_a_part_that_keeps_dying_is_restarted_after_pauses_that_double_until_it_stays_up(
    tmp_path: Path,
) -> None:
    said: list[str] = []
    stack = Stack(tmp_path, dict(os.environ))
    dying = Service("dying", [sys.executable, "-c", "raise SystemExit(3)"], is_ready=lambda: True)
    stack.services.append(dying)
    dying.start(tmp_path, stack.env)
    supervisor = Supervisor(stack, say=said.append)
    now = time.monotonic()
    for restart, pause_s in enumerate((1, 2, 4, 8, 1), start=1):
        if restart == 5:
            now += STABLE_AFTER_S  # it ran a minute before this death: the first pause again
        assert dying.process is not None
        dying.process.wait(30)
        supervisor.tick(now)
        assert said[-1].startswith(f"dying stopped unexpectedly (exit code 3); restarting it in {pause_s} s")
        supervisor.tick(now + pause_s - 0.1)
        assert not dying.running and len(said) == 2 * restart - 1, "restarted before its pause was over"
        now += pause_s
        supervisor.tick(now)
        assert said[-1] == f"dying restarted (restart {restart})"


def test_ctrl_c_stops_every_child_and_saves_redis(up: LaunchedUp) -> None:
    health = httpx.get(f"{up.url}/api/v1/health", timeout=5)
    assert health.status_code == 200 and health.json()["broker"] == "ok"
    assert "admin create" in up.output()
    children = up.children()
    for part in ("redis-server", "varbot.cli api", "--queue training", "--queue robot"):
        assert up.child(part)
    assert not [c for c in children if "scene" in c.cmdline()], "no scene runs until a member opens one"

    assert up.interrupt(timeout=90) == 0, up.output()
    wait_until(lambda: not any(alive(c) for c in children), 10, "every child of `varbot up` to exit")
    assert (data_dir(up) / "redis" / "redis.rdb").is_file(), "Redis saved its data on the way out"
    assert "stopped." in up.output()


def data_dir(up: LaunchedUp) -> Path:
    return up.log.parent / "data"
