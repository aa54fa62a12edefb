"""`varbot up` starts the whole product (Redis, migrations, API, a training and a robot worker) and Ctrl-C
stops all of it: no process left behind, Redis's data saved."""

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import psutil
import pytest
from conftest import free_port, wait_until

pytestmark = pytest.mark.slow


def test_varbot_up_serves_health_and_ctrl_c_stops_every_child_and_saves_redis() -> None:
    root = Path(tempfile.mkdtemp(prefix="vbu-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")}
    env.update(VARBOT_DATA_DIR=str(root / "data"), VARBOT_ENVIRONMENT="development", PYTHONUNBUFFERED="1")
    log = (root / "up.log").open("wb")
    up = subprocess.Popen(
        [sys.executable, "-m", "varbot.cli", "up", "--port", str(port), "--no-demo"],
        env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    try:
        output = lambda: (root / "up.log").read_text(errors="replace")  # noqa: E731
        wait_until(lambda: "varbot is running at" in output() or up.poll() is not None, 180, "varbot up")
        assert up.poll() is None, output()
        assert f"http://127.0.0.1:{port}" in output() and "admin create" in output()
        health = httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=5)
        assert health.status_code == 200 and health.json()["broker"] == "ok"
        children = psutil.Process(up.pid).children(recursive=True)
        names = " ".join(" ".join(c.cmdline()) for c in children)
        assert "redis-server" in names and "api" in names
        assert "--queue training" in names and "--queue robot" in names
        assert (root / "data" / "run" / "worker-training.ready").is_file()

        up.send_signal(signal.SIGINT)  # what Ctrl-C in the terminal does
        assert up.wait(90) == 0, output()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(c) for c in children):
            time.sleep(0.2)
        assert not [c.pid for c in children if _alive(c)], "every child of `varbot up` has exited"
        assert (root / "data" / "redis" / "redis.rdb").is_file(), "Redis saved its data on the way out"
        assert "stopped." in output()
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        for child in psutil.Process().children(recursive=True):
            if "vbu-" in " ".join(_cmdline(child)):
                child.kill()


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
