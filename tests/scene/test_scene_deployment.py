"""No always-on scene anywhere: `varbot up` and docker-compose.yml start none; the API starts each household's
scene on demand (scene/on_demand.py), so the API runs where a scene can run, and several API processes share
the scene locks. docker-compose.yml is parsed (no Docker engine runs here)."""

from pathlib import Path

import pytest
import yaml

from varbot.up import plan_stack

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_varbot_up_starts_no_scene_of_its_own(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path))
    _stack, services = plan_stack("127.0.0.1", 8000)
    assert [service.name for service in services] == ["redis", "api", "worker-training", "worker-robot"]
    assert not any("scene" in service.argv for service in services)


def test_compose_runs_no_scene_service_and_every_varbot_command_is_a_long_running_part(compose: dict) -> None:
    services = compose["services"]
    assert "scene" not in services
    commands = {name: s["command"] for name, s in services.items() if s.get("command", [""])[0] == "varbot"}
    assert {name: command[1] for name, command in commands.items()} == {
        "migrate": "db",
        "api": "api",
        "worker-training": "worker",
        "worker-robot": "worker",
    }


def test_the_api_runs_the_image_a_scene_can_run_in_with_several_processes_sharing_the_data_volume(
    compose: dict,
) -> None:
    api = compose["services"]["api"]
    assert api["image"] == "varbot-full" and api["build"]["target"] == "full", "scenes need torch and viser"
    command = api["command"]
    assert int(command[command.index("--workers") + 1]) >= 2, "several API processes"
    assert "blobs:/data" in api["volumes"], "the scene locks and endpoint files live in the data volume"
    assert api["environment"]["VARBOT_DATA_DIR"] == "/data"
    assert "network_mode" not in api
