"""The pages in a real Chromium: sign in, record with a fake microphone, label by keyboard, household, admin
and progress (live through Server-Sent Events), accessibility basics. Screenshots go to tests/artifacts/.

The pages' Content-Security-Policy refuses strings evaluated as code, so wait_for_function gets functions."""

import re
from pathlib import Path

import pytest
from browser_helpers import (
    PASSWORD,
    ConsoleWatch,
    Stack,
    launch,
    open_page,
    screenshot,
    sign_in,
    silent_wav,
    tone_wav,
    upload_clip,
    upload_views,
    wait_until_ready,
)
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from varbot.services import wait_until, worker_service

pytestmark = pytest.mark.browser
PAGES = ["record", "label", "progress", "household", "admin", "scene"]


def test_sign_in_explains_a_wrong_password_then_opens_the_record_page(browser, stack: Stack) -> None:
    context = browser.new_context()
    console = ConsoleWatch()
    context.on("page", console.attach)
    page = context.new_page()
    page.goto(f"{stack.url}/record")
    page.wait_for_url(re.compile(r"/login\?next="))  # signed out: sent to sign in, and back afterwards
    wait_until_ready(page)
    page.get_by_label("Username").fill("alice")
    page.get_by_label("Password").fill("not the password")
    page.get_by_role("button", name="Sign in").click()
    page.get_by_text("Wrong username or password").wait_for()
    screenshot(page, "sign-in")
    page.get_by_label("Password").fill(PASSWORD)
    page.get_by_role("button", name="Sign in").click()
    page.wait_for_url(f"{stack.url}/record")
    page.get_by_role("button", name="Sign out").click()
    page.wait_for_url(re.compile(r"/login"))
    context.close()
    assert [e for e in console.errors if "status of 401" not in e] == []  # only the signed-out visit's 401


def test_recording_with_the_microphone_keeps_a_clip_that_plays(page, stack: Stack) -> None:
    before = stack.count("clips")
    page.get_by_label("What you say").fill("zero")
    page.get_by_role("button", name="Hold to talk").focus()
    page.keyboard.down("Space")
    page.get_by_text("Recording…", exact=True).wait_for()
    # the meter follows the voice while the button is held
    page.wait_for_function(
        "() => Number(document.querySelector('[role=meter]').getAttribute('aria-valuenow')) > 5"
    )
    keep_holding(page, seconds=1.6)
    page.keyboard.up("Space")
    page.get_by_text(re.compile(r"Recorded \d\.\d s")).wait_for()
    preview_seconds = page.evaluate(
        """async () => { const a = document.getElementById('take-audio');
            await new Promise(r => a.readyState >= 1 ? r() : a.addEventListener('loadedmetadata', r));
            return a.duration; }"""
    )
    assert 1.2 < preview_seconds < 3.0
    page.get_by_role("button", name="Keep it").click()
    kept = page.get_by_text(re.compile(r"Kept: recording \d+"))
    kept.wait_for()
    assert stack.count("clips") == before + 1
    # "Kept" is said once the list shows the recording: play the one just kept
    clip_id = re.search(r"Kept: recording (\d+)", kept.inner_text()).group(1)  # type: ignore[union-attr]
    audio = page.locator(f"#clips li[data-clip-id='{clip_id}'] audio").element_handle(timeout=1000)
    audio.evaluate("a => { a.play(); }")
    page.wait_for_function("a => a.currentTime > 0.2 || a.error !== null", arg=audio)
    assert audio.evaluate("a => a.error && a.error.code") is None
    screenshot(page, "record")


def test_a_server_rejection_is_shown_in_plain_words(page, console: ConsoleWatch, tmp_path: Path) -> None:
    console.expect("status of 422 (Unprocessable Entity) (http://127.0.0.1")
    too_short = tone_wav(tmp_path / "short.wav", seconds=0.1)
    page.locator("details summary").click()
    page.get_by_label("WAV file").set_input_files(str(too_short))
    message = page.locator("#take-message")
    message.get_by_text("The server did not accept this recording").wait_for()
    assert "0.3" in message.inner_text()  # the server's own reason: shorter than 0.3 s


def _hold(page, pattern: str) -> list:
    """Holds back the requests matching `pattern`: the list fills as the page makes them."""
    held: list = []
    page.route(pattern, lambda route: held.append(route))
    return held


def _wait_for(page, held: list, what: str) -> None:
    """Until the page made the held request (Playwright hands it over only during a call of its own)."""
    wait_until(lambda: held or page.evaluate("false"), 10, f"the page to have {what}")


def keep_holding(page, seconds: float) -> None:
    """A person keeps the key down this long: here time is the input, not a wait for the page."""
    until = page.evaluate("performance.now()") + 1000 * seconds
    page.wait_for_function(f"() => performance.now() >= {until}")


def _main_is_inert(page) -> bool:
    return page.evaluate("document.querySelector('main').inert")


def test_nothing_on_a_page_can_be_used_until_its_handlers_are_attached(page, stack: Stack) -> None:
    for name in PAGES:
        held = _hold(page, "**/auth/me")  # hold back who is signed in: the page cannot attach its handlers
        page.goto(f"{stack.url}/{name}")
        _wait_for(page, held, f"asked who is signed in ({name})")
        assert _main_is_inert(page), f"{name}: its controls could be used before their handlers exist"
        assert page.locator("body[data-ready]").count() == 0, name
        if name == "record":  # its controls also look unavailable, not only behave so
            assert page.get_by_role("button", name="Hold to talk").is_disabled()
            assert page.locator("#file").is_disabled()
        held[0].continue_()
        page.unroute("**/auth/me")
        wait_until_ready(page)
        assert not _main_is_inert(page), name


def test_the_sign_in_form_cannot_be_used_before_its_script_runs(browser, stack: Stack) -> None:
    context = browser.new_context()
    page = context.new_page()
    held = _hold(page, "**/static/js/pages/login.js")
    page.goto(f"{stack.url}/login", wait_until="commit")
    _wait_for(page, held, "asked for its script")
    assert _main_is_inert(page)  # a native submit would send the password to a page that does not take it
    held[0].continue_()
    wait_until_ready(page)
    assert not _main_is_inert(page)
    assert page.evaluate("document.activeElement.id") == "username"
    context.close()


def test_a_page_that_cannot_start_says_why_and_what_to_do(page, stack: Stack, console: ConsoleWatch) -> None:
    console.expect("500")
    page.route(
        "**/api/v1/household",
        lambda route: route.fulfill(status=500, json={"detail": "the database is not reachable"}),
    )
    page.goto(f"{stack.url}/household")
    note = page.get_by_role("alert")
    note.get_by_text("This page could not start: the database is not reachable").wait_for()
    assert "Reload the page" in note.inner_text()
    assert not _main_is_inert(page)  # the reason is readable (an inert region is hidden from screen readers)
    assert page.locator("#invite").count() == 0


def test_a_silent_microphone_and_a_refused_microphone_each_get_a_way_forward(
    playwright_session, stack: Stack, tmp_path: Path
) -> None:
    quiet = silent_wav(tmp_path / "silence.wav")
    setups = {
        "silent": [
            "--use-fake-ui-for-media-stream",
            "--use-fake-device-for-media-stream",
            f"--use-file-for-fake-audio-capture={quiet}",
        ],
        "denied": ["--use-fake-device-for-media-stream"],
    }
    expected = {"silent": "We heard only silence", "denied": "not allowed to use your microphone"}
    for name, flags in setups.items():
        instance = launch(playwright_session, flags)
        try:
            page = instance.new_page()
            if name == "denied":  # the person blocked the microphone for this site (browser permission state)
                cdp = page.context.new_cdp_session(page)
                cdp.send(
                    "Browser.setPermission",
                    {"permission": {"name": "microphone"}, "setting": "denied", "origin": stack.url},
                )
            sign_in(page, stack.url)
            page.get_by_role("button", name="Hold to talk").focus()
            page.keyboard.down("Space")
            if name == "silent":
                page.get_by_text("Recording…", exact=True).wait_for()  # the microphone is open
                keep_holding(page, seconds=0.9)  # long enough to count as a take, not a tap
            page.keyboard.up("Space")
            page.locator("#take-message").get_by_text(expected[name]).wait_for()
            if name == "denied":
                assert page.get_by_role("button", name="Try the microphone again").is_visible()
            screenshot(page, f"record-{name}")
        finally:
            instance.close()


def test_labelling_ten_pairs_by_keyboard_and_undoing_one_leaves_nine_labels(
    page, stack: Stack, robot_id: int, tmp_path: Path
) -> None:
    with stack.client() as alice:
        upload_views(alice, robot_id, 12, seed=3)
        upload_clip(alice, tone_wav(tmp_path / "c.wav").read_bytes(), "the block")
    labels_before = stack.count("labels")
    open_page(page, f"{stack.url}/label")
    camera = page.locator("#camera")
    camera.wait_for()
    wait_until(lambda: camera.evaluate("img => img.complete && img.naturalWidth > 0"), 10, "the camera image")
    try:
        page.wait_for_function("() => document.getElementById('clip').currentTime > 0", timeout=10_000)
    except PlaywrightTimeout:
        raise AssertionError("the command did not play by itself") from None
    counter = page.locator("#session-count")
    for index in range(10):
        shown = page.evaluate("document.body.dataset.pair")
        page.keyboard.press("y" if index % 2 == 0 else "n")
        page.wait_for_function(f"() => document.getElementById('session-count').textContent == {index + 1}")
        page.wait_for_function(f"() => document.body.dataset.pair !== '{shown}'")  # auto-advance, no dialog
    page.keyboard.press("z")
    page.wait_for_function("() => document.getElementById('session-count').textContent === '9'")
    assert counter.inner_text() == "9"
    assert stack.count("labels") == labels_before + 9
    page.keyboard.press("s")  # skip moves on without answering
    page.get_by_text("Skipped.").wait_for()
    assert stack.count("labels") == labels_before + 9
    screenshot(page, "label")


def test_the_label_page_offers_more_views_when_every_pair_is_answered(
    page, stack: Stack, tmp_path: Path
) -> None:
    with stack.client() as alice:
        lonely = alice.post("/robots", json={"name": "empty corner", "kind": "turtlebot-sim"}).json()
    page.evaluate(f"localStorage.setItem('varbot.robot', '{lonely['id']}')")
    open_page(page, f"{stack.url}/label")
    page.get_by_role("button", name="Capture more views").wait_for()
    page.get_by_text("No camera views of empty corner yet").wait_for()  # not "every pair is answered"
    screenshot(page, "label-queue-dry")
    page.evaluate("localStorage.removeItem('varbot.robot')")


def test_an_admin_invites_a_member_and_changes_roles(page, stack: Stack) -> None:
    open_page(page, f"{stack.url}/household")
    page.get_by_label("Name", exact=True).fill("Carol")
    page.get_by_label("Username").fill("carol")
    page.get_by_label("First password").fill("carol's first password")
    page.get_by_role("button", name="Add member").click()
    page.get_by_text("they can sign in as “carol”").wait_for()
    page.get_by_label("Role of Carol").select_option("admin")
    page.get_by_text("Saved Carol.").wait_for()
    assert stack.count("users", "username = 'carol' AND role = 'admin'") == 1
    screenshot(page, "household")


def test_a_member_does_not_see_the_admin_page(browser, stack: Stack) -> None:
    context = browser.new_context()
    page = context.new_page()
    sign_in(page, stack.url, "bob")
    assert page.get_by_role("link", name="Admin").count() == 0
    page.goto(f"{stack.url}/admin")
    page.get_by_text("Only a household admin can use this page").wait_for()
    assert not _main_is_inert(page)
    context.close()


def _label_for_triplets(stack: Stack, robot: int, tmp_path: Path, count: int) -> None:
    """Two commands and `count` views answered is / is not: `count` triplets."""
    with stack.client() as alice:
        views = upload_views(alice, robot, count, seed=11)
        first = upload_clip(alice, tone_wav(tmp_path / "a.wav", amplitude=0.5).read_bytes(), "left")
        second = upload_clip(alice, tone_wav(tmp_path / "b.wav", amplitude=0.3).read_bytes(), "right")
        for view in views:
            for clip, verdict in ((first, "is"), (second, "is_not")):
                alice.post(
                    "/labels", json={"snapshot_id": view, "clip_id": clip, "verdict": verdict}
                ).raise_for_status()


def test_a_queued_run_is_cancelled_from_admin_and_progress_follows_live(
    page, stack: Stack, tmp_path: Path
) -> None:
    with stack.client() as alice:
        robot = alice.post("/robots", json={"name": "bench arm", "kind": "kinova-sim"}).json()["id"]
    _label_for_triplets(stack, robot, tmp_path, 22)
    progress = page.context.new_page()
    open_page(progress, f"{stack.url}/progress")
    progress.get_by_text("Live: updates appear").wait_for()
    open_page(page, f"{stack.url}/admin")
    page.get_by_label("Robot", exact=True).select_option(str(robot))
    page.get_by_label("What to do").select_option("var_finetune")
    page.get_by_label(re.compile("^quick")).check()
    page.get_by_role("button", name="Start").click()
    started = page.get_by_text(re.compile(r"Run (\d+) is queued"))
    started.wait_for()
    run_id = int(re.search(r"Run (\d+)", started.inner_text()).group(1))  # type: ignore[union-attr]
    card = progress.locator(f"[data-run-id='{run_id}']")
    card.wait_for()
    page.get_by_role("button", name=f"Cancel run {run_id}").click()
    card.locator(".status-pill.cancelled").wait_for(timeout=15_000)  # pushed by the stream, no reload
    screenshot(page, "admin")
    screenshot(progress, "progress-cancelled")


def test_a_quick_run_started_by_an_admin_moves_the_progress_bar_to_done(
    page, stack: Stack, tmp_path: Path
) -> None:
    with stack.client() as alice:
        robot = alice.post("/robots", json={"name": "trained arm", "kind": "kuka-sim"}).json()["id"]
    _label_for_triplets(stack, robot, tmp_path, 22)
    worker = stack.start(worker_service("training", stack.data_dir, "worker-training"))
    try:
        open_page(page, f"{stack.url}/admin")
        page.get_by_label("Robot", exact=True).select_option(str(robot))
        page.get_by_label("What to do").select_option("finetune")
        page.get_by_label(re.compile("^quick")).check()
        page.get_by_role("button", name="Start").click()
        started = page.get_by_text(re.compile(r"Run (\d+) is queued"))
        started.wait_for()
        run_id = int(re.search(r"Run (\d+)", started.inner_text()).group(1))  # type: ignore[union-attr]
        open_page(page, f"{stack.url}/progress")
        card = page.locator(f"[data-run-id='{run_id}']")
        page.evaluate(RECORD_CARD_STATES, run_id)
        try:
            card.locator(".status-pill.succeeded").wait_for(timeout=170_000)
        except PlaywrightTimeout:
            raise AssertionError(f"run {run_id} did not succeed:\n{stack.log('worker-training')}") from None
        bar = card.locator("progress")
        assert float(bar.get_attribute("value") or 0) == 1.0
        states = page.evaluate("[...window.cardStates]")
        values = {value for value, _ in states}
        stages = {stage for _, stage in states}
        # live updates arrived while it ran: intermediate bar values or at least the stage names changing
        assert len(values) > 2 or len(stages) > 2, f"no live updates: {states}"
        # the promotion gate's verdict and its reasons, the saved training curves, the before/after figure
        verdict = card.locator(".message.verdict").inner_text()  # sentences: what changed, what is used
        assert re.search(r"(the new version is active|kept the old version)\.$", verdict), verdict
        assert card.locator("details.reasons li").count() > 0  # and how the gate decided
        charts = card.locator("svg.chart")
        labels = [charts.nth(i).get_attribute("aria-label") or "" for i in range(charts.count())]
        assert any(label.startswith("Loss. VAR loss") for label in labels), labels
        assert any(label.startswith("Return. policy episode return") for label in labels), labels
        assert card.locator("figure.before-after").count() == 1
        screenshot(page, "progress")
    finally:
        worker.stop()


# Every change of a run card (its bar's value and its stage), as the page shows them: window.cardStates.
RECORD_CARD_STATES = """(id) => {
  window.cardStates = [];
  const record = () => {
    const card = document.querySelector(`[data-run-id='${id}']`);
    if (!card) return;
    const state = [String(card.querySelector('progress')?.value),
                   (card.querySelector('p.muted')?.textContent || '').split('·')[0]];
    const last = window.cardStates[window.cardStates.length - 1];
    if (!last || last[0] !== state[0] || last[1] !== state[1]) window.cardStates.push(state);
  };
  record();
  new MutationObserver(record).observe(document.body,
    {subtree: true, childList: true, attributes: true, characterData: true});
}"""


def test_every_control_is_labelled_and_reachable_by_keyboard(page, stack: Stack) -> None:
    problems: list[str] = []
    for name in PAGES:
        open_page(page, f"{stack.url}/{name}")
        page.wait_for_load_state("networkidle")
        unlabelled = page.evaluate(
            """() => [...document.querySelectorAll('button, input, select, a[href], audio[controls]')]
                .filter(e => e.offsetParent !== null && !e.closest('[hidden]'))
                .filter(e => { const id = e.id && document.querySelector(`label[for="${e.id}"]`);
                    const text = (e.getAttribute('aria-label') || e.getAttribute('aria-labelledby') ||
                        (id && id.textContent) || e.closest('label')?.textContent || e.textContent || '')
                        .trim();
                    return !text; })
                .map(e => e.outerHTML.slice(0, 80))"""
        )
        problems += [f"{name}: unlabelled {html}" for html in unlabelled]
        controls = page.evaluate(
            """() => [...document.querySelectorAll('button, input, select, a[href]')]
                .filter(e => e.offsetParent !== null && !e.disabled && e.type !== 'radio').length"""
        )
        page.evaluate(RECORD_FOCUS)
        page.locator("body").focus()
        missing: list[str] = []
        for presses in range(1, controls * 4 + 21):  # <audio controls> holds several tab stops of its own
            page.keyboard.press("Tab")
            if presses % 10 == 0 or presses == controls * 4 + 20:
                missing = page.evaluate(UNREACHED_CONTROLS)
                if not missing:
                    break
        problems += [f"{name}: not reachable by Tab: {html}" for html in missing]
        low = page.evaluate(CONTRAST_CHECK)
        problems += [f"{name}: low contrast {item}" for item in low]
    assert problems == [], "\n".join(problems)


def test_pages_fit_a_phone_screen(browser, stack: Stack) -> None:
    context = browser.new_context(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
    page = context.new_page()
    sign_in(page, stack.url)
    for name in ("record", "label"):
        open_page(page, f"{stack.url}/{name}")
        page.wait_for_load_state("networkidle")
        overflow = page.evaluate(
            "document.documentElement.scrollWidth - document.documentElement.clientWidth"
        )
        assert overflow <= 1, f"{name} scrolls sideways on a phone by {overflow} px"
        screenshot(page, f"phone-{name}")
    context.close()


# Every element that took the keyboard focus since the page loaded, as the Tab walk reached it.
RECORD_FOCUS = """() => { window.reachedByTab = new Set();
  document.addEventListener('focusin', (e) => window.reachedByTab.add(e.target.outerHTML.slice(0, 120))); }"""
UNREACHED_CONTROLS = """() => [...document.querySelectorAll('button, input, select, a[href]')]
  .filter(e => e.offsetParent !== null && !e.disabled && e.type !== 'radio')
  .filter(e => !e.closest('details:not([open])'))
  .map(e => e.outerHTML.slice(0, 120)).filter(h => !window.reachedByTab.has(h))"""

# WCAG relative luminance contrast of visible text against its nearest opaque background (≥ 4.5:1).
CONTRAST_CHECK = """() => {
  const channel = (v) => { v /= 255; return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
  const lum = (rgb) => { const [r, g, b] = rgb.map(channel); return 0.2126 * r + 0.7152 * g + 0.0722 * b; };
  const parse = (c) => (c.match(/[\\d.]+/g) || []).map(Number);
  const background = (e) => {
    for (; e; e = e.parentElement) {
      const c = parse(getComputedStyle(e).backgroundColor);
      if (c.length === 3 || (c.length === 4 && c[3] > 0.9)) return c.slice(0, 3);
    }
    return [255, 255, 255];
  };
  const out = [];
  for (const e of document.querySelectorAll('body *')) {
    if (!e.offsetParent || ![...e.childNodes].some(n => n.nodeType === 3 && n.textContent.trim())) continue;
    const style = getComputedStyle(e);
    if (parseFloat(style.opacity) < 1 || e.closest('button:disabled')) continue;
    const fg = parse(style.color).slice(0, 3), bg = background(e);
    const [a, b] = [lum(fg), lum(bg)].sort((x, y) => y - x);
    const ratio = (a + 0.05) / (b + 0.05);
    if (ratio < 4.5) out.push(`${e.tagName} "${e.textContent.trim().slice(0, 30)}" ${ratio.toFixed(2)}:1`);
  }
  return out;
}"""


def test_the_policy_refuses_a_script_injected_into_a_page(page, stack: Stack, console: ConsoleWatch) -> None:
    console.expect("Content Security Policy")
    open_page(page, f"{stack.url}/record")
    ran = page.evaluate(
        """() => {
            const injected = document.createElement("script");
            injected.textContent = "window.injectedRan = true";
            document.head.append(injected);
            return window.injectedRan === true;
        }"""
    )
    assert ran is False
