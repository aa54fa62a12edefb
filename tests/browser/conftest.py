"""Fixtures of the browser tests live in browser_helpers.py (importable by the test modules too)."""

from browser_helpers import (  # noqa: F401
    browser,
    console,
    fake_microphone_wav,
    page,
    playwright_session,
    robot_id,
    scene_service,
    stack,
)
