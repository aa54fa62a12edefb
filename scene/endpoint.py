"""Where the scene listens: `data_dir()/scene/endpoint.json`, written when the scene starts and removed when
it stops. The app's proxy (`backend/pages.py`) reads it to reach the scene."""

import json
import os
from pathlib import Path

from core.paths import data_subdir


def endpoint_file() -> Path:
    return data_subdir("scene") / "endpoint.json"


def announce(url: str, household_id: int) -> None:
    """Tell the API where the scene listens and whose it is (replacing the file in one step)."""
    payload = {"url": url, "household_id": household_id, "pid": os.getpid()}
    temporary = endpoint_file().with_suffix(".tmp")
    temporary.write_text(json.dumps(payload))
    os.replace(temporary, endpoint_file())


def withdraw() -> None:
    """Remove the announcement, unless another scene process has replaced it since."""
    try:
        if json.loads(endpoint_file().read_text()).get("pid") == os.getpid():
            endpoint_file().unlink()
    except (OSError, ValueError):
        pass
