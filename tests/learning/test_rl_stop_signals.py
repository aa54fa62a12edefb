"""`varbot rl train` stopped by SIGTERM (`kill`, a session ending) or by Ctrl-C in its terminal finishes the
update it is in, writes a checkpoint, closes its env workers, says how to continue, and `--resume` takes the
run up again from there: nothing is lost and no worker dies with a traceback."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from learning.sounds.build import build_corpora
from learning.var.checkpoint import save_var
from learning.var.model import VAR, VARConfig

pytestmark = [pytest.mark.slow, pytest.mark.speech]

IMAGE = 16
UPDATE = 2 * 100  # two envs, 100 steps each
UPDATES = 5


@pytest.fixture(scope="module")
def var_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    torch.manual_seed(0)
    return save_var(VAR(VARConfig(image_size=IMAGE)).eval(), tmp_path_factory.mktemp("var") / "var.pt")


def train_command(var: Path, run_dir: Path, *extra: str) -> list[str]:
    varbot = Path(sys.executable).with_name("varbot")
    return [
        str(varbot), "rl", "train", "--world", "kuka", "--sounds", "wordset", "--var", str(var),
        "--steps", str(UPDATES * UPDATE), "--envs", "2", "--policy-image-size", str(IMAGE),
        "--run-dir", str(run_dir), *extra,
    ]  # fmt: skip


def updates_written(run_dir: Path) -> list[int]:
    metrics = run_dir / "metrics.jsonl"
    if not metrics.exists():
        return []
    return [json.loads(line)["update"] for line in metrics.read_text().splitlines()]


def wait_for_first_update(run_dir: Path, process: subprocess.Popen, timeout_s: float = 180) -> None:  # type: ignore[type-arg]
    deadline = time.monotonic() + timeout_s
    while not updates_written(run_dir):
        assert process.poll() is None, process.communicate()[1]
        assert time.monotonic() < deadline, "no update written"
        time.sleep(0.2)


@pytest.mark.parametrize(
    ("signum", "to_the_group"),
    [(signal.SIGTERM, False), (signal.SIGINT, True)],
    ids=["sigterm-to-the-trainer", "ctrl-c-to-the-terminals-process-group"],
)
def test_a_stopped_run_checkpoints_its_last_update_and_resume_finishes_it(
    tmp_path: Path, var_checkpoint: Path, signum: int, to_the_group: bool
) -> None:
    run_dir = tmp_path / "run"
    process = subprocess.Popen(
        train_command(var_checkpoint, run_dir),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        wait_for_first_update(run_dir, process)
        if to_the_group:
            os.killpg(process.pid, signum)
        else:
            process.send_signal(signum)
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    stopped_at = updates_written(run_dir)[-1]
    assert process.returncode == 128 + signum, stderr
    assert f"stopped by {signal.Signals(signum).name} at {stopped_at * UPDATE:,} env steps" in stderr
    assert "--resume continues" in stderr
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr
    assert 1 <= stopped_at < UPDATES
    checkpoint = torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=False)
    assert checkpoint["update_index"] == stopped_at  # the update it was in when the signal came is kept

    resumed = subprocess.run(
        train_command(var_checkpoint, run_dir, "--resume"), capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert updates_written(run_dir) == list(range(1, UPDATES + 1))
    assert json.loads((run_dir / "summary.json").read_text())["env_steps"] == UPDATES * UPDATE
