"""How benches write bench/results/*.json: paths relative to the data directory or the repository, never this
machine's absolute ones, so a clone elsewhere reads the same file.

A path under the repository (the default data directory ./data included) is written relative to it, one
under a data directory elsewhere `$VARBOT_DATA_DIR/<rest>`; `resolve` turns either back into a path on this
machine. Every absolute path inside a
string is rewritten, so an annotated path ("/…/final.pt (6 epochs)") is too.
"""

import hashlib
import json
import os
import re
from collections.abc import Callable
from pathlib import Path

from core.paths import REPO_ROOT, data_dir

DATA_DIR_MARK = "$VARBOT_DATA_DIR"
ABSOLUTE_PATH = re.compile(r"(?<![\w.$/:])/(?:[\w.+-]+/)+[\w.+-]*")


def relative_path(path: str | Path) -> str:
    """`path` as it is written into a result; one outside both the data directory and the repository keeps
    only its name (it would mean nothing on another machine)."""
    path = Path(path)
    if not path.is_absolute():
        return str(path)
    resolved = path.resolve()
    if resolved.is_relative_to(REPO_ROOT):  # the default data directory, ./data, too
        return str(resolved.relative_to(REPO_ROOT))
    if resolved.is_relative_to(data_dir()):
        return f"{DATA_DIR_MARK}/{resolved.relative_to(data_dir())}"
    return f"(outside the repository) {path.name}"


def map_strings(value: object, change: Callable[[str], str]) -> object:
    """A JSON value with `change` applied to every string in it, dict keys included."""
    if isinstance(value, str):
        return change(value)
    if isinstance(value, dict):
        return {map_strings(key, change): map_strings(item, change) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [map_strings(item, change) for item in value]
    return value


def relative_paths(value: object) -> object:
    """A JSON value with every absolute path in its strings made relative."""
    return map_strings(value, lambda text: ABSOLUTE_PATH.sub(lambda path: relative_path(path[0]), text))


def resolve(written: str) -> Path:
    """A path as a result writes it, on this machine."""
    if written.startswith(DATA_DIR_MARK + "/"):
        return data_dir() / written.removeprefix(DATA_DIR_MARK + "/")
    return REPO_ROOT / written


def file_sha256(path: Path) -> str:
    """Which file a result measured, whatever its path holds later (a base model can be replaced)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_result(path: Path, result: dict) -> None:
    """Writes a bench's JSON with relative paths, atomically (an interrupted write leaves the old file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(path.suffix + ".tmp")
    temporary.write_text(json.dumps(relative_paths(result), indent=2) + "\n")
    os.replace(temporary, path)
