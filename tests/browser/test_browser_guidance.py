"""A new household is guided: the Start page's checklist ticks itself off from what the household really has,
every empty page says what to do next, and a recording goes to a command the household already has."""

import re
from pathlib import Path

import pytest
from browser_helpers import PASSWORD, ConsoleWatch, Stack, open_page, sign_in
from newcomers import add_robot, answer, capture_views, new_household, record_commands
from test_browser_pages import keep_holding

pytestmark = pytest.mark.browser
WORDS = ["zero", "one", "two", "three"]  # a Kuka knows four targets: one command each


@pytest.fixture
def newcomer_tab(browser, stack: Stack, console: ConsoleWatch):  # type: ignore[no-untyped-def]
    """A signed-in tab of the admin of a brand-new household, and that household."""
    household = new_household(stack)
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    context.on("page", console.attach)
    tab = context.new_page()
    sign_in(tab, stack.url, household.username)
    yield tab, household
    context.close()
    assert console.errors == [], "console errors:\n" + "\n".join(console.errors)


def checklist(page, stack: Stack) -> dict[str, bool]:
    """The Start page's steps, by title, and whether each is ticked off."""
    open_page(page, f"{stack.url}/")
    page.locator("body[data-checked=true]").wait_for(state="attached")
    steps = page.locator("#checklist > li")
    return {
        steps.nth(i).locator("h3").evaluate("h => h.firstChild.textContent"): steps.nth(i).get_attribute(
            "data-done"
        )
        == "true"
        for i in range(steps.count())
    }


def test_the_checklist_ticks_itself_off_as_the_household_gets_going(
    newcomer_tab, stack: Stack, tmp_path: Path
):
    page, household = newcomer_tab
    page.context.clear_cookies()
    open_page(page, f"{stack.url}/login")
    page.get_by_label("Username").fill(household.username)
    page.get_by_label("Password").fill(PASSWORD)
    page.get_by_role("button", name="Sign in").click()
    page.wait_for_url(f"{stack.url}/")  # signing in lands on the Start page
    assert list(checklist(page, stack).values()) == [False] * 5
    assert "add a robot" in page.locator("#next-step").inner_text()
    assert page.get_by_role("link", name="Add a robot →").get_attribute("href") == "/admin"

    robot = add_robot(stack, household)
    steps = checklist(page, stack)
    assert steps["Add a robot"] and not steps["Record each command twice"]
    assert "knows 4 targets" in page.locator("#checklist").inner_text()

    clips = record_commands(stack, household, WORDS, times=1, folder=tmp_path)
    assert not checklist(page, stack)["Record each command twice"]
    assert "record “zero”, “one”, “two”, “three” again" in page.locator("#checklist").inner_text()
    record_commands(stack, household, WORDS, times=1, folder=tmp_path)
    assert checklist(page, stack)["Record each command twice"]

    views = capture_views(stack, household, robot, 3)
    assert checklist(page, stack)["Capture camera views"]
    answer(stack, household, views, positive=clips[0], negative=clips[1])
    steps = checklist(page, stack)
    assert list(steps.values()) == [True, True, True, True, False]
    assert "Next: step 5, train" in page.locator("#next-step").inner_text()
    assert page.get_by_role("link", name="Train →").get_attribute("href") == "/admin"


def test_empty_pages_say_what_to_do_next(newcomer_tab, stack: Stack, tmp_path: Path) -> None:
    page, household = newcomer_tab
    open_page(page, f"{stack.url}/label")
    page.get_by_text("No robot yet: an admin of your household adds one on the Admin page").wait_for()
    assert page.locator("#camera").is_hidden()  # no black box with a broken image
    robot = add_robot(stack, household)
    open_page(page, f"{stack.url}/label")
    page.get_by_text("Nothing to ask yet: record a command first").wait_for()
    assert page.get_by_role("link", name="Record a command").is_visible()
    record_commands(stack, household, ["zero"], times=1, folder=tmp_path)
    open_page(page, f"{stack.url}/label")
    page.get_by_text("No camera views of kitchen arm yet: capture some").wait_for()
    assert page.get_by_role("button", name="Capture more views").is_visible()
    assert page.locator("#camera").is_hidden()
    assert robot
    open_page(page, f"{stack.url}/progress")
    page.get_by_text("No training runs yet").wait_for()
    open_page(page, f"{stack.url}/admin")
    page.get_by_text("No model versions for kitchen arm yet").wait_for()


def test_a_recording_goes_to_a_command_the_household_already_has(
    newcomer_tab, stack: Stack, tmp_path: Path
) -> None:
    page, household = newcomer_tab
    add_robot(stack, household)
    record_commands(stack, household, ["zero"], times=1, folder=tmp_path)
    open_page(page, f"{stack.url}/record")
    page.get_by_text("kitchen arm knows 4 targets").wait_for()
    zero = page.locator("#commands li[data-command='zero']")
    assert "1 recording (Nina 1)" in zero.inner_text()
    page.get_by_label("Which command is this?").select_option("zero")
    assert page.locator("#clip-name").is_hidden()  # no new name to type
    page.get_by_role("button", name="Hold to talk").focus()
    page.keyboard.down("Space")
    page.get_by_text("Recording…", exact=True).wait_for()
    keep_holding(page, seconds=1.2)
    page.keyboard.up("Space")
    page.get_by_role("button", name="Keep it").click()
    page.get_by_text(re.compile(r"Kept: recording \d+ of “zero”")).wait_for()
    assert (
        stack.count(
            "clips",
            f"name = 'zero' AND speaker_id IN (SELECT id FROM users WHERE username = '{household.username}')",
        )
        == 2
    )
    zero.get_by_text("2 recordings (Nina 2)").wait_for()
    assert page.get_by_label("Which command is this?").input_value() == "zero"  # the next take goes there too


def test_label_counts_triplets_per_command_and_per_member(newcomer_tab, stack: Stack, tmp_path: Path) -> None:
    page, household = newcomer_tab
    robot = add_robot(stack, household)
    zero, one = record_commands(stack, household, ["zero", "one"], times=1, folder=tmp_path)
    answer(stack, household, capture_views(stack, household, robot, 3), positive=zero, negative=one)
    open_page(page, f"{stack.url}/label")
    per_command = page.locator("#per-command")
    per_command.get_by_text("zero").wait_for()
    assert per_command.inner_text().split("\n") == ["3 zero"]
    assert page.locator("#per-member").inner_text().split("\n") == ["3 Nina"]
