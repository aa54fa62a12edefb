"""`scripts/gpu_continue_policy.py`: `prepare` here puts a corpus split's goal features and the policy to
start from under .dev/; `train` (on a lent GPU machine, here on the CPU) continues that policy's PPO with
another number of envs and step budget, from those files alone."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from rl_helpers import IMAGE, tiny_config

from learning.rl.rewards import corpus_bank
from learning.rl.run import train_run
from learning.sounds.build import build_corpora
from learning.var.checkpoint import save_var
from learning.var.model import VAR, VARConfig

pytestmark = [pytest.mark.slow, pytest.mark.speech]

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "gpu_continue_policy.py"


def script(*arguments: str, cwd: Path) -> subprocess.CompletedProcess:  # type: ignore[type-arg]
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *arguments], cwd=cwd, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return done


def test_a_policy_continues_from_the_prepared_files_with_its_own_settings(tmp_path: Path) -> None:
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    torch.manual_seed(0)
    var = save_var(VAR(VARConfig(image_size=IMAGE)).eval(), tmp_path / "var.pt")
    first = tmp_path / "first"
    train_run(tiny_config(total_steps=24), first, var, goals=corpus_bank("wordset", "train"), progress=False)

    script("prepare", "--var", str(var), "--policy", str(first / "checkpoint.pt"), cwd=tmp_path)
    stored = np.load(tmp_path / ".dev" / "goals.npz")
    assert len(stored["features"]) == len(corpus_bank("wordset", "train").features)
    continued = tmp_path / "continued"
    script("train", "--var", str(var), "--envs", "4", "--steps", "48", "--minutes", "5",
           "--out", str(continued), "--device", "cpu", cwd=tmp_path)  # fmt: skip

    config = json.loads((continued / "config.json").read_text())
    assert config["num_envs"] == 4 and config["total_steps"] == 48
    assert config["num_steps"] == tiny_config().num_steps  # everything else as the policy was trained
    assert config["init_policy"] == str(Path(".dev") / "init_policy.pt")
    assert json.loads((continued / "summary.json").read_text())["env_steps"] == 48
