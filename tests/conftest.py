"""Suite-wide settings: tests never write into the real data directory, and the browser tests run last when
one pytest runs them all (`make test` runs them in a stream of their own beside the rest:
scripts/run_tests.py)."""

import os
import tempfile
from pathlib import Path

import pytest

# Set before any project module reads it. Individual tests may point it elsewhere with monkeypatch.
os.environ["VARBOT_DATA_DIR"] = tempfile.mkdtemp(prefix="varbot-test-data-")
os.environ.setdefault("VARBOT_ENVIRONMENT", "test")

BROWSER_TESTS = Path(__file__).parent / "browser"


def is_browser_test(item: pytest.Item) -> bool:
    return BROWSER_TESTS in Path(item.path).parents


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The browser tests' app, scenes and Chromium live until the session ends, and took CPU from the tests
    collected after them (in one run a browser test's scene still rendered, at a quarter of a core, while the
    PPO tests ran 10 minutes later): they run last, in their own order."""
    items.sort(key=is_browser_test)  # stable: each group keeps its order
