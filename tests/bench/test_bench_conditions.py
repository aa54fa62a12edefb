"""Every bench records the machine and the load average before and after its measurement, and claims nothing
about the load that it did not measure."""

import os
import platform
import re
from pathlib import Path

from conditions import Conditions, describe, load_average

BENCH = Path(__file__).resolve().parents[2] / "bench"
HELPERS = {  # imported by the benches (which record the conditions), or maintaining their results
    "conditions.py", "result_files.py", "results_tool.py", "reproduce_records.py", "reproduce_table.py",
    "raw_stepping.py",
}  # fmt: skip


def test_the_load_average_is_read_for_1_5_and_15_minutes():
    load = load_average()
    assert set(load) == {"1_min", "5_min", "15_min"}
    assert all(isinstance(value, float) and value >= 0 for value in load.values())


def test_finishing_records_the_machine_and_the_load_before_and_after():
    record = Conditions().finish()
    machine = record["machine"]
    assert machine["cpu_cores"] == os.cpu_count()
    assert machine["memory_gib"] > 0
    assert machine["python"] == platform.python_version()
    assert re.fullmatch(r"\d+\.\d+\.\d+.*", machine["torch"])
    assert "gpu" in machine  # None here; the GPU's name on a machine where torch sees one
    assert set(record["load_average"]) == {"before", "after"}
    assert set(record["load_average"]["before"]) == {"1_min", "5_min", "15_min"}


def test_the_printed_line_gives_the_load_before_and_after():
    record = Conditions().finish()
    record["load_average"] = {
        "before": {"1_min": 3.25, "5_min": 0.0, "15_min": 0.0},
        "after": {"1_min": 5.5, "5_min": 0.0, "15_min": 0.0},
    }
    line = describe(record)
    assert "3.2 before, 5.5 after" in line
    assert f"{os.cpu_count()} CPU cores" in line
    record["machine"]["gpu"] = "NVIDIA H200"
    assert "GPU NVIDIA H200" in describe(record)


def test_every_bench_records_its_conditions_and_prints_them():
    benches = [path for path in BENCH.glob("*.py") if path.name not in HELPERS]
    assert len(benches) >= 10
    for bench in benches:
        source = bench.read_text()
        by_hand = "Conditions()" in source and "describe(" in source
        assert by_hand or "measure_and_publish(" in source, bench.name  # conditions.py does both for it


def test_no_bench_claims_a_load_it_did_not_measure():
    benches = [path for path in BENCH.glob("*.py") if path.name != "results_tool.py"]  # it removes the claim
    for path in [*benches, *BENCH.glob("results/*.json")]:
        assert "shared with other" not in path.read_text(), path.name
