"""The pages speak plainly: training stages in words, a bar that is full only when the run is done, no "minute
left" at the end, a verdict in sentences with the household's command words (and one for runs from before
the gate wrote sentences), chart axes around the data, and form errors as sentences."""

import re

import pytest
from browser_helpers import ConsoleWatch, Stack, open_page, sign_in
from newcomers import add_robot, new_household, write_rows

pytestmark = pytest.mark.browser

FLAT_CURVE = [{"epoch": epoch, "loss": 1.0 / (epoch + 1), "accuracy": 0.714} for epoch in range(6)]
TODAYS_GATE = {
    "promoted": False,
    "verdict": "no_change",
    "summary": "No measurable change; kept the old version.",
    "reasons": ["triplet accuracy 0.714 vs 0.714: within chance (±0.143)"],
}
BETTER_GATE = {
    "promoted": True,
    "verdict": "better",
    "summary": "Better: *two* now works in 8 of 10 tries, was 3 of 10; the new version is active.",
    "reasons": ["simulated success of two 0.8 vs 0.3: beyond chance"],
}
OLDER_GATE = {"promoted": True, "reasons": ["candidate 0.8 vs active 0.7 (not worse, tolerance 0.143)"]}
OLDER_EVALUATION = {
    "candidate": {"triplet_accuracy": 0.8, "held_out_triplets": 10, "sim_success": None, "sim_episodes": 0},
    "active": {"triplet_accuracy": 0.7, "held_out_triplets": 10, "sim_success": None, "sim_episodes": 0},
}


def finished(gate: dict, evaluation: dict | None = None) -> dict:
    metrics = {"gate": gate, "curves": {"var_finetune": FLAT_CURVE}, "evaluation": evaluation or {}}
    return {"kind": "finetune", "preset": "quick", "status": "succeeded", "stage": "done", "progress": 1.0,
            "metrics": metrics}  # fmt: skip


@pytest.fixture
def newcomer(browser, stack: Stack, console: ConsoleWatch):  # type: ignore[no-untyped-def]
    household = new_household(stack, "Olga")
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    context.on("page", console.attach)
    tab = context.new_page()
    sign_in(tab, stack.url, household.username)
    yield tab, household, add_robot(stack, household, "hall arm")
    context.close()
    assert console.errors == [], "console errors:\n" + "\n".join(console.errors)


def test_progress_speaks_in_words_and_is_honest_at_the_end(newcomer, stack: Stack) -> None:
    page, _, robot = newcomer
    at_the_end = {"kind": "finetune", "preset": "quick", "status": "running", "stage": "evaluate",
                  "progress": 1.0, "timings": {"eta_s": 60}}  # fmt: skip
    testing, better, same, older = write_rows(
        stack,
        robot,
        runs=[
            at_the_end,
            finished(BETTER_GATE),
            finished(TODAYS_GATE),
            finished(OLDER_GATE, OLDER_EVALUATION),
        ],
    )
    open_page(page, f"{stack.url}/progress")
    card = page.locator(f"[data-run-id='{testing}']")
    line = card.locator("p.muted").first.inner_text()
    assert "testing the new version" in line and "evaluate" not in line, line
    assert "finishing up" in line and "min left" not in line, line  # the bar is full: no minute left
    assert float(card.locator("progress").get_attribute("value") or 0) < 1  # full only once the run is done
    assert "learn your words, practise, test" in card.locator("h2").inner_text()

    better_verdict = page.locator(f"[data-run-id='{better}'] .message.verdict")
    assert (
        better_verdict.inner_text()
        == "Better: two now works in 8 of 10 tries, was 3 of 10; the new version is active."
    )
    assert better_verdict.locator("strong").inner_text() == "two"  # the household's word for the target
    assert "ok" in (better_verdict.get_attribute("class") or "")
    same_card = page.locator(f"[data-run-id='{same}']")
    assert same_card.locator(".message.verdict").inner_text() == "No measurable change; kept the old version."
    assert "ok" not in (same_card.locator(".message.verdict").get_attribute("class") or "")  # not green
    same_card.locator("details.reasons summary").click()
    assert "within chance" in same_card.locator("details.reasons").inner_text()
    assert float(same_card.locator("progress").get_attribute("value") or 0) == 1
    older_verdict = page.locator(f"[data-run-id='{older}'] .message.verdict").inner_text()
    assert older_verdict == "It matches 8 of 10 held-out answers, was 7 of 10; the new version is active."


def test_a_flat_line_gets_an_axis_around_it(newcomer, stack: Stack) -> None:
    page, _, robot = newcomer
    (run,) = write_rows(stack, robot, runs=[finished(TODAYS_GATE)])
    open_page(page, f"{stack.url}/progress")
    success = page.locator(f"[data-run-id='{run}'] svg.chart[aria-label^='Success']")
    assert (success.get_attribute("data-y-from"), success.get_attribute("data-y-to")) == ("0", "1")  # a rate
    ticks = success.locator("text.y-tick").all_text_contents()
    assert ticks[0] == "0" and ticks[-1] == "1", ticks
    axis = page.evaluate(
        """async () => { const { yAxis } = await import('/static/js/chart.js');
            return [yAxis([0.714, 0.714]), yAxis([3, 3]), yAxis([0, 0]), yAxis([-0.2, 0.9], [0, 1])]; }"""
    )
    flat, three, zero, outside = axis
    assert 0.6 <= flat["from"] < 0.714 < flat["to"] <= 0.8, flat  # never -0.286 .. 1.71
    assert 2.5 <= three["from"] < 3 < three["to"] <= 3.5, three
    assert zero["from"] < 0 < zero["to"] <= 0.2, zero
    assert outside["from"] <= -0.2 and outside["to"] >= 0.9, outside  # data outside the range widen it


def test_form_errors_are_sentences(newcomer, stack: Stack, console: ConsoleWatch) -> None:
    console.expect("status of 422")
    page, _, _ = newcomer
    open_page(page, f"{stack.url}/household")
    page.get_by_label("Name", exact=True).fill("Pat")
    page.get_by_label("Username").fill("Pat Smith!")
    page.get_by_label("First password").fill("short")
    page.get_by_role("button", name="Add member").click()
    message = page.locator("#invite-message")
    message.get_by_text("The username may hold only lower-case letters").wait_for()
    text = message.inner_text()
    assert "The password must be at least 8 characters long." in text, text
    assert "String should" not in text and "^[a-z0-9]" not in text, text


def test_a_rollback_that_cannot_happen_names_the_robot(newcomer, stack: Stack, console: ConsoleWatch) -> None:
    console.expect("status of 409")
    page, _, robot = newcomer
    write_rows(stack, robot, versions=["first version"])
    open_page(page, f"{stack.url}/admin")
    page.get_by_role("button", name="Roll back to the previous version").click()
    message = page.locator("#models-message")
    message.get_by_text(re.compile("hall arm")).wait_for()
    assert f"robot {robot}" not in message.inner_text()
