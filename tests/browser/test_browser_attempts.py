"""The Label page's "did it do what I said?" mode in a real Chromium, by keyboard only: the robot's attempt
(final view, a cycling replay) and its command play; Y, or N then a number key (or 0 for nothing); undo; and
on a phone the view and the answers are on screen together. The attempts are stored as the robot worker
stores them (`worker.attempts`, tested in tests/worker), from real views of the simulated Kuka."""

import pytest
from browser_helpers import Stack, open_page, robot_with_commands, screenshot, sign_in, store_attempts

from varbot.services import wait_until

pytestmark = pytest.mark.browser
WORDS = ["zero", "one", "two"]


@pytest.fixture(scope="module")
def attempt_robot(stack: Stack, tmp_path_factory: pytest.TempPathFactory) -> int:
    return robot_with_commands(stack, "attempt arm", WORDS, tmp_path_factory.mktemp("attempt-clips"))


def _recordings(stack: Stack, name: str) -> int:
    return stack.count("clips", f"deleted_at IS NULL AND lower(trim(name)) = '{name}'")


def _attempt_shown(page) -> str:  # type: ignore[no-untyped-def]
    return str(page.evaluate("document.body.dataset.attempt || ''"))


def _next_attempt_after(page, shown: str) -> None:  # type: ignore[no-untyped-def]
    page.wait_for_function(f"() => (document.body.dataset.attempt || '') !== '{shown}'")


def test_judging_attempts_by_keyboard_stores_full_labels_and_undo_takes_them_back(
    page, stack: Stack, attempt_robot: int
) -> None:  # type: ignore[no-untyped-def]
    store_attempts(stack, attempt_robot, ["zero", "one", "two"])
    clips = stack.count("clips", "deleted_at IS NULL")
    page.evaluate(f"localStorage.setItem('varbot.robot', '{attempt_robot}')")
    open_page(page, f"{stack.url}/label")
    page.keyboard.press("m")
    page.wait_for_function("() => document.body.dataset.mode === 'attempts'")
    final = page.locator("#attempt-final")
    final.wait_for()
    wait_until(lambda: final.evaluate("img => img.complete && img.naturalWidth > 0"), 10, "the final view")
    page.wait_for_function("() => document.getElementById('attempt-clip').currentTime > 0", timeout=10_000)
    replay = page.locator("#attempt-replay")
    first_frame = replay.get_attribute("src")
    page.wait_for_function(
        "first => document.getElementById('attempt-replay').getAttribute('src') !== first", arg=first_frame
    )  # the replay cycles through the attempt's frames
    assert page.locator("#attempt-command").inner_text() == "The robot was asked: “zero”"
    labels = stack.count("labels")

    shown = _attempt_shown(page)
    page.keyboard.press("y")  # yes, that's it
    _next_attempt_after(page, shown)
    page.get_by_text("Saved: it shows “zero”.").wait_for()
    assert stack.count("labels") == labels + clips, "one answer labels the view for every recording"
    assert stack.count("labels", f"snapshot_id = {shown} AND verdict = 'is'") == _recordings(stack, "zero")

    shown = _attempt_shown(page)
    assert page.locator("#attempt-command").inner_text() == "The robot was asked: “one”"
    page.keyboard.press("n")
    page.wait_for_function("() => document.body.dataset.attemptStage === 'instead'")
    assert page.locator("#attempt-instead").is_visible()
    choices = [
        text.rsplit(maxsplit=1) for text in page.locator("#attempt-instead-choices button").all_inner_texts()
    ]
    assert [key for _, key in choices] == [*map(str, range(1, len(choices))), "0"]
    assert choices[-1][0] == "nothing we said" and "one" not in [name for name, _ in choices]
    instead = choices[0][0]
    page.keyboard.press("1")  # it shows the first other command instead
    _next_attempt_after(page, shown)
    page.get_by_text(f"Saved: it shows “{instead}”.").wait_for()
    assert stack.count("labels", f"snapshot_id = {shown} AND verdict = 'is'") == _recordings(stack, instead)
    assert stack.count("labels") == labels + 2 * clips

    shown = _attempt_shown(page)
    page.keyboard.press("n")
    page.wait_for_function("() => document.body.dataset.attemptStage === 'instead'")
    page.keyboard.press("0")  # nothing we said
    page.get_by_text("Saved: it shows nothing we said.").wait_for()
    assert stack.count("labels", f"snapshot_id = {shown} AND verdict = 'is_not'") == clips
    page.get_by_text("no attempts left to judge").wait_for()

    page.keyboard.press("z")
    page.get_by_text("Undone: answer this attempt again.").wait_for()
    assert _attempt_shown(page) == shown
    assert stack.count("labels") == labels + 2 * clips, "undo removed every label of the last answer"
    screenshot(page, "label-attempts")
    page.keyboard.press("s")
    page.get_by_text("Skipped.").wait_for()
    page.evaluate("localStorage.removeItem('varbot.robot')")


def test_on_a_phone_the_attempt_and_its_answers_are_on_screen_together(
    browser, stack: Stack, attempt_robot: int
) -> None:  # type: ignore[no-untyped-def]
    store_attempts(stack, attempt_robot, ["one"])
    context = browser.new_context(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
    page = context.new_page()
    sign_in(page, stack.url)
    page.evaluate(f"localStorage.setItem('varbot.robot', '{attempt_robot}')")
    open_page(page, f"{stack.url}/label")
    page.get_by_role("button", name="Did it do what I said?").click()
    final = page.locator("#attempt-final")
    final.wait_for()
    wait_until(lambda: final.evaluate("img => img.complete && img.naturalWidth > 0"), 10, "the final view")
    for control in (final, page.locator("#attempt-yes"), page.locator("#attempt-no")):
        box = control.bounding_box()
        assert box is not None and box["y"] >= 0 and box["y"] + box["height"] <= 844, box
    assert page.evaluate("document.documentElement.scrollWidth <= document.documentElement.clientWidth")
    screenshot(page, "label-attempts-phone")
    page.evaluate("localStorage.removeItem('varbot.robot')")
    context.close()
