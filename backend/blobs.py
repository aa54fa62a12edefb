"""The blob store: clips, camera images and checkpoints, content-addressed by sha256.

`BlobStore` is the interface; `LocalBlobStore` keeps blobs in a directory (written to a temp file, then
renamed, so a reader never sees half a blob). An S3-compatible store implements the same five methods.
Keys are always sha256 hex digests computed here: a user-supplied name never becomes a path.
"""

import hashlib
import os
import re
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from core.paths import private_dir

_KEY = re.compile(r"^[0-9a-f]{64}$")


class BlobNotFound(KeyError):
    pass


class BlobStore(Protocol):
    def put(self, data: bytes) -> str:
        """Store `data`; return its key (sha256 hex). Storing the same bytes twice is a no-op."""

    def get(self, key: str) -> bytes: ...

    def exists(self, key: str) -> bool: ...

    def delete(self, key: str) -> None: ...

    def keys_older_than(self, seconds: float) -> Iterator[str]:
        """Keys written more than `seconds` ago (the sweep leaves younger ones to requests in flight)."""


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def check_key(key: str) -> str:
    if not _KEY.match(key):
        raise BlobNotFound(f"not a blob key: {key!r}")
    return key


class LocalBlobStore:
    def __init__(self, root: Path) -> None:
        self.root = private_dir(Path(root))  # folders 0700; mkstemp makes the files 0600
        self._tmp = private_dir(self.root / "tmp")

    def path(self, key: str) -> Path:
        check_key(key)
        return self.root / key[:2] / key[2:4] / key

    def put(self, data: bytes) -> str:
        key = sha256_hex(data)
        target = self.path(key)
        if target.exists():
            os.utime(target)  # a fresh upload of known bytes must not be swept as an orphan meanwhile
            return key
        private_dir(target.parent)
        fd, tmp_name = tempfile.mkstemp(dir=self._tmp, prefix=key[:8], suffix=".part")
        try:
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp_name, target)
        except BaseException:
            Path(tmp_name).unlink(missing_ok=True)
            raise
        return key

    def get(self, key: str) -> bytes:
        try:
            return self.path(key).read_bytes()
        except FileNotFoundError as exc:
            raise BlobNotFound(key) from exc

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()

    def delete(self, key: str) -> None:
        self.path(key).unlink(missing_ok=True)

    def keys_older_than(self, seconds: float) -> Iterator[str]:
        cutoff = time.time() - seconds
        for path in self.root.glob("??/??/*"):
            if _KEY.match(path.name) and path.stat().st_mtime < cutoff:
                yield path.name
        for stale in self._tmp.glob("*.part"):  # left by a crash between write and rename
            if stale.stat().st_mtime < cutoff:
                stale.unlink(missing_ok=True)


def referenced_keys(session: Session) -> set[str]:
    """Every blob key some row points at."""
    keys: set[str] = set()
    for column_pair in (
        (models.Clip.original_key, models.Clip.wav_key),
        (models.Snapshot.image_key,),
        (models.ModelVersion.var_key, models.ModelVersion.policy_key),
    ):
        for row in session.execute(select(*column_pair)):
            keys.update(key for key in row if key)
    for (checkpoints,) in session.execute(select(models.Run.checkpoints)):
        keys.update(key for key in checkpoints or [] if isinstance(key, str))
    return keys


def delete_if_unreferenced(session: Session, store: BlobStore, keys: list[str]) -> None:
    """After a row is gone: drop its blobs unless another row (same bytes uploaded twice) still uses them."""
    keys = [key for key in keys if key]
    if not keys:
        return
    still_used: set[str] = set()
    for column in (
        models.Clip.original_key,
        models.Clip.wav_key,
        models.Snapshot.image_key,
        models.ModelVersion.var_key,
        models.ModelVersion.policy_key,
    ):
        still_used.update(session.scalars(select(column).where(column.in_(keys))))
    for key in keys:
        if key not in still_used:
            store.delete(key)


def sweep_orphans(session: Session, store: BlobStore, grace_seconds: float) -> list[str]:
    """Delete blobs no row references (left by a crash between writing a blob and committing its row)."""
    used = referenced_keys(session)
    orphans = [key for key in store.keys_older_than(grace_seconds) if key not in used]
    for key in orphans:
        store.delete(key)
    return orphans
