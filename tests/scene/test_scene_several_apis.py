"""Two API processes on one data directory (as `varbot api --workers 2` or two machines' APIs sharing a
volume): a household's members asking both at once get one scene, started on demand; a voice sent through the
API that did not start it reaches it; and "try it now" refuses bad input in plain words."""

import contextlib
import io
import json
import subprocess
import tempfile
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest
import soundfile
from scene_helpers import eventually

from varbot import services
from varbot.services import (
    Service,
    api_url,
    free_port,
    redis_service,
    throwaway_stack_environment,
    varbot_argv,
)

PASSWORD = "several apis test password"


@dataclass
class TwoApis:
    urls: list[str]
    data_dir: Path
    env: dict[str, str]

    def bearer(self, url: str, username: str) -> dict[str, str]:
        token = httpx.post(
            f"{url}/api/v1/auth/token", data={"username": username, "password": PASSWORD}, timeout=30
        )
        token.raise_for_status()
        return {"Authorization": f"Bearer {token.json()['access_token']}"}

    def scene_files(self) -> list[Path]:
        return sorted((self.data_dir / "scene").glob("household-*.json"))


def api_process(name: str, port: int) -> Service:
    argv = varbot_argv("api", "--host", "127.0.0.1", "--port", str(port), "--no-migrate")
    return Service(name, argv, is_ready=lambda: services.http_answers(f"{api_url('127.0.0.1', port)}/health"))


@pytest.fixture(scope="module")
def two_apis() -> Iterator[TwoApis]:
    data_dir = Path(tempfile.mkdtemp(prefix="vb-2api-"))
    sock = data_dir / "redis.sock"
    env = throwaway_stack_environment(
        data_dir,
        sock,
        "several-apis-test-secret-key-not-for-production",
        VARBOT_ADMIN_PASSWORD=PASSWORD,
        VARBOT_SCENE_IDLE_STOP_S="600",
    )
    with services.Stack(data_dir, env) as running:
        running.start(redis_service(sock, persist=False))
        running.migrate(quiet=True)
        admin = ("--username", "dana", "--household", "two api home", "--display-name", "Dana")
        subprocess.run(varbot_argv("admin", "create", *admin), env=env, capture_output=True, check=True)
        ports = [free_port(), free_port()]
        for index, port in enumerate(ports):
            running.start(api_process(f"api-{index}", port))
        yield TwoApis([api_url("127.0.0.1", port) for port in ports], data_dir, env)


def spoken_wav(peak: float) -> bytes:
    rate = 16_000
    t = np.arange(rate) / rate
    buffer = io.BytesIO()
    soundfile.write(buffer, peak * np.sin(2 * np.pi * 330 * t), rate, format="WAV", subtype="PCM_16")
    return buffer.getvalue()


def send_try(url: str, member: dict[str, str], wav: bytes, **form: str) -> httpx.Response:
    return httpx.post(
        f"{url}/api/v1/scene/tries",
        headers=member,
        files={"file": ("try.wav", wav, "audio/wav")},
        data=form,
        timeout=30,
    )


def try_status_once_finished(url: str, member: dict[str, str], sent: httpx.Response) -> dict:
    assert sent.status_code == 202, sent.text
    status_url = f"{url}/api/v1/scene/tries/{sent.json()['try_id']}"
    answers: list[dict] = []

    def finished() -> bool:
        answers.append(httpx.get(status_url, headers=member, timeout=10).json())
        return answers[-1]["finished"]

    eventually(finished, 60, "the scene's answer")
    return answers[-1]


def test_members_asking_two_api_processes_at_once_get_one_scene_which_either_api_reaches(
    two_apis: TwoApis,
) -> None:
    members = [two_apis.bearer(url, "dana") for url in two_apis.urls]

    def ask(index: int) -> dict:
        url = two_apis.urls[index % 2]
        return httpx.get(f"{url}/scene/status", headers=members[index % 2], timeout=60).json()

    with ThreadPoolExecutor(6) as pool:
        list(pool.map(ask, range(6)))  # six asks at once, three to each API
    eventually(lambda: all(ask(i)["available"] for i in range(2)), 180, "the household's scene")
    announced = two_apis.scene_files()
    assert len(announced) == 1, f"one scene for the household, announced once: {announced}"
    pid = json.loads(announced[0].read_text())["pid"]

    # A voice sent through either API reaches the same scene (no model yet: it says what to do).
    for url, member in zip(two_apis.urls, members, strict=True):
        answer = try_status_once_finished(url, member, send_try(url, member, spoken_wav(0.4)))
        assert "no active model yet" in answer["message"] and answer["state"] == "refused", answer
    assert json.loads(two_apis.scene_files()[0].read_text())["pid"] == pid, "still the one scene"
    assert scene_processes(two_apis.data_dir) == [pid], (
        "one scene process for the household, whichever API was asked"
    )


def scene_processes(data_dir: Path) -> list[int]:
    """The scene processes serving this data directory (other tests' stacks may run scenes of their own)."""
    import psutil

    found = []
    for process in psutil.process_iter(["pid", "cmdline"]):
        cmdline = process.info["cmdline"] or []
        if "varbot.cli" in cmdline and "scene" in cmdline and "--household" in cmdline:
            with contextlib.suppress(psutil.Error):
                if process.environ().get("VARBOT_DATA_DIR") == str(data_dir):
                    found.append(process.info["pid"])
    return found


def test_try_it_now_refuses_bad_input_in_plain_words(two_apis: TwoApis) -> None:
    url = two_apis.urls[0]
    member = two_apis.bearer(url, "dana")

    silent = send_try(url, member, spoken_wav(0.0))
    assert silent.status_code == 422 and "silent" in silent.json()["detail"]
    not_audio = send_try(url, member, b"hello, this is not a recording")
    assert not_audio.status_code == 415 or not_audio.status_code == 422, not_audio.text
    unknown_robot = send_try(url, member, spoken_wav(0.4), robot_id="999999")
    assert unknown_robot.status_code == 404 and "robot 999999 not found" in unknown_robot.json()["detail"]
    nobody = httpx.get(f"{url}/api/v1/scene/tries/{'0' * 32}", headers=member, timeout=10)
    assert nobody.status_code == 404
