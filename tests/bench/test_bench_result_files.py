"""Results name paths relative to the repository or the data directory, never by this machine's absolute
path, so a clone elsewhere can read them."""

import json
import os
from pathlib import Path

from result_files import ABSOLUTE_PATH, relative_paths, resolve, write_result

from core.paths import REPO_ROOT

RESULTS = REPO_ROOT / "bench" / "results"


def strings_in(value: object) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for key, item in value.items() for s in [key, *strings_in(item)]]
    if isinstance(value, list):
        return [s for item in value for s in strings_in(item)]
    return []


def test_no_result_holds_an_absolute_path():
    files = sorted(RESULTS.glob("*.json"))
    assert files
    for path in files:
        for text in strings_in(json.loads(path.read_text())):
            assert not ABSOLUTE_PATH.search(text), f"{path.name}: {text[:200]}"
            assert str(REPO_ROOT) not in text and "/tmp/" not in text, f"{path.name}: {text[:200]}"


def test_paths_in_the_repository_are_written_relative_to_it():
    written = relative_paths({"curves": str(REPO_ROOT / "bench" / "results" / "reproduce_kuka-mix.png")})
    assert written == {"curves": "bench/results/reproduce_kuka-mix.png"}
    assert resolve(written["curves"]) == REPO_ROOT / "bench" / "results" / "reproduce_kuka-mix.png"


def test_paths_in_a_data_directory_elsewhere_are_written_from_the_data_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path))
    run_dir = tmp_path / "bench" / "reproduce" / "rl" / "full" / "kuka-wordset-var"
    written = relative_paths({"run_dir": str(run_dir), "note": f"checkpoint {run_dir}/final.pt (6 epochs)"})
    assert written["run_dir"] == "$VARBOT_DATA_DIR/bench/reproduce/rl/full/kuka-wordset-var"
    assert written["note"] == f"checkpoint {written['run_dir']}/final.pt (6 epochs)"
    assert resolve(written["run_dir"]) == run_dir


def test_a_path_outside_both_keeps_only_its_name_and_other_text_is_left_alone():
    text = ["/opt/elsewhere/var.pt", "http://127.0.0.1:8000/api/labels", "0.0 / 0.8 steps/s", "data/var/x.pt"]
    assert relative_paths(text) == [
        "(outside the repository) var.pt",
        "http://127.0.0.1:8000/api/labels",
        "0.0 / 0.8 steps/s",
        "data/var/x.pt",
    ]


def test_writing_a_result_makes_its_paths_relative(tmp_path):
    out = tmp_path / "result.json"
    var = str(REPO_ROOT / "worker" / "base_models" / "kuka" / "var.pt")
    write_result(out, {"var": var, "rows": [1.5], "by_env_groups": {2: {"steps_per_s": 30.0}}})
    assert json.loads(out.read_text()) == {
        "var": "worker/base_models/kuka/var.pt",
        "rows": [1.5],
        "by_env_groups": {"2": {"steps_per_s": 30.0}},
    }
    assert not [name for name in os.listdir(tmp_path) if name.endswith(".tmp")]
    assert Path(out).read_text().endswith("\n")
