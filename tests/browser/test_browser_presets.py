"""The Admin page, where a run is started, states each preset's budget in minutes on this machine beside its
steps (the API's GET /runs/presets, `backend.services.runs.minutes_here`), for the picked robot's triplets
once it has some."""

import math
from pathlib import Path

import pytest
from browser_helpers import Stack, open_page, robot_with_commands, upload_views

pytestmark = pytest.mark.browser


def test_each_preset_states_its_budget_in_minutes(page, stack: Stack) -> None:  # type: ignore[no-untyped-def]
    open_page(page, f"{stack.url}/admin")
    page.locator("label[for='preset-quick']").wait_for()
    picked = page.input_value("#robot")  # the budgets are for its triplets when it has some
    with stack.client() as alice:
        triplets = (
            alice.get("/triplets/stats", params={"robot_id": picked}).json()["triplets"] if picked else 0
        )
        presets = alice.get("/runs/presets", params={"triplets": triplets} if triplets else {}).json()
    for name, params in presets.items():
        label = page.locator(f"label[for='preset-{name}']")
        assert f"about {said_minutes(params)} on a 2-core computer" in label.inner_text(), label.inner_text()
        assert f"{params['policy_steps']:,} policy steps" in label.inner_text()


def test_the_budget_is_for_the_picked_robots_triplets(page, stack: Stack, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    robot = robot_with_commands(stack, "budget arm", ["budget left", "budget right"], tmp_path)
    with stack.client() as alice:
        view = upload_views(alice, robot, 1, seed=3)[0]
        clips = {clip["name"]: clip["id"] for clip in alice.get("/clips", params={"limit": 500}).json()}
        for word, verdict in (("budget left", "is"), ("budget right", "is_not")):
            body = {"snapshot_id": view, "clip_id": clips[word], "verdict": verdict}
            alice.post("/labels", json=body).raise_for_status()
        triplets = alice.get("/triplets/stats", params={"robot_id": robot}).json()["triplets"]
        thorough = alice.get("/runs/presets", params={"triplets": triplets}).json()["thorough"]
    assert triplets == 1
    open_page(page, f"{stack.url}/admin")
    page.select_option("#robot", str(robot))
    label = page.locator("label[for='preset-thorough']")
    expected = f"about {said_minutes(thorough)} on a 2-core computer with this robot's 1 triplet:"
    page.wait_for_function(
        "([selector, text]) => (document.querySelector(selector)?.innerText ?? '').includes(text)",
        arg=["label[for='preset-thorough']", expected],
    )
    assert "4,034" not in label.inner_text()


def said_minutes(params: dict) -> str:
    minutes = max(1, math.floor(params["minutes_here"] + 0.5))  # the page's Math.round: halves go up
    return "1 minute" if minutes == 1 else f"{minutes} minutes"
