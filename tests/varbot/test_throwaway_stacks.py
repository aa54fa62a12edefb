"""A test's throwaway stack runs with exactly the settings the test gives it: another test's stack, still
running in the same pytest process, may have put its own VARBOT_ settings into this process's environment."""

from pathlib import Path

import pytest

from varbot.services import throwaway_stack_environment


def test_a_throwaway_stack_inherits_no_varbot_setting_left_by_another_stack(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", "/elsewhere/tiny_base_models")
    monkeypatch.setenv("VARBOT_RUN_LEASE_S", "3")
    env = throwaway_stack_environment(
        tmp_path / "data", tmp_path / "redis.sock", "k", VARBOT_SSE_POLL_SECONDS="1"
    )
    assert "VARBOT_BASE_MODELS_DIR" not in env and "VARBOT_RUN_LEASE_S" not in env
    assert env["VARBOT_DATA_DIR"] == str(tmp_path / "data") and env["VARBOT_SECRET_KEY"] == "k"
    assert env["VARBOT_SSE_POLL_SECONDS"] == "1" and env["VARBOT_ENVIRONMENT"] == "test"


def test_a_throwaway_stack_keeps_the_rest_of_the_environment(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("SOME_TOOL_SETTING", "kept")
    env = throwaway_stack_environment(tmp_path / "data", tmp_path / "redis.sock", "k")
    assert env["SOME_TOOL_SETTING"] == "kept" and env["PYTHONUNBUFFERED"] == "1"
