"""What an idle product costs with and without scenes that stop by themselves. A real stack (Redis, the API,
one household with a simulated Kuka) in a fresh data directory, measured with psutil over `--window-s` seconds
each (CPU seconds of every product process, in cores):

- always on: the household's scene started as before issue 20 (`varbot scene --household <id>`, running
  until stopped), nobody watching;
- on demand: the scene started by the API when a member asks for it (GET /scene/status), watched for a few
  seconds through the app's proxy, then left alone: it stops after `--idle-stop-s`, and the window is
  measured once it has.

Writes bench/results/scene_idle.json with the load average before/after.

    nice -n 10 .venv/bin/python bench/scene_idle.py [--window-s 60] [--idle-stop-s 10]
"""

import argparse
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
import psutil
import viser
import websockets.sync.client
from conditions import Conditions, describe
from result_files import write_result

from varbot import services
from varbot.services import api_service, api_url, free_port, redis_service, stack_environment, varbot_argv

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "scene_idle.json"
PASSWORD = "scene idle bench password"


def product_cpu_seconds(roots: list[psutil.Process]) -> dict[int, float]:
    """CPU seconds (user + system) so far of `roots` and all their children, by pid."""
    seconds: dict[int, float] = {}
    for root in roots:
        for process in [root, *root.children(recursive=True)]:
            try:
                times = process.cpu_times()
                seconds[process.pid] = times.user + times.system
            except psutil.NoSuchProcess:
                pass
    return seconds


def cores_over(roots: list[psutil.Process], window_s: float) -> float:
    """Cores used over the window by the processes that ran at its end (one that ended in it is left out,
    so the figure is at most an underestimate by what such a process used)."""
    start = product_cpu_seconds(roots)
    time.sleep(window_s)
    end = product_cpu_seconds(roots)
    return round(sum(used - start.get(pid, 0.0) for pid, used in end.items()) / window_s, 4)


def gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def measure(window_s: float, idle_stop_s: float) -> dict[str, object]:
    data_dir = Path(tempfile.mkdtemp(prefix="vb-scene-idle-"))
    sock, port = data_dir / "redis.sock", free_port()
    env = stack_environment(
        data_dir,
        sock,
        VARBOT_SECRET_KEY="scene-idle-bench-secret-key-not-for-production",
        VARBOT_ADMIN_PASSWORD=PASSWORD,
        VARBOT_SCENE_IDLE_STOP_S=str(idle_stop_s),
    )
    url = api_url("127.0.0.1", port)
    try:
        with services.Stack(data_dir, env) as running:
            redis = running.start(redis_service(sock, persist=False))
            running.migrate(quiet=True)
            admin = ("--username", "alice", "--household", "home")
            created = subprocess.run(
                varbot_argv("admin", "create", *admin), env=env, capture_output=True, text=True
            )
            household = int(created.stdout.rsplit("(id ", 1)[1].split(")")[0])
            api = running.start(api_service("127.0.0.1", port, quiet=True))
            token = httpx.post(f"{url}/api/v1/auth/token", data={"username": "alice", "password": PASSWORD})
            member = {"Authorization": f"Bearer {token.json()['access_token']}"}
            httpx.post(f"{url}/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers=member)
            roots = [psutil.Process(s.process.pid) for s in (redis, api) if s.process is not None]

            always_on = running.start(
                services.Service(
                    "scene-always-on",
                    varbot_argv("scene", "--household", str(household)),
                    is_ready=(data_dir / "scene" / f"household-{household}.json").exists,
                )
            )
            time.sleep(10)  # past the first sphere and world
            scene = psutil.Process(always_on.process.pid)  # type: ignore[union-attr]
            before = cores_over([*roots, scene], window_s)
            always_on.stop()

            services.wait_until(
                lambda: httpx.get(f"{url}/scene/status", headers=member, timeout=30).json()["available"],
                180,
                "the scene to start on demand",
            )
            on_demand = json.loads((data_dir / "scene" / f"household-{household}.json").read_text())["pid"]
            ws = url.replace("http://", "ws://") + "/scene/viser"
            with websockets.sync.client.connect(
                ws, subprotocols=[f"viser-v{viser.__version__}"], additional_headers=member, open_timeout=30
            ) as viewer:
                viewer.recv(timeout=30)
                time.sleep(5)
            services.wait_until(lambda: gone(on_demand), idle_stop_s + 60, "the unwatched scene to stop")
            after = cores_over(roots, window_s)
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)
    return {
        "window_s": window_s,
        "idle_stop_s": idle_stop_s,
        "idle_cores_scene_always_on": before,
        "idle_cores_scene_on_demand_after_idle_stop": after,
        "what": "CPU of Redis + the API (+ the scene while it runs) with nobody watching, in cores",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window-s", type=float, default=60.0)
    parser.add_argument("--idle-stop-s", type=float, default=10.0)
    args = parser.parse_args()
    conditions = Conditions()
    result = measure(args.window_s, args.idle_stop_s)
    result |= conditions.finish()
    write_result(RESULT, result)
    for key, cores in result.items():
        if key.startswith("idle_cores"):
            print(f"{key.removeprefix('idle_cores_').replace('_', ' '):<40} {cores:.4f} cores")
    print(describe(result))


if __name__ == "__main__":
    main()
