"""Password guessing against the real API: how many guesses get through per minute, the API process's memory,
and how long another member waits for GET /labels/next meanwhile.

Starts Redis, a migrated SQLite database and one uvicorn process on 127.0.0.1 (varbot/services.py) with the
production Argon2 cost (64 MiB, 3 passes), seeds a household, then runs each scenario for `--seconds`:

- `idle`: nobody guesses (the baseline);
- `one-address`: 40 clients guess one member's password from one address;
- `rotating`: 40 clients guess, each attempt from a new address (X-Forwarded-For, which uvicorn trusts from
  127.0.0.1 as it would from a reverse proxy) at a new username: what the throttle cannot stop, so only the
  hashing bound and the waiting room keep memory and the other member's latency in check.

"Through" counts the guesses whose password was checked (401); 429 is the throttle, 503 the full waiting room.
The other member's requests come from a process of their own (the guessers' event loop would delay them).
Writes bench/results/login_throttle.json with the machine and /proc/loadavg before and after.

    nice -n 10 .venv/bin/python bench/login_throttle.py [--seconds 30] [--clients 40] [--set KEY=VALUE ...]
"""

import argparse
import asyncio
import contextlib
import itertools
import multiprocessing
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from multiprocessing.pool import Pool
from pathlib import Path

import httpx
from api_load import PASSWORD, ServerWatch, percentiles, start_api, token, upload_views, wav_bytes
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "login_throttle.json"
SCENARIOS = ("idle", "one-address", "rotating")
console = Console(width=150)


def create_admin(env: dict[str, str], username: str) -> None:
    code = (
        "from backend.cli import create_admin; "
        f"create_admin(username={username!r}, household='home', display_name=None, password={PASSWORD!r})"
    )
    subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, cwd=ROOT)


async def seed(base: str, env: dict[str, str]) -> dict[str, str]:
    """A household with a robot, camera views and commands; returns the bystander's bearer headers."""
    create_admin(env, "alice")
    async with httpx.AsyncClient(base_url=base, timeout=120) as client:
        alice = await token(client, "alice")
        robot = (
            await client.post("/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers=alice)
        ).json()
        await upload_views(client, alice, robot["id"], list(range(200)))
        for k, word in enumerate(("zero", "one", "two", "three")):
            wav = wav_bytes(1.0, 16_000, 300 + 100 * k)
            await client.post(
                "/api/v1/clips",
                headers=alice,
                data={"name": word},
                files={"file": ("c.wav", wav, "audio/wav")},
            )
        member = {"username": "bob", "display_name": "Bob", "password": PASSWORD}
        (await client.post("/api/v1/members", headers=alice, json=member)).raise_for_status()
        return await token(client, "bob")


async def bystander(base: str, headers: dict[str, str], deadline: float) -> list[float]:
    """Another member asking for the next pair to label, again and again (no answer sent: the pair stays)."""
    latencies = []
    async with httpx.AsyncClient(base_url=base, headers=headers, timeout=60) as client:
        while time.monotonic() < deadline:
            start = time.perf_counter()
            (await client.get("/api/v1/labels/next")).raise_for_status()
            latencies.append(time.perf_counter() - start)
            await asyncio.sleep(0.05)
    return latencies


def bystander_process(base: str, headers: dict[str, str], deadline: float) -> list[float]:
    return asyncio.run(bystander(base, headers, deadline))


async def guesser(base: str, scenario: str, number: int, deadline: float, outcomes: Counter) -> None:
    addresses = (f"10.{number}.{n // 250}.{n % 250 + 1}" for n in itertools.count())
    async with httpx.AsyncClient(base_url=base, timeout=120) as client:
        for attempt in itertools.count():
            if time.monotonic() >= deadline:
                return
            if scenario == "one-address":
                username, headers = "alice", {}
            else:
                username, headers = f"guess{number}x{attempt}", {"X-Forwarded-For": next(addresses)}
            body = {"username": username, "password": f"wrong {attempt}"}
            try:
                response = await client.post("/api/v1/auth/login", json=body, headers=headers)
                outcomes[str(response.status_code)] += 1
                if response.status_code in (429, 503):
                    await asyncio.sleep(0.05)  # a client that waits a little, not one that spins
            except httpx.HTTPError as exc:
                outcomes[type(exc).__name__] += 1


async def scenario_run(
    pool: Pool, base: str, bob: dict[str, str], scenario: str, clients: int, seconds: float
) -> dict:
    deadline = time.monotonic() + seconds
    outcomes: Counter = Counter()
    # The other member runs in a process of their own, so that the guessers' event loop does not delay them.
    watched = pool.apply_async(bystander_process, (base, bob, deadline))
    if scenario != "idle":
        await asyncio.gather(*(guesser(base, scenario, n, deadline, outcomes) for n in range(clients)))
    latencies = await asyncio.get_running_loop().run_in_executor(None, watched.get)
    return {
        "attempts": sum(outcomes.values()),
        "outcomes": dict(outcomes),
        "through_per_minute": round(outcomes["401"] * 60 / seconds, 1),
        "bystander_requests": len(latencies),
        "bystander_max_ms": round(1000 * max(latencies), 1) if latencies else None,
        **{f"bystander_{key}": value for key, value in percentiles(latencies).items()},
    }


def measure(args: argparse.Namespace) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="vb-bench-login-"))
    with contextlib.ExitStack() as cleanup:
        cleanup.callback(shutil.rmtree, folder, ignore_errors=True)
        settings = dict(setting.split("=", 1) for setting in args.set)
        server, base, env = start_api(cleanup, folder, f"sqlite:///{folder / 'varbot.db'}", settings)
        bob = asyncio.run(seed(base, env))
        pool = cleanup.enter_context(multiprocessing.get_context("fork").Pool(1))
        results = {}
        for scenario in SCENARIOS:
            watch = ServerWatch(server.pid)
            rss_before = watch.rss_mb()
            console.print(f"[bold]{scenario}[/]: {args.seconds:.0f} s …")
            found = asyncio.run(scenario_run(pool, base, bob, scenario, args.clients, args.seconds))
            watch.stop()
            found["server_rss_before_mb"] = round(rss_before, 1)
            found["server_rss_peak_mb"] = round(max(watch.peak_rss_mb, rss_before), 1)
            found["server_rss_growth_mb"] = round(found["server_rss_peak_mb"] - rss_before, 1)
            results[scenario] = found
            time.sleep(2)  # let the last hashes finish before the next baseline
        return results


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=30.0, help="per scenario")
    parser.add_argument("--clients", type=int, default=40, help="guessing clients at once")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an API setting, e.g. VARBOT_PASSWORD_HASH_CONCURRENCY=8",
    )
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args()
    conditions = Conditions()
    results = measure(args)
    record = {
        "scenarios": results,
        "clients": args.clients,
        "seconds_per_scenario": args.seconds,
        "api_settings": args.set,
        "argon2": "64 MiB, 3 passes (production defaults)",
        "command": " ".join(["nice -n 10 .venv/bin/python bench/login_throttle.py", *sys.argv[1:]]),
        **conditions.finish(),
    }
    table = Table(
        title=f"Password guessing, {args.clients} clients, one uvicorn process, {args.seconds:.0f} s each"
    )
    for column in ("scenario", "attempts", "through/min", "429", "503", "RSS before MB", "RSS peak MB",
                   "growth MB", "other member p50 ms", "p95 ms", "max ms"):  # fmt: skip
        table.add_column(column, justify="right")
    for scenario, r in results.items():
        table.add_row(
            scenario,
            str(r["attempts"]),
            str(r["through_per_minute"]),
            str(r["outcomes"].get("429", 0)),
            str(r["outcomes"].get("503", 0)),
            str(r["server_rss_before_mb"]),
            str(r["server_rss_peak_mb"]),
            str(r["server_rss_growth_mb"]),
            str(r["bystander_p50_ms"]),
            str(r["bystander_p95_ms"]),
            str(r["bystander_max_ms"]),
        )
    console.print(table)
    console.print(describe(record))
    write_result(args.out, record)
    console.print(f"written to {args.out.relative_to(ROOT) if args.out.is_relative_to(ROOT) else args.out}")


if __name__ == "__main__":
    main()
