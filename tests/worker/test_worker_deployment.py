"""docker-compose.yml and the Dockerfile, checked by parsing (no Docker engine runs here)."""

import re
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
VARBOT_SERVICES = {"migrate", "api", "worker-training", "worker-robot"}  # scenes: on demand, by the API


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def parse_varbot_argv(argv: list[str]) -> None:
    """Resolve `varbot <group> <command> --options` down to the command and parse its options with typer's
    own parser; anything it would refuse fails here with its message."""
    import typer
    from typer.exceptions import TyperException

    from varbot.cli import app

    command = typer.main.get_command(app)
    args = list(argv)
    while hasattr(command, "commands"):  # a group
        assert args, f"`varbot {' '.join(argv)}` names a group, not a command"
        name = args.pop(0)
        assert name in command.commands, f"`varbot {' '.join(argv)}`: no sub-command {name!r}"
        command = command.commands[name]
    try:
        command.make_context("varbot", args)
    except TyperException as exc:
        raise AssertionError(f"`varbot {' '.join(argv)}`: {exc}") from exc


def test_the_command_check_itself_rejects_unknown_commands_options_and_values() -> None:
    refusals = {
        "nothing": "no sub-command 'nothing'",
        "worker --bogus": "No such option: --bogus",
        "worker --queue nope": "'nope' is not one of 'training', 'robot'",
        "db": "names a group, not a command",
    }
    for argv, reason in refusals.items():
        with pytest.raises(AssertionError, match=re.escape(reason)):
            parse_varbot_argv(argv.split())


def test_every_service_the_product_needs_is_there(compose: dict) -> None:
    assert {"postgres", "redis", *VARBOT_SERVICES} <= set(compose["services"])


def test_the_data_services_have_healthchecks_and_volumes(compose: dict) -> None:
    for name, mount in (("postgres", "/var/lib/postgresql/data"), ("redis", "/data")):
        service = compose["services"][name]
        assert service["healthcheck"]["test"], name
        assert any(
            v.endswith(":" + mount) and v.split(":")[0] in compose["volumes"] for v in service["volumes"]
        )


def test_the_api_starts_after_healthy_data_services_and_completed_migrations(compose: dict) -> None:
    services = compose["services"]
    for name in VARBOT_SERVICES - {"migrate"}:
        depends = services[name]["depends_on"]
        assert depends["postgres"]["condition"] == "service_healthy", name
        assert depends["redis"]["condition"] == "service_healthy", name
        assert depends["migrate"]["condition"] == "service_completed_successfully", name
    assert services["migrate"]["command"][1:] == ["db", "upgrade"]
    assert services["api"]["healthcheck"]["test"]


def test_workers_and_api_share_one_blob_volume_and_environment_driven_settings(compose: dict) -> None:
    services = compose["services"]
    for name in VARBOT_SERVICES - {"migrate"}:
        volumes = services[name]["volumes"]
        assert "blobs:/data" in volumes, name
    assert "blobs" in compose["volumes"]
    for name in VARBOT_SERVICES:
        env = services[name]["environment"]
        assert (
            env["VARBOT_DATABASE_URL"].startswith("postgresql://")
            and "postgres:5432" in env["VARBOT_DATABASE_URL"]
        )
        assert env["VARBOT_BROKER_URL"] == "redis://redis:6379/0"
        assert env["VARBOT_SECRET_KEY"].startswith("${"), "secrets come from the environment / .env"


def test_every_command_is_a_real_varbot_sub_command(compose: dict) -> None:
    for name in VARBOT_SERVICES:
        command = compose["services"][name]["command"]
        assert command[0] == "varbot", name
        parse_varbot_argv(command[1:])


def test_the_worker_queues_match_the_services(compose: dict) -> None:
    services = compose["services"]
    assert services["worker-training"]["command"][-2:] == ["--queue", "training"]
    assert services["worker-robot"]["command"][-2:] == ["--queue", "robot"]


def test_the_dockerfile_builds_every_target_compose_asks_for_from_sources_that_exist(compose: dict) -> None:
    dockerfile = (REPO / "Dockerfile").read_text()
    stages = {
        line.split()[-1] for line in dockerfile.splitlines() if line.startswith("FROM ") and " AS " in line
    }
    targets = {s["build"]["target"] for s in compose["services"].values() if isinstance(s.get("build"), dict)}
    assert targets == {"api", "full"} and targets <= stages
    images = {s.get("image") for s in compose["services"].values() if s.get("image", "").startswith("varbot")}
    assert images == {"varbot-api", "varbot-full"}
    for line in dockerfile.splitlines():
        if line.startswith("COPY ") and "--from" not in line:
            for source in line.split()[1:-1]:
                assert (REPO / source).exists(), f"Dockerfile copies {source}, which does not exist"


def test_the_images_hold_every_package_and_the_pages_and_import_them_from_the_sources() -> None:
    import tomllib

    dockerfile = (REPO / "Dockerfile").read_text()
    copied = {
        line.split()[1]
        for line in dockerfile.splitlines()
        if line.startswith("COPY ") and "--from" not in line
    }
    packages = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    wanted = {name.rstrip("*") for name in packages["include"]}
    assert wanted | {"frontend"} <= copied, f"not copied into the image: {(wanted | {'frontend'}) - copied}"
    assert "PYTHONPATH=/app" in dockerfile, (
        "the pages are found beside the sources only when /app is imported"
    )
