"""The one data directory for everything varbot generates: corpora, datasets, checkpoints, database, blobs."""

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def data_dir() -> Path:
    """`$VARBOT_DATA_DIR`, default `./data`; created on first use."""
    path = Path(os.environ.get("VARBOT_DATA_DIR", "data")).expanduser().resolve()
    path.mkdir(parents=True, exist_ok=True)
    return path


def data_subdir(*parts: str) -> Path:
    path = data_dir().joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
