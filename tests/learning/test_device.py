"""VARBOT_DEVICE: auto takes a GPU only when torch sees one, cpu never, cuda insists and says what is missing;
the trainer runs its VAR and policy there and places its environment workers on the machine's cores."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from rl_helpers import IMAGE, tiny_config

from backend.settings import Settings
from learning.device import DeviceUnavailable, core_plan, resolve_device
from learning.rl.frozen_var import LoadedVar
from learning.rl.rewards import ClipBank
from learning.rl.run import train_run
from learning.var.model import VAR, VARConfig

CPU, CUDA = torch.device("cpu"), torch.device("cuda")


def test_cpu_is_the_cpu_and_auto_takes_a_gpu_only_when_torch_sees_one() -> None:
    assert resolve_device("cpu") == CPU
    assert resolve_device("auto") == (CUDA if torch.cuda.is_available() else CPU)


def test_asking_for_cuda_on_a_machine_without_one_says_what_is_missing() -> None:
    if torch.cuda.is_available():  # a GPU machine: cuda is simply the GPU
        assert resolve_device("cuda") == CUDA
        return
    with pytest.raises(DeviceUnavailable) as refused:
        resolve_device("cuda")
    message = str(refused.value)
    assert "VARBOT_DEVICE=cuda" in message and "no CUDA GPU" in message
    assert "VARBOT_DEVICE=auto" in message and torch.__version__ in message


def test_an_unknown_device_is_refused_naming_the_choices(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="auto, cpu, cuda"):
        resolve_device("gpu")
    monkeypatch.setenv("VARBOT_DEVICE", "gpu")
    with pytest.raises(ValueError, match="device"):
        Settings(environment="development")
    monkeypatch.delenv("VARBOT_DEVICE")
    assert Settings(environment="development").device == "auto"


def test_envs_get_cores_of_their_own_only_where_the_machine_has_enough() -> None:
    two_cores = core_plan(2, 8, CPU, cpu_threads=1)
    assert (two_cores.learner_threads, two_cores.learner_cores, two_cores.env_cores) == (1, (), ())
    gpu_machine = core_plan(16, 8, CUDA, cpu_threads=8)
    assert gpu_machine.learner_threads == 1 and gpu_machine.learner_cores == (0,)
    assert gpu_machine.env_cores == tuple(range(1, 9))
    cpu_machine = core_plan(16, 8, CPU, cpu_threads=8)
    assert cpu_machine.learner_cores == tuple(range(8)) and cpu_machine.env_cores == tuple(range(8, 16))
    assert core_plan(16, 8, CPU, cpu_threads=9).env_cores == ()


@pytest.mark.slow
def test_a_run_on_the_auto_device_learns_exactly_what_it_learns_on_the_cpu(tmp_path: Path) -> None:
    """On this machine auto is the CPU: the same seed gives the same updates and weights."""
    torch.manual_seed(0)
    var = LoadedVar.in_memory(VAR(VARConfig(image_size=IMAGE)))
    clips = np.random.default_rng(0).normal(size=(4, 100, 40)).astype(np.float32)
    results = {}
    for device in ("cpu", "auto"):
        config = tiny_config(total_steps=24)  # one update
        goals = ClipBank(clips.copy(), np.arange(4))
        train_run(config, tmp_path / device, var, goals, progress=False, device=resolve_device(device))
        lines = (tmp_path / device / "metrics.jsonl").read_text().splitlines()
        updates = [
            {k: v for k, v in json.loads(line).items() if k not in ("sps", "time", "peak_memory_mb")}
            for line in lines
        ]
        weights = torch.load(tmp_path / device / "checkpoint.pt", weights_only=False)["policy"]
        results[device] = (updates, weights)
    assert json.dumps(results["cpu"][0]) == json.dumps(results["auto"][0])
    cpu_weights, auto_weights = results["cpu"][1], results["auto"][1]
    assert all(torch.equal(cpu_weights[name], auto_weights[name]) for name in cpu_weights)


def test_building_a_base_model_on_a_device_it_cannot_have_is_refused_before_it_starts(
    tmp_path: Path,
) -> None:
    from typer.testing import CliRunner

    from varbot.cli import app

    def build(device: str):  # type: ignore[no-untyped-def]
        command = ["models", "build-base", "--world", "kuka", "--device", device, "--out", str(tmp_path)]
        return CliRunner().invoke(app, command, env={"COLUMNS": "300"})

    unknown = build("gpu")
    assert unknown.exit_code != 0 and "auto, cpu, cuda" in unknown.output, unknown.output
    if not torch.cuda.is_available():
        missing = build("cuda")
        assert missing.exit_code != 0 and "no CUDA GPU" in missing.output, missing.output
    assert not any(tmp_path.iterdir()), "nothing was built"
