"""Where each household's scene listens: `data_dir()/scene/household-<id>.json`, written when that scene
starts and removed when it stops. The app's proxy (`backend/pages.py`) reads it to reach the scene of the
signed-in member's household, and presents the `headers` it names on every request (this start's secret,
`scene.access`). Only the app's user may read the file.

A scene holds `household-<id>.lock` for as long as it runs, so a household has one scene however many API
processes asked for it. This module imports no Viser, torch or PyBullet: the API process reads it too."""

import fcntl
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from core.paths import data_subdir

SECRET_HEADER = "X-Varbot-Scene-Secret"
PRIVATE_FILE = 0o600


@dataclass(frozen=True)
class Announced:
    url: str  # http://127.0.0.1:port
    household_id: int
    pid: int
    headers: dict[str, str] = field(default_factory=dict)  # to present on every request (the secret)


def endpoint_file(household_id: int) -> Path:
    return data_subdir("scene") / f"household-{household_id}.json"


def announce(url: str, household_id: int, secret: str) -> None:
    """Tell the API where the scene listens, whose it is and how to get in (the file replaced in one step)."""
    payload = {
        "url": url,
        "household_id": household_id,
        "headers": {SECRET_HEADER: secret},
        "pid": os.getpid(),
    }
    written = endpoint_file(household_id)
    temporary = written.with_suffix(f".{os.getpid()}.tmp")  # two scenes never share one
    temporary.unlink(missing_ok=True)  # a leftover could have been created with wider permissions
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, PRIVATE_FILE)
    with os.fdopen(descriptor, "w") as file:
        file.write(json.dumps(payload))
    os.replace(temporary, written)


def withdraw(household_id: int) -> None:
    """Remove the announcement, unless another scene process has replaced it since."""
    try:
        if json.loads(endpoint_file(household_id).read_text()).get("pid") == os.getpid():
            endpoint_file(household_id).unlink()
    except (OSError, ValueError):
        pass


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def announced(household_id: int) -> Announced | None:
    """The household's running scene, or None (none announced, or the one announced has died)."""
    try:
        found = json.loads(endpoint_file(household_id).read_text())
        headers = {str(k): str(v) for k, v in found["headers"].items()}
        scene = Announced(
            str(found["url"]).rstrip("/"), int(found["household_id"]), int(found["pid"]), headers
        )
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return None
    return scene if alive(scene.pid) else None


def hold_scene_lock(household_id: int) -> IO[str] | None:
    """The household's scene lock, held until the returned file is closed (or the process ends); None when
    another scene for this household holds it."""
    lock = (data_subdir("scene") / f"household-{household_id}.lock").open("a")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        return None
    return lock
