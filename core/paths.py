"""The one data directory for everything varbot generates: corpora, datasets, checkpoints, database, blobs.

What varbot creates there is private to the account that runs it (folders 0700, files 0600): the database
holds password hashes and session HMACs, the blobs hold the household's voices."""

import os
from collections.abc import Mapping
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
PRIVATE_DIR_MODE = 0o700
PRIVATE_FILE_MODE = 0o600


def private_dir(path: Path) -> Path:
    """`path` and any missing parents, created 0700 (an existing folder keeps its mode)."""
    missing = [folder for folder in (path, *path.parents) if not folder.exists()]
    for folder in reversed(missing):
        folder.mkdir(mode=PRIVATE_DIR_MODE, exist_ok=True)
    return path


def private_file(path: Path) -> Path:
    """Creates `path` empty and 0600 when it is missing, so that whoever fills it (SQLite) keeps that mode."""
    private_dir(path.parent)
    os.close(os.open(path, os.O_CREAT | os.O_WRONLY, PRIVATE_FILE_MODE))
    return path


def data_dir() -> Path:
    """`$VARBOT_DATA_DIR`, default `./data`; created (0700) on first use."""
    return private_dir(data_dir_in(os.environ))


def data_dir_in(environ: Mapping[str, str]) -> Path:
    """The data dir a process with this environment uses (not created)."""
    return Path(environ.get("VARBOT_DATA_DIR", "data")).expanduser().resolve()


def data_subdir(*parts: str) -> Path:
    return private_dir(data_dir().joinpath(*parts))
