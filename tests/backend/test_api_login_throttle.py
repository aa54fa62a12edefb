"""Guessing passwords is throttled per account and per client address (429 with Retry-After, before any hash
is computed), in Redis or, without it, in the database, across API processes; the owner's right password
works again after the window; and a process hashes a bounded number of passwords at once, so its memory
stays flat however fast sign-ins arrive."""

import asyncio
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from apitest_helpers import PASSWORD
from conftest import clear_backend_caches, migrate
from fastapi.testclient import TestClient

PER_ACCOUNT, PER_ADDRESS = 10, 20  # the defaults in backend/settings.py


def sign_in(client: TestClient | httpx.Client, username: str, password: str) -> httpx.Response:
    return client.post("/api/v1/auth/login", json={"username": username, "password": password})


@pytest.fixture
def settings_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[pytest.MonkeyPatch]:
    """Change settings for one test through the environment, as an operator would."""
    yield monkeypatch
    monkeypatch.undo()
    clear_backend_caches()


def test_wrong_passwords_for_one_account_get_429_with_retry_after(wired_app, admin) -> None:
    guesser = TestClient(wired_app)
    assert [sign_in(guesser, "alice", f"guess {n}").status_code for n in range(PER_ACCOUNT)] == [401] * 10
    refused = sign_in(guesser, "alice", "guess 11")
    assert refused.status_code == 429
    assert 1 <= int(refused.headers["Retry-After"]) <= 900
    assert "try again in" in refused.json()["detail"]
    # The account is closed for the window, to the right password too, from anywhere.
    elsewhere = TestClient(wired_app, client=("192.0.2.7", 50000))
    assert sign_in(elsewhere, "alice", PASSWORD).status_code == 429
    assert (
        elsewhere.post("/api/v1/auth/token", data={"username": "alice", "password": PASSWORD}).status_code
        == 429
    )


def test_the_right_password_works_again_after_the_window(wired_app, admin, settings_env) -> None:
    settings_env.setenv("VARBOT_LOGIN_WINDOW_SECONDS", "1.5")
    clear_backend_caches()
    guesser = TestClient(wired_app)
    for n in range(PER_ACCOUNT):
        sign_in(guesser, "alice", f"guess {n}")
    refused = sign_in(guesser, "alice", PASSWORD)
    assert refused.status_code == 429 and refused.headers["Retry-After"] in {"1", "2"}
    time.sleep(1.6)
    assert sign_in(guesser, "alice", PASSWORD).status_code == 200


def test_refused_and_successful_sign_ins_do_not_count(wired_app, admin) -> None:
    owner = TestClient(wired_app)
    for _ in range(PER_ACCOUNT + 5):
        assert sign_in(owner, "alice", PASSWORD).status_code == 200
    for n in range(PER_ACCOUNT):
        assert sign_in(owner, "alice", f"typo {n}").status_code == 401


def test_one_address_guessing_many_accounts_is_throttled(wired_app, admin, make_person) -> None:
    make_person("bob")
    sprayer = TestClient(wired_app, client=("198.51.100.4", 50000))
    names = [f"user{n}" for n in range(PER_ADDRESS)]
    assert {sign_in(sprayer, name, "password1").status_code for name in names} == {401}
    assert sign_in(sprayer, "bob", PASSWORD).status_code == 429
    assert sign_in(TestClient(wired_app), "bob", PASSWORD).status_code == 200  # other addresses still get in


def test_wrong_current_passwords_count_against_the_account(wired_app, member) -> None:
    for n in range(PER_ACCOUNT):
        wrong = {"current_password": f"guess {n}", "new_password": "a brand new password"}
        assert member.client.patch("/api/v1/auth/me", json=wrong).status_code == 403
    right = {"current_password": PASSWORD, "new_password": "a brand new password"}
    assert member.client.patch("/api/v1/auth/me", json=right).status_code == 429


def test_without_redis_the_database_keeps_the_counts(wired_app, admin, broker_down, db) -> None:
    from backend import models

    guesser = TestClient(wired_app)
    assert {sign_in(guesser, "alice", f"guess {n}").status_code for n in range(PER_ACCOUNT)} == {401}
    assert sign_in(guesser, "alice", PASSWORD).status_code == 429
    assert db.query(models.LoginFailure).count() == 2 * PER_ACCOUNT  # per account and per address


# --- several API processes ----------------------------------------------------------------------------------


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _seed_admin(url: str) -> None:
    from sqlalchemy.orm import Session

    from backend.db import make_engine
    from backend.schemas import MemberCreate
    from backend.services import accounts

    engine = make_engine(url)
    with Session(engine) as session:
        household = accounts.create_household(session, "home")
        accounts.create_user(
            session,
            household.id,
            MemberCreate(username="alice", display_name="A", password=PASSWORD, role="admin"),
        )
        session.commit()
    engine.dispose()


@pytest.fixture(params=["redis", "database"])
def two_api_processes(request, redis_socket: Path, tmp_path: Path) -> Iterator[list[str]]:  # type: ignore[no-untyped-def]
    url = f"sqlite:///{tmp_path / 'shared.db'}"
    migrate(url)
    _seed_admin(url)
    broker = redis_socket if request.param == "redis" else tmp_path / "nobody.sock"
    env = {**os.environ, "VARBOT_DATABASE_URL": url, "VARBOT_BROKER_URL": f"redis+socket://{broker}"}
    ports = [_free_port(), _free_port()]
    argv = [
        sys.executable,
        "-m",
        "uvicorn",
        "backend.main:app",
        "--host",
        "127.0.0.1",
        "--log-level",
        "warning",
    ]
    processes = [subprocess.Popen([*argv, "--port", str(port)], env=env) for port in ports]
    urls = [f"http://127.0.0.1:{port}" for port in ports]
    try:
        for base in urls:
            for _ in range(300):
                try:
                    httpx.get(f"{base}/health", timeout=1)
                    break
                except httpx.HTTPError:
                    time.sleep(0.1)
        yield urls
    finally:
        for process in processes:
            process.terminate()
            process.wait(10)


def test_the_throttle_holds_across_api_processes(two_api_processes: list[str]) -> None:
    clients = [httpx.Client(base_url=base, timeout=30) for base in two_api_processes]
    statuses = [sign_in(clients[n % 2], "alice", f"guess {n}").status_code for n in range(PER_ACCOUNT)]
    assert statuses == [401] * PER_ACCOUNT
    assert [sign_in(client, "alice", PASSWORD).status_code for client in clients] == [429, 429]


# --- memory: a bounded number of hashes at once -------------------------------------------------------------


def _peak_rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM in /proc/self/status")


def test_concurrent_sign_ins_hash_one_password_at_a_time(settings_env) -> None:
    from backend.security import hash_password, verify_password_waiting

    settings_env.setenv("VARBOT_PASSWORD_HASH_MEMORY_KIB", str(32 * 1024))
    clear_backend_caches()
    stored = hash_password(PASSWORD)

    async def twelve_at_once() -> list[bool]:
        return await asyncio.gather(*(verify_password_waiting(f"guess {n}", stored) for n in range(12)))

    Path("/proc/self/clear_refs").write_text("5")  # resets the peak (VmHWM) to what is resident now
    before = _peak_rss_mib()
    assert asyncio.run(twelve_at_once()) == [False] * 12
    grown = _peak_rss_mib() - before
    assert grown < 50, f"memory peaked {grown:.0f} MiB higher: more than one 32 MiB hash ran at once"


def test_sign_ins_beyond_the_waiting_room_are_answered_503_at_once(settings_env) -> None:
    from backend.security import HashingBusy, hash_password, verify_password_waiting

    settings_env.setenv("VARBOT_PASSWORD_HASH_QUEUE", "2")
    clear_backend_caches()
    stored = hash_password(PASSWORD)

    async def five_at_once() -> list[object]:
        return await asyncio.gather(
            *(verify_password_waiting("guess", stored) for _ in range(5)), return_exceptions=True
        )

    outcomes = asyncio.run(five_at_once())
    busy = [outcome for outcome in outcomes if isinstance(outcome, HashingBusy)]
    assert len(busy) == 2 and busy[0].headers == {"Retry-After": "1"}, outcomes
    assert outcomes.count(False) == 3
