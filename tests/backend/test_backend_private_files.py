"""What varbot creates on disk is readable by its own account only: the data directory and every folder under
it 0700, the SQLite database (and its WAL files) and the blobs 0600, whatever the umask lets others read."""

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def open_umask() -> Iterator[None]:
    """The usual umask (022): what others could read unless varbot says otherwise."""
    previous = os.umask(0o022)
    yield
    os.umask(previous)


def test_the_data_directory_and_its_subfolders_are_private(
    open_umask, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from core.paths import data_dir, data_subdir

    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path / "new" / "data"))
    assert mode(data_dir()) == 0o700
    assert mode(tmp_path / "new") == 0o700  # a missing parent is made private too
    assert mode(data_subdir("scene", "logs")) == 0o700
    assert mode(tmp_path / "new" / "data" / "scene") == 0o700


def test_the_sqlite_database_and_its_wal_files_are_private(open_umask, tmp_path: Path) -> None:
    from sqlalchemy import text

    from backend.db import make_engine

    engine = make_engine(f"sqlite:///{tmp_path / 'db' / 'varbot.db'}")
    try:
        with engine.begin() as connection:
            connection.execute(text("CREATE TABLE t (x INTEGER)"))
            connection.execute(text("INSERT INTO t VALUES (1)"))
        files = sorted((tmp_path / "db").iterdir())
        assert {path.name for path in files} >= {"varbot.db", "varbot.db-wal"}
        assert {path.name: mode(path) for path in files} == {path.name: 0o600 for path in files}
        assert mode(tmp_path / "db") == 0o700
    finally:
        engine.dispose()


def test_blobs_and_their_folders_are_private(open_umask, tmp_path: Path) -> None:
    from backend.blobs import LocalBlobStore

    store = LocalBlobStore(tmp_path / "blobs")
    key = store.put(b"a household's voice")
    blob = store.path(key)
    assert mode(blob) == 0o600
    assert {mode(folder) for folder in (tmp_path / "blobs", blob.parent, blob.parent.parent)} == {0o700}
