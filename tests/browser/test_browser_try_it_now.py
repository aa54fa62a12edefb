"""Try it now, with a live voice, in Chromium with a fake microphone that says "zero": on the Record page
(hold Space) and on the Scene page (hold the button), the household's robot, in its scene, carries out what
was just said. The page answers in words at once, then says how the robot is doing and where it ended in the
household's command words; the clip is not kept. The Scene page also explains its sphere with a legend in
the household's words and lets a member choose which of the household's robots it shows."""

import json
import re
import tempfile
import time
from pathlib import Path

import pytest
from browser_helpers import (
    ARTIFACTS,
    SCENE_VIEWPORT,
    Stack,
    activate_untrained_model,
    open_page,
    speech_wav,
    upload_clip,
    upload_views,
)
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from test_browser_pages import keep_holding

pytestmark = pytest.mark.browser
PAGE_VIEWPORT = SCENE_VIEWPORT  # `browser_helpers.viewport_of`

TIMINGS = ARTIFACTS / "try-it-now.json"
FINISHED = ("done", "refused", "failed")

# Records, in the page, when the button or key was let go and when the try's message first showed each state
# (try_now.js sets data-try-state with each message), so that the measurement adds no round trips.
WATCH_TRY = """(message) => {
    const times = { states: {} };
    window.__try = times;
    const released = () => { if (times.released === undefined) times.released = performance.now(); };
    // capture phase: before the page's own handlers send the take (and change the message)
    window.addEventListener('pointerup', released, true);
    window.addEventListener('keyup', released, true);
    new MutationObserver(() => {
        const state = document.getElementById(message).dataset.tryState;
        if (times.released !== undefined && state && times.states[state] === undefined) {
            times.states[state] = { ms: performance.now() - times.released,
                                    text: document.getElementById(message).textContent };
        }
    }).observe(document.getElementById(message), { attributes: true, childList: true, subtree: true });
}"""


@pytest.fixture(scope="module")
def household_with_a_model(stack: Stack, robot_id: int) -> Stack:
    """Alice's household says "zero" and "three", has views, and its robot an active (untrained) model."""
    folder = Path(tempfile.mkdtemp(prefix="vb-try-"))
    with stack.client() as alice:
        upload_views(alice, robot_id, 6, seed=31)
        for word in ("zero", "three"):
            upload_clip(alice, speech_wav(word, folder / f"{word}.wav").read_bytes(), word)
    activate_untrained_model(stack, robot_id)
    return stack


def choose_robot_on_every_page(page, robot_id: int) -> None:  # type: ignore[no-untyped-def]
    page.evaluate("id => localStorage.setItem('varbot.robot', String(id))", robot_id)


def follow_try(page, message_id: str) -> dict:  # type: ignore[no-untyped-def]
    """Until the try ends (the scene may still have to start: up to 3 minutes); what the page measured."""
    ended = f"{json.dumps(list(FINISHED))}.includes(document.getElementById('{message_id}').dataset.tryState)"
    try:
        page.wait_for_function(f"() => {ended}", timeout=180_000)
    except PlaywrightTimeout as error:
        said = page.locator(f"#{message_id}").inner_text()
        raise AssertionError(f"the try did not end in 3 minutes; the page says: {said!r}") from error
    return page.evaluate("window.__try")


def assert_said_before_the_server_answered(measured: dict) -> None:
    """The first words ("Starting…") do not wait for the network: they come before any state the server's
    answer brings. How many milliseconds that is (11-50 on a quiet machine) is kept in TIMINGS, not asserted:
    on a loaded machine the browser itself can be late."""
    states = measured["states"]
    later = [state["ms"] for name, state in states.items() if name != "sending"]
    assert states["sending"]["ms"] <= min(later), measured


def save_timings(name: str, measured: dict) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    found = json.loads(TIMINGS.read_text()) if TIMINGS.exists() else {}
    found[name] = measured
    TIMINGS.write_text(json.dumps(found, indent=1))


def test_on_the_record_page_the_robot_carries_out_what_was_just_said_and_nothing_is_kept(
    page, household_with_a_model: Stack, robot_id: int
) -> None:  # type: ignore[no-untyped-def]
    stack = household_with_a_model
    choose_robot_on_every_page(page, robot_id)
    open_page(page, f"{stack.url}/record")
    clips_before = stack.count("clips")
    page.get_by_label("Try it now").check()
    assert page.get_by_text("Nothing is kept").is_visible()
    page.evaluate(WATCH_TRY, "try-message")
    page.get_by_role("button", name="Hold to talk").focus()
    page.keyboard.down("Space")
    page.get_by_text("Recording…", exact=True).wait_for()
    keep_holding(page, seconds=1.6)
    page.keyboard.up("Space")
    measured = follow_try(page, "try-message")
    save_timings("record page", measured)
    print("record page:", measured)

    first = measured["states"]["sending"]
    assert first["text"].startswith("Starting…"), first
    assert_said_before_the_server_answered(measured)
    final = page.locator("#try-message")
    assert final.get_attribute("data-try-state") == "done", final.inner_text()
    words = final.inner_text()
    assert words.startswith("Done with what you said"), words
    assert re.search(r"looks most like “[^”]+”|cannot tell which of your commands", words), words
    assert "running" in measured["states"], "the page said how the robot was doing on the way"
    assert stack.count("clips") == clips_before, "a try is not kept as a recording"
    assert page.locator("#review").is_hidden(), "nothing is offered for keeping"


def test_on_the_scene_page_a_held_button_drives_the_robot_and_the_sphere_has_a_legend(
    page, household_with_a_model: Stack
) -> None:  # type: ignore[no-untyped-def]
    stack = household_with_a_model
    page.goto(f"{stack.url}/scene")
    frame = page.frame_locator("#scene")
    frame.get_by_text("What the sphere shows").first.wait_for(timeout=180_000)
    legend = frame.locator(".varbot-legend")
    legend.wait_for(timeout=60_000)
    frame.locator(".varbot-legend", has_text="“zero”").wait_for(timeout=60_000)
    text = legend.inner_text()
    for meaning in ("“three”", "the robot's view right now", "your recordings", "closest to none"):
        assert meaning in text, text

    for attempt in ("first", "second"):
        page.evaluate(WATCH_TRY, "scene-try-message")
        button = page.get_by_role("button", name="Hold to tell the robot")
        box = button.bounding_box()
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        message = page.locator("#scene-try-message")
        message.get_by_text("Listening…").wait_for()  # never the last try's outcome while talking
        keep_holding(page, seconds=1.6)
        page.mouse.up()
        measured = follow_try(page, "scene-try-message")
        save_timings(f"scene page, {attempt} try", measured)
        print(f"scene page, {attempt} try:", measured)
        assert_said_before_the_server_answered(measured)
        assert message.get_attribute("data-try-state") == "done", message.inner_text()
        assert message.inner_text().startswith("Done with what you said")
    frame.get_by_text(re.compile(r"Done with what you said")).first.wait_for(timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "scene-try-it-now.png"), full_page=True)


def test_a_member_chooses_which_of_the_households_robots_the_scene_shows(
    page, household_with_a_model: Stack, robot_id: int
) -> None:  # type: ignore[no-untyped-def]
    stack = household_with_a_model
    with stack.client() as alice:
        robots = alice.get("/robots").json()
        rover = next((r for r in robots if r["name"] == "hall rover"), None)
        if rover is None:
            rover = alice.post("/robots", json={"name": "hall rover", "kind": "turtlebot-sim"}).json()
    page.goto(f"{stack.url}/scene")
    frame = page.frame_locator("#scene")
    frame.get_by_text("kitchen arm").first.wait_for(timeout=180_000)  # the robot whose model was made active
    choice = page.get_by_label("Robot shown", exact=True)
    page.wait_for_function("() => document.querySelectorAll('#scene-robot option').length > 2")
    try:
        choice.select_option(str(rover["id"]))
        frame.get_by_text("hall rover").first.wait_for(timeout=120_000)
        page.reload()
        page.locator("#scene-robot").wait_for()
        page.wait_for_function(
            f"() => document.getElementById('scene-robot').value === '{rover['id']}'", timeout=60_000
        )
    finally:
        page.get_by_label("Robot shown", exact=True).select_option(
            str(robot_id)
        )  # as the other tests expect it
        frame.get_by_text("kitchen arm").first.wait_for(timeout=120_000)


def test_a_version_made_active_reaches_the_open_scene_at_once(
    page, household_with_a_model: Stack, robot_id: int
) -> None:  # type: ignore[no-untyped-def]
    """Rolling back and activating again, through the API, while the Scene page is open: each change shows
    in the scene's status line; how long it took is measured from the API call (the scene re-read its data
    only every 5 s before, and 21 s were seen)."""
    stack = household_with_a_model
    newest = activate_untrained_model(stack, robot_id)  # a version to come back to; not timed
    page.goto(f"{stack.url}/scene")
    frame = page.frame_locator("#scene")

    def shows(version: int) -> None:
        frame.get_by_text(re.compile(rf"model version {version}\b")).first.wait_for(timeout=120_000)

    shows(newest)
    delays = {}
    with stack.client() as alice:
        for step in ("rollback", "activate again"):
            started = time.monotonic()
            if step == "rollback":
                answer = alice.post(f"/robots/{robot_id}/models:rollback")
            else:
                answer = alice.post(f"/models/{newest}:activate")
            answer.raise_for_status()
            shows(answer.json()["id"])
            delays[step] = round(time.monotonic() - started, 2)
    save_timings("activation to the open scene's status line (s)", delays)
    print("activation reached the open scene:", delays)
