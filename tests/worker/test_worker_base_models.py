"""Base models: checkpoints trained by the benchmarks become a world's base model with their record."""

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from varbot.cli import app
from worker.base_models import SHIPPED_DIR, find_base

SHIPPED = SHIPPED_DIR / "kuka"


def adopt(world: str, out: Path, record: Path) -> object:
    return CliRunner().invoke(
        app,
        [
            *("models", "adopt", "--world", world, "--out", str(out)),
            *(
                "--var",
                str(SHIPPED / "var.pt"),
                "--policy",
                str(SHIPPED / "policy.pt"),
                "--record",
                str(record),
            ),
        ],
    )


@pytest.fixture
def record(tmp_path: Path) -> Path:
    path = tmp_path / "record.json"
    path.write_text(json.dumps({"command": "bench/reproduce.py --rows kuka-wordset:var", "success": 0.5}))
    return path


def test_adopted_checkpoints_become_the_base_model_with_their_record(
    tmp_path: Path, record: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    result = adopt("kuka", tmp_path / "models", record)
    assert result.exit_code == 0, result.output
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "models"))
    base = find_base("kuka")
    assert base.folder == tmp_path / "models" / "kuka"
    assert base.record["success"] == 0.5 and base.record["image_size"] == 96
    assert base.record["adopted_from"]["policy"].endswith("policy.pt")
    assert set(base.record["file_bytes"]) == {"var.pt", "policy.pt"}


def test_a_policy_of_another_world_is_refused(tmp_path: Path, record: Path) -> None:
    result = adopt("turtlebot", tmp_path / "models", record)
    assert result.exit_code == 2 and "trained in the kuka world" in result.output
    assert not (tmp_path / "models" / "turtlebot").exists()
