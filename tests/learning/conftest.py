"""Fixtures shared by the PPO tests."""

import subprocess

import pytest
from rl_helpers import WORDS

from learning.rl.rewards import ClipBank, clip_bank_from_paths


@pytest.fixture(scope="module")
def goal_clips(tmp_path_factory: pytest.TempPathFactory) -> ClipBank:
    """Real spoken commands: espeak-ng says each word in two voices; features from the project's front end."""
    folder = tmp_path_factory.mktemp("clips")
    specs = []
    for intent, word in enumerate(WORDS):
        for voice in ("en", "en-us"):
            path = folder / f"{word}-{voice}.wav"
            subprocess.run(["espeak-ng", "-v", voice, "-w", str(path), word], check=True)
            specs.append(f"{intent}:{path}")
    return clip_bank_from_paths(specs)
