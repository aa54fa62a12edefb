"""How long the Label page makes a person take per answer, by keyboard, in a real Chromium, in both modes:
pairs (Y / N) and "did it do what I said?" (Y, or N and a number). A person answers once the view is shown
and the command has been heard to its end; the test does the same, so what it measures is the page's part
of an answer: the command's playback plus the page's turn-around (store the answer, fetch and show the next),
not the person's own thinking time. The figures go to tests/artifacts/label_speed.json (bench/label_speed.py
runs this test and writes them under bench/results with the machine and load)."""

import json
import time

import pytest
from browser_helpers import ARTIFACTS, Stack, open_page, robot_with_commands, store_attempts, upload_views

pytestmark = pytest.mark.browser
WORDS = ["near", "far"]
PAIR_ANSWERS = 8
ATTEMPT_ANSWERS = 4
RESULT = ARTIFACTS / "label_speed.json"

HEARD_AND_SHOWN = """
([image, audio]) => {
  const shown = image && !image.hidden && image.complete && image.naturalWidth > 0;
  const heard = audio.ended || audio.currentTime >= audio.duration - 0.02;
  return shown && audio.src && audio.duration > 0 && heard;
}
"""


@pytest.fixture(scope="module")
def speed_robot(stack: Stack, tmp_path_factory: pytest.TempPathFactory) -> int:
    robot = robot_with_commands(
        stack, "speed arm", WORDS, tmp_path_factory.mktemp("speed-clips"), seconds=0.8
    )
    with stack.client() as alice:
        upload_views(alice, robot, PAIR_ANSWERS, seed=31)
    return robot


def _wait_heard_and_shown(page, image: str, audio: str) -> None:  # type: ignore[no-untyped-def]
    """Until the view is on screen and its command has played to the end, as a person waits."""
    handles = [page.locator(image).element_handle(), page.locator(audio).element_handle()]
    page.wait_for_function(HEARD_AND_SHOWN, arg=handles, timeout=30_000)


def _answer_all(page, count: int, image: str, audio: str, keys: list[list[str]], item: str) -> dict:  # type: ignore[no-untyped-def]
    """Answers `count` items by keyboard; seconds from the first item shown to the last answer stored."""
    _wait_heard_and_shown(page, image, audio)
    # the first command was heard before the clock started: its playback counts as if it had been timed
    started = time.perf_counter() - float(page.locator(audio).evaluate("a => a.duration"))
    playback = 0.0
    for index in range(count):
        playback += float(page.locator(audio).evaluate("a => a.duration"))
        shown = page.evaluate(f"document.body.dataset.{item} || ''")
        for key in keys[index % len(keys)]:
            page.keyboard.press(key)
            if key == "n" and item == "attempt":  # then the page asks what the view shows instead
                page.wait_for_function("() => document.body.dataset.attemptStage === 'instead'")
        page.wait_for_function(f"s => (document.body.dataset.{item} || '') !== s", arg=shown, timeout=30_000)
        if index < count - 1:
            _wait_heard_and_shown(page, image, audio)
    seconds = time.perf_counter() - started
    return {
        "answers": count,
        "seconds_per_answer": round(seconds / count, 3),
        "playback_seconds_per_answer": round(playback / count, 3),
        "page_seconds_per_answer": round((seconds - playback) / count, 3),
    }


def test_seconds_per_answer_by_keyboard_in_both_modes(page, stack: Stack, speed_robot: int) -> None:  # type: ignore[no-untyped-def]
    page.evaluate(f"localStorage.setItem('varbot.robot', '{speed_robot}')")
    labels = stack.count("labels")
    open_page(page, f"{stack.url}/label")
    pairs = _answer_all(page, PAIR_ANSWERS, "#camera", "#clip", [["y"], ["n"]], "pair")
    assert stack.count("labels") == labels + PAIR_ANSWERS, "every key press stored one answer"

    store_attempts(stack, speed_robot, [WORDS[i % 2] for i in range(ATTEMPT_ANSWERS)])
    page.keyboard.press("m")
    page.wait_for_function("() => document.body.dataset.mode === 'attempts'")
    household = f"household_id = (SELECT household_id FROM robots WHERE id = {speed_robot})"
    clips = stack.count("clips", f"deleted_at IS NULL AND {household}")  # the database holds other households
    labels = stack.count("labels")
    answers = [["y"], ["n", "1"], ["n", "0"]]
    attempts = _answer_all(page, ATTEMPT_ANSWERS, "#attempt-final", "#attempt-clip", answers, "attempt")
    assert stack.count("labels") == labels + ATTEMPT_ANSWERS * clips, "each answer labels every recording"
    page.evaluate("localStorage.removeItem('varbot.robot')")

    for figures in (pairs, attempts):
        assert figures["seconds_per_answer"] >= figures["playback_seconds_per_answer"] > 0
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    RESULT.write_text(json.dumps({"pairs": pairs, "attempts": attempts}, indent=2) + "\n")
