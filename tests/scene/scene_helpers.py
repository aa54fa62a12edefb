"""Helpers of the scene tests (a module of its own: test modules import it by name, as tests/backend does)."""

import time
from dataclasses import dataclass


@dataclass
class SceneHousehold:
    household_id: int
    robot_id: int


def clear_backend_caches() -> None:
    from backend.deps import forget_cached_settings

    forget_cached_settings()


def eventually(condition, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out after {timeout:.0f} s waiting for {what}"
        time.sleep(0.05)
