"""The Admin page, where a run is started, states each preset's budget in minutes on this machine beside its
steps (the API's GET /runs/presets, `backend.services.runs.minutes_here`)."""

import math

import pytest
from browser_helpers import Stack, open_page

pytestmark = pytest.mark.browser


def test_each_preset_states_its_budget_in_minutes(page, stack: Stack) -> None:  # type: ignore[no-untyped-def]
    with stack.client() as alice:
        presets = alice.get("/runs/presets").json()
    open_page(page, f"{stack.url}/admin")
    for name, params in presets.items():
        label = page.locator(f"label[for='preset-{name}']")
        label.wait_for()
        minutes = max(1, math.floor(params["minutes_here"] + 0.5))  # the page's Math.round: halves go up
        said = "1 minute" if minutes == 1 else f"{minutes} minutes"
        assert f"about {said} on a 2-core computer" in label.inner_text(), label.inner_text()
        assert f"{params['policy_steps']:,} policy steps" in label.inner_text()
