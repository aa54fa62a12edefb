"""Every page on a phone (390×844) and a desktop (1280×800), in light and dark: nothing scrolls sideways, the
Label page shows the camera image and the answer buttons together, dark mode follows the browser, and "?"
lists a page's shortcuts. Each page's screenshot at both sizes goes to tests/artifacts/screens/."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from browser_helpers import ARTIFACTS, ConsoleWatch, Stack, open_page, sign_in
from newcomers import Newcomers, add_robot, answer, capture_views, new_household, record_commands, write_rows
from test_browser_pages import CONTRAST_CHECK

pytestmark = pytest.mark.browser
PAGES = ["", "record", "label", "progress", "household", "admin", "scene", "login"]  # "" is the Start page
PHONE = {"width": 390, "height": 844}
DESKTOP = {"width": 1280, "height": 800}
SCREENS = ARTIFACTS / "screens"


@pytest.fixture(scope="module")
def furnished(stack: Stack, tmp_path_factory: pytest.TempPathFactory) -> Newcomers:
    """A household some way in: a robot, four commands, answered views, a finished run, model versions."""
    household = new_household(stack, "Pia")
    robot = add_robot(stack, household)
    folder: Path = tmp_path_factory.mktemp("voices")
    clips = record_commands(stack, household, ["zero", "one", "two", "three"], times=2, folder=folder)
    views = capture_views(stack, household, robot, 6)
    answer(stack, household, views[:3], positive=clips[0], negative=clips[2])
    summary = "Better: *zero* now works in 8 of 10 tries, was 3 of 10; the new version is active."
    gate = {"promoted": True, "verdict": "better", "reasons": ["beyond chance"], "summary": summary}
    curve = [{"epoch": e, "loss": 1 / (e + 1), "accuracy": 0.5 + e / 20} for e in range(8)]
    run = {"kind": "finetune", "preset": "quick", "status": "succeeded", "stage": "done", "progress": 1.0,
           "metrics": {"gate": gate, "curves": {"var_finetune": curve}}}  # fmt: skip
    write_rows(stack, robot, runs=[run], versions=["base version", "first retraining"])
    return household


@pytest.fixture
def tab_of(browser, stack: Stack, furnished: Newcomers, console: ConsoleWatch) -> Iterator[object]:
    """tab_of(viewport, scheme): a signed-in tab of the furnished household's admin."""
    contexts = []

    def open_tab(viewport: dict, scheme: str = "light") -> object:
        phone = viewport == PHONE
        context = browser.new_context(
            viewport=viewport, is_mobile=phone, has_touch=phone, color_scheme=scheme
        )
        contexts.append(context)
        context.on("page", console.attach)
        tab = context.new_page()
        sign_in(tab, stack.url, furnished.username)
        return tab

    yield open_tab
    for context in contexts:
        context.close()
    assert console.errors == [], "console errors:\n" + "\n".join(console.errors)


def settle(page: object, stack: Stack, name: str) -> None:
    open_page(page, f"{stack.url}/{name}")
    page.wait_for_load_state("networkidle")  # type: ignore[attr-defined]
    if name == "":
        page.locator("body[data-checked=true]").wait_for(state="attached")  # type: ignore[attr-defined]
    if name == "label":
        camera = page.locator("#camera")  # type: ignore[attr-defined]
        camera.wait_for()
        page.wait_for_function(
            "() => { const i = document.getElementById('camera'); return i.complete && i.naturalWidth > 0; }"
        )  # type: ignore[attr-defined]


def sideways(page: object) -> int:
    return page.evaluate("document.documentElement.scrollWidth - document.documentElement.clientWidth")  # type: ignore[attr-defined]


def on_screen(page: object, selector: str) -> bool:
    """The whole element lies inside the viewport, without scrolling."""
    box = page.locator(selector).first.bounding_box()  # type: ignore[attr-defined]
    size = page.viewport_size  # type: ignore[attr-defined]
    return bool(box) and box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= size["width"] + 0.5 \
        and box["y"] + box["height"] <= size["height"] + 0.5  # fmt: skip


def shoot(page: object, name: str) -> None:
    """The whole page, except Label's: there what fits on the screen is the point."""
    SCREENS.mkdir(parents=True, exist_ok=True)
    whole = not name.startswith("label")
    page.screenshot(path=str(SCREENS / f"{name}.png"), full_page=whole)  # type: ignore[attr-defined]


@pytest.mark.parametrize(("size", "viewport"), [("phone", PHONE), ("desktop", DESKTOP)])
def test_no_page_scrolls_sideways_and_each_is_photographed(
    tab_of, stack: Stack, size: str, viewport: dict
) -> None:
    page = tab_of(viewport)
    problems = []
    for name in PAGES:
        settle(page, stack, name)
        if sideways(page) > 0:
            problems.append(f"/{name} scrolls sideways by {sideways(page)} px")
        if not on_screen(page, "main h1"):
            problems.append(f"/{name}: its title is not on screen")
        shoot(page, f"{name or 'start'}-{size}")
    assert problems == [], "\n".join(problems)


def test_the_label_page_shows_the_image_and_the_answers_together_on_a_phone(tab_of, stack: Stack) -> None:
    page = tab_of(PHONE)
    settle(page, stack, "label")
    for selector in ("#camera", "#yes", "#no"):
        assert on_screen(page, selector), f"{selector} is not on screen with the rest"
    assert page.locator("#camera").bounding_box()["height"] > 150  # still big enough to judge


def test_dark_mode_follows_the_browser_and_keeps_text_readable(tab_of, stack: Stack) -> None:
    page = tab_of(PHONE, "dark")
    problems = []
    for name in PAGES:
        settle(page, stack, name)
        background = page.evaluate("getComputedStyle(document.documentElement).backgroundColor")
        if background in ("rgb(243, 245, 248)", "rgb(255, 255, 255)"):
            problems.append(f"/{name} stays light: {background}")
        problems += [f"/{name}: low contrast {item}" for item in page.evaluate(CONTRAST_CHECK)]
        if name in ("", "label", "progress"):
            shoot(page, f"{name or 'start'}-phone-dark")
    assert problems == [], "\n".join(problems)


def test_question_mark_lists_the_shortcuts_of_the_page(tab_of, stack: Stack) -> None:
    page = tab_of(DESKTOP)
    settle(page, stack, "label")
    page.keyboard.press("?")
    dialog = page.get_by_role("dialog", name="Keyboard shortcuts")
    dialog.wait_for()
    listed = dialog.inner_text()
    for key, what in (("Y", "It is"), ("N", "It is not"), ("R", "Replay"), ("S", "Skip"), ("Z", "Undo")):
        assert key in listed and what in listed, listed
    page.keyboard.press("Escape")
    dialog.wait_for(state="hidden")
    settle(page, stack, "record")
    page.get_by_role("button", name="Keyboard shortcuts").click()
    assert "Hold to record, let go to stop" in page.get_by_role("dialog").inner_text()
    page.get_by_role("button", name="Close").click()
    settle(page, stack, "household")  # nothing to list
    assert page.get_by_role("button", name="Keyboard shortcuts").count() == 0
