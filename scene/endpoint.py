"""Where the scene listens: `data_dir()/scene/endpoint.json`, written when the scene starts and removed when
it stops. The app's proxy (`backend/pages.py`) reads it to reach the scene, and presents the `headers` it
names on every request (this start's secret, `scene.access`). Only the app's user may read the file."""

import json
import os
from pathlib import Path

from core.paths import data_subdir
from scene.access import SECRET_HEADER

PRIVATE_FILE = 0o600


def endpoint_file() -> Path:
    return data_subdir("scene") / "endpoint.json"


def announce(url: str, household_id: int, secret: str) -> None:
    """Tell the API where the scene listens, whose it is and how to get in (the file replaced in one step)."""
    payload = {
        "url": url,
        "household_id": household_id,
        "headers": {SECRET_HEADER: secret},
        "pid": os.getpid(),
    }
    temporary = endpoint_file().with_suffix(f".{os.getpid()}.tmp")  # two scenes never share one
    temporary.unlink(missing_ok=True)  # a leftover could have been created with wider permissions
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, PRIVATE_FILE)
    with os.fdopen(descriptor, "w") as file:
        file.write(json.dumps(payload))
    os.replace(temporary, endpoint_file())


def withdraw() -> None:
    """Remove the announcement, unless another scene process has replaced it since."""
    try:
        if json.loads(endpoint_file().read_text()).get("pid") == os.getpid():
            endpoint_file().unlink()
    except (OSError, ValueError):
        pass
