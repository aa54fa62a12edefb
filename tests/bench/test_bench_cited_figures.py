"""A figure a bench did not measure (the reference implementation's PPO speed) is stored with its source, and
the result holds it beside the ratio computed from it."""

import json

import pytest
from rl_throughput import REFERENCE

from core.paths import REPO_ROOT


def test_the_reference_speed_is_cited_with_its_unit_machine_and_source():
    assert REFERENCE["value"] == 4.7
    assert REFERENCE["unit"] == "env steps/s"
    assert "2 CPU cores" in REFERENCE["measured_on"]
    assert "DESIGN.md" in REFERENCE["source"] and "154 s" in REFERENCE["source"]


def test_the_throughput_result_holds_the_reference_beside_the_ratio():
    result = json.loads((REPO_ROOT / "bench" / "results" / "rl_throughput.json").read_text())
    assert result["reference"] == REFERENCE
    ratio = result["trainer_steps_per_s"] / result["reference"]["value"]
    assert result["speedup_over_reference"] == pytest.approx(ratio)
    assert set(result["load_average"]) == {"before", "after"}
