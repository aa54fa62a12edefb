"""bench/reproduce.py hands the PPO options given on its command line to the run's settings, and leaves the
others at PPOConfig's defaults."""

import sys

import pytest
from reproduce import optional_overrides, parse_arguments

from learning.rl.baselines import method_config


def run_settings(monkeypatch: pytest.MonkeyPatch, *options: str):
    monkeypatch.setattr(sys, "argv", ["reproduce.py", "--rows", "kuka-wordset:var", *options])
    return method_config("var", world="kuka", sounds="wordset", **optional_overrides(parse_arguments()))


def test_a_start_curriculum_given_on_the_command_line_reaches_the_runs_settings(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    assert run_settings(monkeypatch, "--hard-start-share", "0.3").hard_start_share == 0.3


def test_without_one_the_gripper_starts_anywhere_as_in_the_paper(monkeypatch: pytest.MonkeyPatch) -> None:
    settings = run_settings(monkeypatch)
    assert settings.hard_start_share == 0.0 and settings.reward_temperature is None
