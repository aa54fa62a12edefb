"""Coaching the robot by voice in a real Chromium: on the Scene page a member starts a session, the robot
worker plays the shipped Kuka base model on the command at five steps a second, and holding Space while the
fake microphone says "zero" stores a recording of the command, the view it was said over and an *is* label
between them; stopping the session keeps that answer."""

from collections.abc import Iterator

import pytest
from browser_helpers import Stack, open_page, screenshot, speech_wav, upload_clip

from varbot.services import Service, worker_service

pytestmark = pytest.mark.browser
SAID_S = 1.0  # Space is held until the page has heard this much of the fake microphone ("zero" and a pause)
# what the page says once the API answered the clip: "… saved as …", or "Not saved: …"
ANSWERED = "() => /saved/i.test(document.getElementById('coach-heard').textContent)"


@pytest.fixture(scope="module")
def coached_robot(stack: Stack, tmp_path_factory: pytest.TempPathFactory) -> int:
    wav = speech_wav("zero", tmp_path_factory.mktemp("coaching") / "zero.wav")
    with stack.client() as alice:
        robot = alice.post("/robots", json={"name": "coached arm", "kind": "kuka-sim"}).json()["id"]
        upload_clip(alice, wav.read_bytes(), "zero")
    return int(robot)


@pytest.fixture(scope="module")
def robot_worker(stack: Stack) -> Iterator[Service]:
    worker = stack.start(worker_service("robot", stack.data_dir, "worker-robot-coaching"))
    yield worker
    worker.stop()


def test_holding_space_while_the_robot_works_stores_an_is_label_for_the_view_said_over(
    page, stack: Stack, coached_robot: int, robot_worker: Service
) -> None:  # type: ignore[no-untyped-def]
    coaching_views = "source = 'coaching'"
    zeros = "deleted_at IS NULL AND name = 'zero'"
    recordings = stack.count("clips", zeros)  # other tests' households may have said "zero" too
    page.evaluate(f"localStorage.setItem('varbot.robot', '{coached_robot}')")
    open_page(page, f"{stack.url}/scene")
    panel = page.locator("#coaching")
    panel.wait_for()
    page.get_by_label("Command").select_option("zero")
    page.get_by_role("button", name="Start coaching").click()
    page.get_by_text("Starting…").wait_for(timeout=5_000)
    try:
        page.wait_for_function("() => document.body.dataset.coaching === 'running'", timeout=150_000)
        page.wait_for_function("() => Number(document.body.dataset.coachingStep) > 0", timeout=60_000)
    except Exception:
        log = stack.log("worker-robot-coaching")[-4000:]
        raise AssertionError(f"the session did not run:\n{log}") from None
    assert "hold Space and say “zero”" in page.locator("#coach-message").inner_text()

    page.keyboard.down("Space")
    page.wait_for_function("() => document.getElementById('coach-talk').classList.contains('talking')")
    heard_enough = f"() => Number(document.body.dataset.coachingListenedS) >= {SAID_S}"
    page.wait_for_function(heard_enough, polling=50)  # not once a frame: the scene's software WebGL is slow
    page.keyboard.up("Space")
    try:
        page.wait_for_function(ANSWERED, timeout=120_000)
    except Exception:
        raise AssertionError(f"no answer to the clip:\n{stack.log('api')[-4000:]}") from None
    heard = page.locator("#coach-heard").inner_text()
    assert "saved as “zero” for that view" in heard, heard
    assert page.evaluate("document.body.dataset.coachingAnswers") == "1"
    assert stack.count("snapshots", coaching_views) == 1
    (snapshot,) = _coaching_snapshots(stack)
    assert stack.count("labels", f"snapshot_id = {snapshot} AND verdict = 'is'") == 1
    assert stack.count("clips", zeros) == recordings + 1, "the clip is a recording of zero"
    screenshot(page, "scene-coaching")

    page.get_by_role("button", name="Stop coaching").click()
    page.wait_for_function("() => document.body.dataset.coaching === 'cancelled'", timeout=90_000)
    assert "your answers are kept" in page.locator("#coach-message").inner_text()
    assert stack.count("labels", f"snapshot_id = {snapshot} AND verdict = 'is'") == 1
    assert page.get_by_role("button", name="Start coaching").is_enabled()


def _coaching_snapshots(stack: Stack) -> list[int]:
    import sqlite3

    with sqlite3.connect(stack.database) as connection:
        rows = connection.execute("SELECT id FROM snapshots WHERE source = 'coaching'").fetchall()
    return [int(row[0]) for row in rows]
